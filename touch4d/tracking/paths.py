"""Scripted hand paths: the hand's pose in screen coordinates as a pure function of time.

A path is deterministic: `sample(t)` depends on t alone, so a tracker that steps t by tick
count gives the same poses on every run. Kinds (config/paths.yaml):
  waypoints  keyframes [t, position] with eased motion, slerped orientation, stepped trigger/buttons
  sweep      start -> end -> start (across a face)
  press      from `distance` away along `approach` onto `target`, dwell, and back (an edge, a vertex)
  orbit      a circle around `center` (optionally with the trigger held, to rotate the object)
  hold       one pose
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Annotated, Literal, Union

import msgspec
import numpy as np

from touch4d import schema
from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError
from touch4d.schema import Finite, Fraction, NonNegative, Positive

from touch4d.geometry import quaternion
from .calibration import Steps, Vec3, _steps
from .config import CONFIG_DIR

DEFAULT_PATHS = CONFIG_DIR / "paths.yaml"
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class PathSample:
    """The hand at one instant: screen position, orientation (x, y, z, w) hand -> screen, controller inputs."""

    position: np.ndarray
    orientation: np.ndarray
    trigger: float = 0.0
    buttons: tuple[str, ...] = ()
    valid: bool = True


@dataclass(frozen=True)
class Keyframe:
    t: float
    position: np.ndarray
    orientation: np.ndarray = field(default_factory=lambda: IDENTITY.copy())
    trigger: float = 0.0
    buttons: tuple[str, ...] = ()


def smoothstep(u: float) -> float:
    """Ease in and out: zero velocity at both ends, so the hand never jumps in speed at a keyframe."""
    u = min(max(u, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


class Waypoints:
    """Piecewise motion through keyframes; trigger and buttons hold the value of the last keyframe passed."""

    def __init__(self, keyframes: list[Keyframe]):
        if not keyframes:
            raise ValueError("a waypoint path needs at least one keyframe")
        times = [k.t for k in keyframes]
        if times[0] != 0.0 or any(b <= a for a, b in zip(times, times[1:])):
            raise ValueError(f"keyframe times must start at 0 and increase, got {times}")
        self.keyframes = keyframes
        self.times = np.array(times)
        self.duration = float(times[-1])

    def sample(self, t: float) -> PathSample:
        t = min(max(t, 0.0), self.duration)
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        i = min(i, len(self.keyframes) - 1)
        a = self.keyframes[i]
        if i == len(self.keyframes) - 1:
            return PathSample(a.position.copy(), _canonical(a.orientation), a.trigger, a.buttons)
        b = self.keyframes[i + 1]
        u = smoothstep((t - a.t) / (b.t - a.t))
        position = a.position + u * (b.position - a.position)
        orientation = quaternion.slerp(_canonical(a.orientation), _canonical(b.orientation), u)
        return PathSample(position, orientation, a.trigger, a.buttons)


class Orbit:
    """A circle of `radius` around `center` in the plane spanned by two screen axes, one turn per `period`."""

    def __init__(self, center, radius: float, period: float, plane: str = "xy", orientation=IDENTITY,
                 trigger: float = 0.0):
        if len(plane) != 2 or plane[0] == plane[1] or not set(plane) <= set("xyz"):
            raise ValueError(f"orbit plane must be two of x, y, z, got {plane!r}")
        if not period > 0:
            raise ValueError(f"orbit period must be > 0, got {period}")
        self.center = np.asarray(center, dtype=float)
        self.radius = float(radius)
        self.duration = float(period)
        self.axes = ("xyz".index(plane[0]), "xyz".index(plane[1]))
        self.orientation = _canonical(np.asarray(orientation, dtype=float))
        self.trigger = float(trigger)

    def sample(self, t: float) -> PathSample:
        angle = 2.0 * math.pi * t / self.duration
        position = self.center.copy()
        position[self.axes[0]] += self.radius * math.cos(angle)
        position[self.axes[1]] += self.radius * math.sin(angle)
        return PathSample(position, self.orientation.copy(), self.trigger)


class Hold:
    """One pose for `duration` seconds."""

    def __init__(self, position, duration: float, orientation=IDENTITY, trigger: float = 0.0):
        self.position = np.asarray(position, dtype=float)
        self.orientation = _canonical(np.asarray(orientation, dtype=float))
        self.duration = float(duration)
        self.trigger = float(trigger)

    def sample(self, t: float) -> PathSample:
        return PathSample(self.position.copy(), self.orientation.copy(), self.trigger)


def sweep(start, end, duration: float, orientation=IDENTITY, trigger: float = 0.0) -> Waypoints:
    """Across and back: start -> end in half the duration, end -> start in the other half."""
    start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    half = duration / 2.0
    q = np.asarray(orientation, dtype=float)
    return Waypoints([
        Keyframe(0.0, start, q, trigger), Keyframe(half, end, q, trigger), Keyframe(duration, start, q, trigger),
    ])


def press(target, approach, distance: float, move_s: float, dwell_s: float, orientation=IDENTITY) -> Waypoints:
    """From `distance` away along the unit `approach` direction onto `target`, dwell there, and back."""
    target = np.asarray(target, dtype=float)
    away = np.asarray(approach, dtype=float)
    norm = np.linalg.norm(away)
    if not norm > 0:
        raise ValueError("press approach direction must be non-zero")
    start = target + distance * away / norm
    q = np.asarray(orientation, dtype=float)
    return Waypoints([
        Keyframe(0.0, start, q), Keyframe(move_s, target, q), Keyframe(move_s + dwell_s, target, q),
        Keyframe(2 * move_s + dwell_s, start, q),
    ])


def looped(path, t: float) -> PathSample:
    """The path sampled at t, wrapping around at its end."""
    return path.sample(math.fmod(t, path.duration) if path.duration > 0 else 0.0)


def _canonical(q) -> np.ndarray:
    return quaternion.canonical(np.asarray(q, dtype=float))


# ---- config ------------------------------------------------------------------------------------


class _Path(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, tag_field="kind"):
    rotation_deg: Steps = []             # hand -> screen
    trigger: Fraction = 0.0              # the controller's trigger, held along the path


class SweepSpec(_Path, tag="sweep", kw_only=True):
    start: Vec3
    end: Vec3
    duration_s: Positive


class PressSpec(_Path, tag="press", kw_only=True):
    target: Vec3
    approach: Vec3 = (0.0, 0.0, 1.0)
    distance: Positive
    move_s: Positive
    dwell_s: NonNegative = 1.0


class OrbitSpec(_Path, tag="orbit", kw_only=True):
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: Positive
    period_s: Positive
    plane: Literal["xy", "yx", "xz", "zx", "yz", "zy"] = "xy"


class HoldSpec(_Path, tag="hold", kw_only=True):
    position: Vec3
    duration_s: Positive = 1.0


class KeyframeSpec(msgspec.Struct, forbid_unknown_fields=True):
    t: Finite
    position: Vec3
    rotation_deg: Steps | None = None    # default: the path's
    trigger: Fraction = 0.0
    buttons: list[str] = []


class WaypointsSpec(_Path, tag="waypoints", kw_only=True):
    keyframes: Annotated[list[KeyframeSpec], msgspec.Meta(min_length=1, description="a non-empty list of {t, position, ...}")]


PathSpec = Union[SweepSpec, PressSpec, OrbitSpec, HoldSpec, WaypointsSpec]


class PathsFile(msgspec.Struct, forbid_unknown_fields=True):
    """A paths file (config/paths.yaml): named paths."""

    paths: dict[str, PathSpec]


def path_from_config(spec, file=None, where: str = "") -> object:
    """Build a path from one entry of paths.yaml; errors name the file and the key."""
    key = where.rstrip(".")
    if not isinstance(spec, (SweepSpec, PressSpec, OrbitSpec, HoldSpec, WaypointsSpec)):
        spec = schema.convert(spec, PathSpec, file, key)
    q = _steps(spec.rotation_deg).as_quat()
    try:
        if isinstance(spec, SweepSpec):
            return sweep(spec.start, spec.end, spec.duration_s, q, spec.trigger)
        if isinstance(spec, PressSpec):
            return press(spec.target, spec.approach, spec.distance, spec.move_s, spec.dwell_s, q)
        if isinstance(spec, OrbitSpec):
            return Orbit(spec.center, spec.radius, spec.period_s, spec.plane, q, spec.trigger)
        if isinstance(spec, HoldSpec):
            return Hold(spec.position, spec.duration_s, q, spec.trigger)
        return Waypoints([Keyframe(k.t, np.array(k.position, dtype=float),
                                   _steps(k.rotation_deg).as_quat() if k.rotation_deg is not None else q,
                                   k.trigger, tuple(k.buttons)) for k in spec.keyframes])
    except ValueError as exc:           # a path the kinds refuse (keyframe times, a zero approach)
        raise ConfigError(file, key, "a valid path", got=str(exc)) from None


def load_paths(path=None) -> dict[str, object]:
    """Every named path of config/paths.yaml (or `path`)."""
    path = resolve_path(path if path is not None else "config/paths.yaml", what="paths file")
    entries = schema.load(path, PathsFile, "paths file").paths
    return {name: path_from_config(spec, path, f"paths.{name}.") for name, spec in entries.items()}


def load_path(name: str, path=None):
    """One named path; an unknown name is a ConfigError listing the names that exist."""
    file = resolve_path(path if path is not None else "config/paths.yaml", what="paths file")
    paths = load_paths(file)
    if name not in paths:
        schema.fail(file, f"paths.{name}", f"one of {', '.join(sorted(paths))}", got=name, choices=paths)
    return paths[name]

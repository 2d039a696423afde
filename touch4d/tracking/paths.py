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

import numpy as np

from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError

from touch4d.geometry import quaternion
from .calibration import rotation_from_steps
from .config import CONFIG_DIR, get_map, get_number, get_vector, read_yaml

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


def path_from_config(spec: dict, file=None, where: str = "") -> object:
    """Build a path from one entry of paths.yaml; errors name the file and the key."""
    if not isinstance(spec, dict):
        raise ConfigError(file, where.rstrip("."), "a map with a 'kind'", got=spec)
    kind = spec.get("kind")
    q = rotation_from_steps(spec.get("rotation_deg", []), file, where + "rotation_deg").as_quat()
    trigger = _trigger(spec, file, where)
    try:
        if kind == "sweep":
            return sweep(get_vector(spec, "start", file, 3, where), get_vector(spec, "end", file, 3, where),
                         get_number(spec, "duration_s", file, where, positive=True), q, trigger)
        if kind == "press":
            return press(get_vector(spec, "target", file, 3, where),
                         get_vector(spec, "approach", file, 3, where, default=[0, 0, 1]),
                         get_number(spec, "distance", file, where, positive=True),
                         get_number(spec, "move_s", file, where, positive=True),
                         get_number(spec, "dwell_s", file, where, default=1.0), q)
        if kind == "orbit":
            return Orbit(get_vector(spec, "center", file, 3, where, default=[0, 0, 0]),
                         get_number(spec, "radius", file, where, positive=True),
                         get_number(spec, "period_s", file, where, positive=True),
                         str(spec.get("plane", "xy")), q, trigger)
        if kind == "hold":
            return Hold(get_vector(spec, "position", file, 3, where),
                        get_number(spec, "duration_s", file, where, default=1.0, positive=True), q, trigger)
        if kind == "waypoints":
            return Waypoints(_keyframes(spec, q, file, where))
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(file, where.rstrip("."), "a valid path", got=str(exc)) from None
    raise ConfigError(file, where + "kind", "one of waypoints, sweep, press, orbit, hold", got=kind)


def _trigger(spec: dict, file, where: str) -> float:
    value = get_number(spec, "trigger", file, where, default=0.0)
    if not 0.0 <= value <= 1.0:
        raise ConfigError(file, where + "trigger", "a number in 0..1", got=value)
    return value


def _keyframes(spec: dict, q: np.ndarray, file, where: str) -> list[Keyframe]:
    frames = spec.get("keyframes")
    if not isinstance(frames, list) or not frames:
        raise ConfigError(file, where + "keyframes", "a non-empty list of {t, position, ...}", got=frames)
    out = []
    for index, frame in enumerate(frames):
        at = f"{where}keyframes[{index}]."
        if not isinstance(frame, dict):
            raise ConfigError(file, at.rstrip("."), "a map {t, position}", got=frame)
        buttons = frame.get("buttons", [])
        if not isinstance(buttons, list) or not all(isinstance(b, str) for b in buttons):
            raise ConfigError(file, at + "buttons", "a list of button names", got=buttons)
        frame_q = rotation_from_steps(frame["rotation_deg"], file, at + "rotation_deg").as_quat() \
            if "rotation_deg" in frame else q
        out.append(Keyframe(get_number(frame, "t", file, at), get_vector(frame, "position", file, 3, at),
                            frame_q, _trigger(frame, file, at), tuple(buttons)))
    return out


def load_paths(path=None) -> dict[str, object]:
    """Every named path of config/paths.yaml (or `path`)."""
    path = resolve_path(path if path is not None else "config/paths.yaml", what="paths file")
    entries = get_map(read_yaml(path), "paths", path)
    return {str(name): path_from_config(spec, path, f"paths.{name}.") for name, spec in entries.items()}


def load_path(name: str, path=None):
    """One named path; an unknown name is a ConfigError listing the names that exist."""
    file = resolve_path(path if path is not None else "config/paths.yaml", what="paths file")
    paths = load_paths(file)
    if name not in paths:
        raise ConfigError(file, f"paths.{name}", f"one of {', '.join(sorted(paths))}", got=name)
    return paths[name]

"""Finger motions for trackers without hand tracking: how the fingers bend, as a pure function of time.

A motion is keyframes of hand shapes (`HandShape`: a curl per finger, 0 straight .. 1 fist, and a
spread, 0 .. 1), eased like the scripted paths, so a tracker that steps t by tick count bends the
fingers the same way on every run. Named shapes (`SHAPES`: flat, fist, point, spread, pinch) hold
still; named motions come from a fingers file (config/fingers.yaml):

    motions:
      curl:                       # straight -> fist -> straight in 2 s
        keyframes:
          - {t: 0, shape: flat}
          - {t: 1, shape: fist}
          - {t: 2, shape: flat}
      wave:
        keyframes:
          - {t: 0, curl: {index: 0, middle: 0.5}, spread: 0.2}   # per finger, or `all`

A keyframe starts from its `shape` (default flat) and sets the fingers `curl` names and `spread`.
"""
from __future__ import annotations

import math
from typing import Annotated

import msgspec

from touch4d import schema
from touch4d.configfile import resolve_path
from touch4d.hands import FINGER_NAMES, HandShape

from .paths import smoothstep

_ALL = {f: 1.0 for f in FINGER_NAMES}
SHAPES = {
    "flat": HandShape(),
    "fist": HandShape(curl=dict(_ALL, thumb=0.8)),
    "point": HandShape(curl=dict(_ALL, index=0.0, thumb=0.7)),
    "spread": HandShape(spread=1.0),
    "pinch": HandShape(curl={"thumb": 0.6, "index": 0.45}),
}

Unit = Annotated[float, msgspec.Meta(ge=0, le=1)]


class KeyframeSpec(msgspec.Struct, forbid_unknown_fields=True):
    t: Annotated[float, msgspec.Meta(ge=0)]
    shape: str = "flat"
    curl: dict[str, Unit] = {}
    spread: Unit | None = None


class MotionSpec(msgspec.Struct, forbid_unknown_fields=True):
    keyframes: Annotated[list[KeyframeSpec], msgspec.Meta(min_length=1)]


class FingersFile(msgspec.Struct, forbid_unknown_fields=True):
    motions: dict[str, object] = {}      # each a MotionSpec, converted one by one so errors name it


class FingerMotion:
    """Hand shapes at keyframe times, eased between; holds the last one after the end."""

    def __init__(self, keyframes: list[tuple[float, HandShape]]):
        self.keyframes = keyframes
        self.duration = keyframes[-1][0]

    def sample(self, t: float) -> HandShape:
        frames = self.keyframes
        t = min(max(t, 0.0), self.duration)
        for (ta, a), (tb, b) in zip(frames, frames[1:]):
            if t <= tb:
                u = smoothstep((t - ta) / (tb - ta))
                curl = {f: a.of(f) + u * (b.of(f) - a.of(f)) for f in FINGER_NAMES}
                return HandShape(curl=curl, spread=a.spread + u * (b.spread - a.spread))
        return frames[-1][1]

    def looped(self, t: float) -> HandShape:
        return self.sample(math.fmod(t, self.duration) if self.duration > 0 else 0.0)


def still(shape: HandShape) -> FingerMotion:
    return FingerMotion([(0.0, shape)])


def motion_from_spec(spec: MotionSpec, file, key: str) -> FingerMotion:
    frames = []
    for i, k in enumerate(spec.keyframes):
        where = f"{key}.keyframes[{i}]"
        if k.shape not in SHAPES:
            schema.fail(file, f"{where}.shape", f"one of {', '.join(SHAPES)}", got=k.shape, choices=SHAPES)
        base = SHAPES[k.shape]
        curl = {f: base.of(f) for f in FINGER_NAMES}
        for finger, amount in k.curl.items():
            if finger not in (*FINGER_NAMES, "all"):
                schema.fail(file, f"{where}.curl.{finger}", f"one of {', '.join(FINGER_NAMES)}, all", got=finger,
                            choices=(*FINGER_NAMES, "all"))
            curl.update({f: amount for f in FINGER_NAMES} if finger == "all" else {finger: amount})
        if frames and k.t <= frames[-1][0]:
            schema.fail(file, f"{where}.t", f"a time after the previous keyframe's ({frames[-1][0]:g})", got=k.t)
        if not frames and k.t != 0:
            schema.fail(file, f"{where}.t", "0 (a motion starts at its first keyframe)", got=k.t)
        frames.append((float(k.t), HandShape(curl=curl, spread=base.spread if k.spread is None else k.spread)))
    return FingerMotion(frames)


def load_motions(path=None) -> dict[str, FingerMotion]:
    """Every named motion of a fingers file (default config/fingers.yaml)."""
    path = resolve_path(path if path is not None else "config/fingers.yaml", what="fingers file")
    data = schema.load(path, FingersFile, "fingers file")
    return {name: motion_from_spec(schema.convert(spec, MotionSpec, path, f"motions.{name}"), path, f"motions.{name}")
            for name, spec in data.motions.items()}


def load_motion(name: str, path=None, key: str = "fingers") -> FingerMotion:
    """A named shape (held still) or a motion of the fingers file; an unknown name lists both."""
    if name in SHAPES:
        return still(SHAPES[name])
    file = resolve_path(path if path is not None else "config/fingers.yaml", what="fingers file")
    motions = load_motions(file)
    if name not in motions:
        names = [*SHAPES, *motions]
        schema.fail(file, f"motions.{name}", f"a shape ({', '.join(SHAPES)}) or a motion of the file "
                    f"({', '.join(motions) or 'none'})", got=name, choices=names)
    return motions[name]

"""The glove file's optional `bones:` section: where each finger's joints lie along its capsule.

A finger capsule of the glove file is split into three bones, base to tip: the thumb's metacarpal,
proximal and distal phalanges, each other finger's proximal, intermediate and distal phalanges
(its metacarpal lies inside the palm). `bones: {index: [0.46, 0.30, 0.24], ...}` gives a finger's
bone lengths as fractions of its capsule (they must add up to 1); a finger not named, or a file
without the section, gets the human proportions below. `wrist: [x, y]` (metres, hand frame) is
where the wrist joint lies, by default the middle of the palm's proximal edge. The samples and
motors of the palm move with the wrist joint, those of a finger with the bone they lie in
(touch4d.tactile.skeleton).
"""
from __future__ import annotations

import math
from typing import Annotated

import msgspec

from touch4d import schema

# Phalanx lengths as fractions of the finger, base to tip (after Buchholz et al. 1992, rounded);
# the thumb's capsule starts at its metacarpal, so its first bone is the metacarpal's free part.
DEFAULT_FRACTIONS = {
    "thumb": (0.40, 0.33, 0.27),
    "index": (0.48, 0.29, 0.23),
    "middle": (0.48, 0.30, 0.22),
    "ring": (0.47, 0.31, 0.22),
    "little": (0.46, 0.30, 0.24),
}

Fraction = Annotated[float, msgspec.Meta(gt=0, lt=1)]
Fractions = Annotated[list[Fraction], msgspec.Meta(min_length=3, max_length=3)]
Point2 = Annotated[list[float], msgspec.Meta(min_length=2, max_length=2)]


class BonesSection(msgspec.Struct, forbid_unknown_fields=True):
    """The `bones:` section of a glove file (every key optional)."""

    wrist: Point2 | None = None
    thumb: Fractions | None = None
    index: Fractions | None = None
    middle: Fractions | None = None
    ring: Fractions | None = None
    little: Fractions | None = None

    def fractions(self, finger: str) -> tuple[float, float, float]:
        given = getattr(self, finger)
        return tuple(given) if given is not None else DEFAULT_FRACTIONS[finger]


def read_bones(data, file=None) -> BonesSection:
    """The `bones:` section (None: all defaults), checked; a mistake is a ConfigError naming `bones.KEY`."""
    if data is None:
        return BonesSection()
    section = schema.convert(data, BonesSection, file, "bones")
    for finger in DEFAULT_FRACTIONS:
        given = getattr(section, finger)
        if given is not None and not math.isclose(sum(given), 1.0, abs_tol=1e-6):
            schema.fail(file, f"bones.{finger}", "three fractions of the finger's length adding up to 1", got=given)
    if section.wrist is not None and not all(math.isfinite(v) for v in section.wrist):
        schema.fail(file, "bones.wrist", "two finite numbers [x, y] (metres)", got=section.wrist)
    return section

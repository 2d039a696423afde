"""Where each finger's joints lie along its capsule: the glove file's optional `bones:` section
(declared in touch4d.glovefile as `Bones`), with human proportions where a file names none.

A finger capsule of the glove file is split into three bones, base to tip: the thumb's metacarpal,
proximal and distal phalanges, each other finger's proximal, intermediate and distal phalanges
(its metacarpal lies inside the palm). `bones: {index: [0.46, 0.30, 0.24], ...}` gives a finger's
bone lengths as fractions of its capsule (adding up to 1); `wrist: [x, y]` (metres, hand frame)
is where the wrist joint lies, by default the middle of the palm's proximal edge. The samples and
motors of the palm move with the wrist joint, those of a finger with the bone they lie in
(touch4d.tactile.skeleton).
"""
from __future__ import annotations

from touch4d.glovefile import Bones

# Phalanx lengths as fractions of the finger, base to tip (after Buchholz et al. 1992, rounded);
# the thumb's capsule starts at its metacarpal, so its first bone is the metacarpal's free part.
DEFAULT_FRACTIONS = {
    "thumb": (0.40, 0.33, 0.27),
    "index": (0.48, 0.29, 0.23),
    "middle": (0.48, 0.30, 0.22),
    "ring": (0.47, 0.31, 0.22),
    "little": (0.46, 0.30, 0.24),
}


def fractions(bones: Bones, finger: str) -> tuple[float, float, float]:
    """A finger's three bone lengths as fractions of its capsule: the file's, else the default."""
    given = getattr(bones, finger)
    return tuple(given) if given is not None else DEFAULT_FRACTIONS[finger]

"""The one tolerance policy of geometry and physics: lengths are compared relative to the bodies' size.

Rounding moves a computed plane or point by about 1e-16 of the coordinates involved (a hull rebuilt
from its own half-spaces has its cells off by that much), so "on a cell", "inside", "the same point"
and "parallel" are decided with a slack of `RELATIVE` times the size of the bodies at hand: small enough
to tell apart anything a scene can hold (a body 1e9 times smaller than another is not one), large
enough for every rounding a chain of transforms and hulls leaves. Angles (dot products of unit
vectors) use `ANGLE`, which needs no scale.
"""
from __future__ import annotations

import numpy as np

RELATIVE = 1e-9     # a length below this fraction of the bodies' size is zero
ANGLE = 1e-9        # a dot product of unit vectors within this of 0 (or +-1) is 0 (or +-1)
POINT = 1e-6        # relative: two points this close are one (a corner typed in a file, a contact point found twice)
HULL = 1e-7         # relative: points this close to a hull facet's plane lie on it (Qhull's own rounding is coarser)


def of(size: float) -> float:
    """The length tolerance among bodies of this size (screen units in, screen units out)."""
    return RELATIVE * float(size)


def size(points) -> float:
    """A point set's size: its largest distance from its centroid (0 for one point)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, np.shape(points)[-1])
    return float(np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).max()))


def extent(*arrays) -> float:
    """The magnitude of the coordinates involved (their largest absolute value; 1 when all are 0):
    the size for a computation whose rounding grows with the coordinates, such as a screen region."""
    top = max((float(np.abs(np.asarray(a, dtype=np.float64)).max(initial=0.0)) for a in arrays), default=0.0)
    return top if top > 0 else 1.0

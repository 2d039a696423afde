"""Clipping a segment to a convex region n.x <= c (Cyrus-Beck), in any dimension: the one clipper of the
contact points (physics) and of hidden edges (visibility).

Compiled with numba so the physics step calls it per edge; from Python it costs a call.
"""
from __future__ import annotations

from touch4d.jit import lazy_njit


@lazy_njit(cache=True, nogil=True)
def clip_segment(p0, p1, normals, offsets, tol):
    """(t0, t1): the part p0 + t (p1 - p0), 0 <= t <= 1, inside every half-space n.x <= c + tol; empty
    when t0 > t1. tol > 0 grows the region (a segment lying on a boundary is kept), tol < 0 shrinks
    it (one on the boundary is outside); the shared tolerance (`tolerance.of`) sizes it."""
    t0, t1 = 0.0, 1.0
    dims = len(p0)
    for c in range(len(offsets)):
        den = 0.0
        num = offsets[c] + tol
        for k in range(dims):
            den += normals[c, k] * (p1[k] - p0[k])
            num -= normals[c, k] * p0[k]
        if den == 0.0:
            if num < 0.0:                        # parallel to this plane and outside it
                return 1.0, 0.0
        elif den > 0.0:
            t1 = min(t1, num / den)
        else:
            t0 = max(t0, num / den)
        if t0 > t1:
            return t0, t1
    return t0, t1

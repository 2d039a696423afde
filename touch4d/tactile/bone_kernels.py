"""The articulated hand's hot loops, compiled with numba: every bone's map from its joints, and the
points placed by their bones' maps.

The tactile loop runs them once per joint set at 1 kHz on 16 bones and ~250 samples; as numpy array
operations they cost more than the rigid hand's whole placing (bench/bench_tactile.py: the joint
sets against the rigid pose). The rotation is geometry.quaternion's quadratic form, passed in.
"""
from __future__ import annotations

import math

from numba import njit

cache = dict(cache=True, nogil=True)


@njit(**cache)
def bone_maps(p, q, base, end, inv_rest2, quadratic, n2_low, n2_high, mirror, scale, out):  # noqa: PLR0913
    """Each bone's map (B, 3, 4) into `out`: [R | t] with R its base joint's rotation (quaternion
    q[base], normalised), its z column times the bone's stretch (length now over its rest length,
    from `inv_rest2` = 1 / rest length^2), x negated for the other hand (`mirror`), x and y times
    `scale` (another scale than the glove's), t the base joint p[base]. False (with `out` partly
    written) when a base joint is not finite, a quaternion's squared norm is outside
    [n2_low, n2_high] or a bone's length is not finite: the caller says which."""
    for k in range(out.shape[0]):
        j, e = base[k], end[k]
        dx, dy, dz = p[e, 0] - p[j, 0], p[e, 1] - p[j, 1], p[e, 2] - p[j, 2]
        stretch = math.sqrt((dx * dx + dy * dy + dz * dz) * inv_rest2[k])
        n2 = q[j, 0] * q[j, 0] + q[j, 1] * q[j, 1] + q[j, 2] * q[j, 2] + q[j, 3] * q[j, 3]
        if not (n2 >= n2_low and n2 <= n2_high and math.isfinite(stretch)):   # NaN fails each (a NaN base: its length)
            return False
        for c in range(9):
            acc = 0.0
            for a in range(4):
                for b in range(4):
                    acc += q[j, a] * q[j, b] * quadratic[4 * a + b, c]
            out[k, c // 3, c % 3] = acc / n2
        for r in range(3):
            out[k, r, 2] *= stretch
            if mirror:
                out[k, r, 0] = -out[k, r, 0]
            out[k, r, 0] *= scale
            out[k, r, 1] *= scale
            out[k, r, 3] = p[j, r]
    return True


@njit(**cache)
def place_points(m, local, bone, out):
    """Points (N, 3) into `out`: each point's local coordinates (N, 3) through its bone's map m[bone]."""
    for i in range(local.shape[0]):
        k = bone[i]
        x, y, z = local[i, 0], local[i, 1], local[i, 2]
        for r in range(3):
            out[i, r] = m[k, r, 0] * x + m[k, r, 1] * y + m[k, r, 2] * z + m[k, r, 3]

"""Unit quaternions (x, y, z, w) for one pose at a time, in plain numpy (and on Python floats:
`product`, `unit`, `rotate`, for a pose's few steps without an array between them).

scipy's Rotation is the reference (the tests compare against it) and reads config, but costs tens
of microseconds per call on single rotations; a tracker at 1 kHz composes several per pose, so the
per-sample path uses these few closed forms instead (bench/bench_tracking.py has the figures).
`to_matrix` is the library's one quaternion -> matrix conversion, for one quaternion or a stack of
them: bench/bench_quaternion.py chose the quadratic form (a stack of 16 or 25 in ~5 us, 6x quicker
than the entries written out and 2.5x than scipy; one quaternion ~1 us slower than written out).
"""
from __future__ import annotations

import math

import numpy as np

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation b followed by a (Hamilton product a * b)."""
    return np.array(product(np.asarray(a, dtype=float).tolist(), np.asarray(b, dtype=float).tolist()))


def product(a, b) -> tuple[float, float, float, float]:
    """`multiply` on Python floats (sequences of four in, a tuple out): numpy's scalars cost ~5x more
    for these sixteen products, and a pose's few steps need no array between them."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def conjugate(q: np.ndarray) -> np.ndarray:
    """The inverse of a unit quaternion."""
    return np.array([-q[0], -q[1], -q[2], q[3]])


def canonical(q: np.ndarray) -> np.ndarray:
    """q and -q are the same rotation; the one with w >= 0, normalised, so equal poses give equal numbers."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = q.tolist()                   # Python floats: ~2x quicker than q @ q and q / n
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        return q / n                          # numpy's answer for a zero (or NaN) quaternion: NaN
    if w < 0:
        n = -n
    return np.array([x / n, y / n, z / n, w / n])


def unit(q) -> tuple[float, float, float, float]:
    """`canonical` on Python floats (a sequence of four in, a tuple out; NaNs for a zero or NaN quaternion)."""
    x, y, z, w = q
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0:
        return (math.nan,) * 4
    if w < 0:
        n = -n
    return (x / n, y / n, z / n, w / n)


def rotate(q, v) -> tuple[float, float, float]:
    """The vector v (three floats) turned by the unit quaternion q (four floats): R(q) v on Python
    floats, as v + 2 w (u x v) + 2 u x (u x v) with u the vector part."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)   # 2 u x v
    return (vx + w * tx + y * tz - z * ty, vy + w * ty + z * tx - x * tz, vz + w * tz + x * ty - y * tx)


def _quadratic_form() -> np.ndarray:
    """C (16, 9) with R.ravel() = (q outer q).ravel() @ C for q = (x, y, z, w): each entry of the
    rotation matrix is a quadratic form of q (the 1 of the diagonal written x2+y2+z2+w2)."""
    c = np.zeros((4, 4, 3, 3))
    x, y, z, w = range(4)
    for (i, j), terms in {
        (0, 0): [(w, w, 1), (x, x, 1), (y, y, -1), (z, z, -1)], (1, 1): [(w, w, 1), (y, y, 1), (x, x, -1), (z, z, -1)],
        (2, 2): [(w, w, 1), (z, z, 1), (x, x, -1), (y, y, -1)],
        (0, 1): [(x, y, 2), (z, w, -2)], (1, 0): [(x, y, 2), (z, w, 2)],
        (0, 2): [(x, z, 2), (y, w, 2)], (2, 0): [(x, z, 2), (y, w, -2)],
        (1, 2): [(y, z, 2), (x, w, -2)], (2, 1): [(y, z, 2), (x, w, 2)],
    }.items():
        for a, b, k in terms:
            c[a, b, i, j] += k
    return c.reshape(16, 9)


QUADRATIC_FORM = _quadratic_form()


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (4,), or matrices (..., 3, 3) of a stack (..., 4):
    the outer products q q^T times QUADRATIC_FORM, one matrix product. Homogeneous: a quaternion of
    norm n gives n^2 times the rotation (divide by q.q to normalise)."""
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        return ((q[:, None] * q).reshape(16) @ QUADRATIC_FORM).reshape(3, 3)
    outer = (q[..., :, None] * q[..., None, :]).reshape(-1, 16)
    return (outer @ QUADRATIC_FORM).reshape(q.shape[:-1] + (3, 3))


def to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (axis times angle in radians, angle <= pi) of a unit quaternion."""
    q = -q if q[3] < 0 else q
    s = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    angle = 2.0 * np.arctan2(s, q[3])
    # angle / sin(angle / 2) -> 2 as the angle -> 0 (series keeps small rotations exact)
    scale = angle / s if s > 1e-8 else 2.0 + angle * angle / 12.0
    return scale * q[:3]


def slerp(a: np.ndarray, b: np.ndarray, u: float) -> np.ndarray:
    """The rotation a fraction u of the shortest way from a to b."""
    dot = float(a @ b)
    if dot < 0:
        b, dot = -b, -dot
    if dot > 0.9995:  # nearly equal: linear interpolation is exact to rounding
        return canonical(a + u * (b - a))
    theta = np.arccos(dot)
    return canonical((np.sin((1 - u) * theta) * a + np.sin(u * theta) * b) / np.sin(theta))

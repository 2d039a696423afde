"""4D rotations and poses: plane rotations (ab turns axis a toward axis b), composition, re-orthonormalisation,
and the controller mapping of paper §4.4."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from touch4d.jit import lazy_njit
from scipy.linalg import expm

AXES = "xyzw"
PLANES = ("xy", "xz", "xw", "yz", "yw", "zw")


def plane_axes(plane: str) -> tuple[int, int]:
    """Axis indices (a, b) of a plane name such as "xw" or "zx" (the order sets the sign)."""
    if not isinstance(plane, str) or len(plane) != 2 or plane[0] == plane[1] or not set(plane) <= set(AXES):
        raise ValueError(f"unknown rotation plane {plane!r}; expected two of x, y, z, w such as 'xw' or 'zx'")
    return AXES.index(plane[0]), AXES.index(plane[1])


def plane_rotation(plane: str, angle_rad: float) -> np.ndarray:
    """4x4 rotation in plane (a, b): x_a' = cos θ x_a − sin θ x_b, x_b' = sin θ x_a + cos θ x_b."""
    a, b = plane_axes(plane)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    r = np.eye(4)
    r[a, a], r[a, b], r[b, a], r[b, b] = c, -s, s, c
    return r


def rotation_from_list(steps) -> np.ndarray:
    """World orientation from [[plane, degrees], ...] applied in order to local coordinates.

    [[xw, 30], [yz, 10]] gives R_yz(10) @ R_xw(30).
    """
    r = np.eye(4)
    for plane, degrees in steps:
        r = plane_rotation(plane, np.radians(degrees)) @ r
    return r


def orthonormalize(r: np.ndarray) -> np.ndarray:
    """The rotation nearest to r (polar decomposition), so long chains of compositions do not drift.

    Works on one 4x4 matrix or a stack (..., 4, 4).
    """
    r = np.asarray(r, dtype=np.float64)
    flat = np.ascontiguousarray(r.reshape(-1, 4, 4))
    return np.array([_nearest(m) for m in flat]).reshape(r.shape)


@lazy_njit(cache=True, nogil=True)
def _nearest(r):
    """The rotation nearest to one 4x4 matrix: U V^T of its SVD, a reflection turned back to +1."""
    u, _, vt = np.linalg.svd(r)
    m = np.ascontiguousarray(u) @ np.ascontiguousarray(vt)
    if np.linalg.det(m) < 0:                    # u's last column turned: U' V^T = U V^T - 2 u_3 v_3^T
        m -= 2.0 * np.outer(u[:, 3], vt[3])
    return m


@lazy_njit(cache=True, nogil=True)
def renormalize(r):
    """The rotation nearest to a near-rotation r (4x4), cheaply: for a running orientation after each update
    (the physics step's, the controller's).

    One Newton-Schulz step r (3I - r^T r) / 2 squares the deviation from orthogonality (1e-16 stays
    at rounding), at a fraction of an SVD's cost; a matrix further than 1e-6 from orthogonal goes
    through the SVD (`orthonormalize`). Compiled, so the physics step calls it too.
    """
    r = np.ascontiguousarray(r)
    e = r.T @ r
    for k in range(4):
        e[k, k] -= 1.0
    if np.abs(e).max() > 1e-6:
        return _nearest(r)
    return r - 0.5 * (r @ e)


def is_rotation(r: np.ndarray, tol: float = 1e-9) -> bool:
    """Orthogonal with determinant +1 (within tol)."""
    r = np.asarray(r, dtype=np.float64)
    return r.shape == (4, 4) and np.allclose(r @ r.T, np.eye(4), atol=tol) and abs(np.linalg.det(r) - 1) < tol


def controller_rotation(dtrans3, drot3, gains=(1.0, 1.0)) -> np.ndarray:
    """4x4 rotation from a controller's motion in one step (paper §4.4).

    dtrans3: translation (x, y, z) -> rotations in xw, yw, zw by translation_gain * component (rad);
    drot3: rotation vector (radians) about x, y, z -> rotations in yz, zx, xy by rotation_gain * component,
    so the xyz block turns exactly as the controller did. gains: (translation_gain rad/unit,
    rotation_gain) or one number for both. The six plane rotations are combined as one exponential of
    their generators, so the result does not depend on an order.
    """
    g_t, g_r = (gains, gains) if np.isscalar(gains) else gains
    t = g_t * np.asarray(dtrans3, dtype=np.float64).reshape(3)
    q = g_r * np.asarray(drot3, dtype=np.float64).reshape(3)
    gen = np.zeros((4, 4))
    for plane, angle in zip(("xw", "yw", "zw", "yz", "zx", "xy"), (*t, *q)):
        a, b = plane_axes(plane)
        gen[b, a] += angle
        gen[a, b] -= angle
    return expm(gen)


@dataclass
class Pose:
    """A 4D position and a 4x4 orientation: x_world = orientation @ x_local + position."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(4))
    orientation: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64).reshape(4)
        self.orientation = np.asarray(self.orientation, dtype=np.float64).reshape(4, 4)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Local (N,4) points to world."""
        return np.asarray(points) @ self.orientation.T + self.position

    def compose(self, other: "Pose") -> "Pose":
        """self after other: x -> self.apply(other.apply(x))."""
        return Pose(self.orientation @ other.position + self.position, self.orientation @ other.orientation)

    def rotated(self, r: np.ndarray) -> "Pose":
        """The same position, orientation turned by world rotation r (about the object's own centre)."""
        return Pose(self.position, orthonormalize(np.asarray(r) @ self.orientation))

    def inverse(self) -> "Pose":
        rt = self.orientation.T
        return Pose(-rt @ self.position, rt)

"""Hand poses: checking them, and placing the glove's sample points in screen coordinates."""
from __future__ import annotations

import math

import numpy as np

from touch4d.errors import Touch4dError
from touch4d.geometry import quaternion

UNIT_TOLERANCE = 1e-3  # as touch4d.messages.hand: a tracker's float32 quaternion passes


class PoseError(Touch4dError, ValueError):
    """A hand pose that cannot be used: names the field (position / orientation) and the problem."""


def check_pose(position, orientation) -> tuple[np.ndarray, np.ndarray]:
    """Return (position (3,), unit quaternion (4,) x,y,z,w) as floats, or raise PoseError."""
    p = np.asarray(position, dtype=float)
    q = np.asarray(orientation, dtype=float)
    if p.shape == (3,) and q.shape == (4,):   # the usual case, in plain floats (quicker for 7 values)
        values = q.tolist()
        if math.isfinite(sum(p.tolist()) + sum(values)):
            norm = math.hypot(*values)
            if abs(norm - 1.0) <= UNIT_TOLERANCE:
                return p, q / norm
    if p.shape != (3,):
        raise PoseError(f"position: expected 3 numbers (x, y, z), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise PoseError(f"position: expected finite numbers, got {p.tolist()}")
    if q.shape != (4,):
        raise PoseError(f"orientation: expected a quaternion of 4 numbers (x, y, z, w), got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise PoseError(f"orientation: expected finite numbers, got {q.tolist()}")
    raise PoseError(f"orientation: expected a unit quaternion (x, y, z, w), got norm {np.sqrt(q @ q):.6g}")


def place(points_m: np.ndarray, units_per_metre: float, position, orientation) -> np.ndarray:
    """Hand-frame points (N, 3) in metres -> screen coordinates (N, 3): rotate, scale, translate."""
    p, q = check_pose(position, orientation)
    rotation = quaternion.to_matrix(q) * units_per_metre
    return points_m @ rotation.T + p

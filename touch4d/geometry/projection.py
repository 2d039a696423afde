"""Projection of the 4D world onto the 3D screen w = 0: orthographic (drop w) or perspective
(eye on the w axis at w = -d), and the projective map that turns perspective into orthographic."""
from __future__ import annotations

import numpy as np

MODES = ("orthographic", "perspective")


def project(points4, mode: str = "orthographic", eye_distance: float | None = None) -> np.ndarray:
    """(N,4) world points -> (N,3) screen points.

    Perspective: where the line from the eye (0,0,0,-d) through the point meets w = 0, i.e.
    x3 * d / (w + d); points must lie in front of the eye (w > -d).
    """
    p = np.asarray(points4, dtype=np.float64)
    if mode == "orthographic":
        return p[..., :3].copy()
    if mode == "perspective":
        d = _eye(eye_distance)
        return p[..., :3] * (d / (p[..., 3:4] + d))
    raise ValueError(f"projection: expected one of {', '.join(MODES)}, got {mode!r}")


def _eye(eye_distance) -> float:
    if eye_distance is None or not float(eye_distance) > 0:
        raise ValueError(f"eye_distance: expected a positive number for perspective, got {eye_distance!r}")
    return float(eye_distance)


def perspective_points(points4, eye_distance: float) -> np.ndarray:
    """The projective map phi(x3, w) = (d x3, w) / (w + d).

    It sends every line through the eye to a line parallel to w, keeps the screen w = 0 fixed and keeps
    the order along each sight line (v = w / (w + d) grows with w), so perspective visibility is
    orthographic visibility of the mapped scene.
    """
    d = _eye(eye_distance)
    p = np.asarray(points4, dtype=np.float64)
    den = p[..., 3:4] + d
    return np.concatenate([p[..., :3] * d, p[..., 3:4]], axis=-1) / den


def perspective_halfspaces(normals, offsets, eye_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-spaces n.x <= c mapped by `perspective_points`, valid in front of the eye (v < 1).

    n3.x3 + n_w w <= c becomes n3.u + (n_w d + c) v <= c; the results are normalised to unit normals.
    """
    d = _eye(eye_distance)
    n = np.array(normals, dtype=np.float64, copy=True)
    c = np.asarray(offsets, dtype=np.float64)
    n[..., 3] = n[..., 3] * d + c
    norm = np.linalg.norm(n, axis=-1)
    norm = np.where(norm > 0, norm, 1.0)
    return n / norm[..., None], c / norm


def perspective_distance(points3, w, eye_distance: float) -> np.ndarray:
    """Distance (eq. 7) from the screen point (x3, 0) to the point at depth w on its sight line."""
    d = _eye(eye_distance)
    p = np.asarray(points3, dtype=np.float64)
    return np.asarray(w) / d * np.sqrt(np.einsum("...i,...i->...", p, p) + d * d)

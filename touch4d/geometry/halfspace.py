"""The half-space kernel that seeing and touching share: which cells face the viewer, where a sight
line enters a convex body, and the clip units of a body's outline (paper §4.3, eq. 4-6).

A convex body is n.x <= c. Everything here works in *view space*: the world itself for orthographic
projection, the image of `projection.perspective_points` for perspective. There every sight line is
parallel to w, the screen is v = 0, and a point is (u, v): u its place on the 3D screen, v a depth
that grows away from the viewer and is affine across a flat face. Along the sight line through u a
half-space n3.u + n_w v <= c

- enters where v = (c - n3.u) / n_w if n_w < -FACING: its cell faces the viewer;
- leaves there if n_w > FACING;
- otherwise runs parallel to the line, which is then inside only if n3.u <= c.

The ray caster (`raycast`), the clip-unit frame build (`touch4d.render.clip`) and the reference
visibility code (`visibility`) all classify and bound with these functions and tolerances; the GPU
renderer's fragment shader asks the same question per pixel in `render/shaders/halfspace.glsl`
(float32, so with its own, documented, tolerances).
"""
from __future__ import annotations

import numpy as np

from . import tolerance
from .projection import perspective_halfspaces

FACING = tolerance.ANGLE     # |n_w| of a unit view normal below this: the cell is edge-on (parallel to the sight lines)
GRAZE = tolerance.of(1.0)    # slack so that a sight line grazing an edge or a cell still counts as a hit (the
                             # screen's size: its half-width, 1 screen unit)


def view_halfspaces(normals, offsets, eye_distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(normals, offsets) in view space: as they are (orthographic) or mapped for perspective (unit
    normals); any leading axes."""
    if eye_distance is None:
        return np.asarray(normals, dtype=np.float64), np.asarray(offsets, dtype=np.float64)
    return perspective_halfspaces(normals, offsets, eye_distance)


def facing(view_normals) -> np.ndarray:
    """(...) bool: the cell faces the viewer (its half-space is where a sight line enters the body).
    Back-cell culling keeps these; edge-on cells do not face the viewer."""
    return np.asarray(view_normals)[..., 3] < -FACING


def kinds(view_normals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks (entering, leaving, parallel) of half-spaces with these view normals."""
    nw = np.asarray(view_normals)[..., 3]
    entering, leaving = nw < -FACING, nw > FACING
    return entering, leaving, ~(entering | leaving)


def depth_bounds(view_normals, view_offsets, points3) -> np.ndarray:
    """The depth v where each half-space's boundary crosses the sight line through a screen point.

    Half-spaces (..., C, 4), (..., C); points (..., 3), broadcast against the half-spaces' leading axes
    (pass (N, 1, 3) against (B, C, 4) for every point and body). Returns (..., C); ±inf or NaN for
    parallel half-spaces: use `kinds` to tell them.
    """
    n = np.asarray(view_normals, dtype=np.float64)
    p = np.asarray(points3, dtype=np.float64)[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        return (view_offsets - np.sum(n[..., :3] * p, axis=-1)) / n[..., 3]


def ray_interval(view_normals, view_offsets, points3, start: float | None = 0.0):
    """The part [enter, leave] of the sight line through a screen point that lies in a body, from depth
    `start` on (None: the whole line), and whether there is one (grazing counts, within GRAZE).

    Shapes as in `depth_bounds`; results (...) without the half-space axis.
    """
    n = np.asarray(view_normals, dtype=np.float64)
    entering, leaving, parallel = kinds(n)
    bound = depth_bounds(n, view_offsets, points3)
    enter = np.max(np.where(entering, bound, -np.inf), axis=-1)
    leave = np.min(np.where(leaving, bound, np.inf), axis=-1)
    if start is not None:
        enter = np.maximum(enter, start)
    slack = view_offsets - np.sum(n[..., :3] * np.asarray(points3, dtype=np.float64)[..., None, :], axis=-1)
    through = np.all(~parallel | (slack >= -GRAZE), axis=-1)
    return enter, leave, through & (enter <= leave + GRAZE)


def entry_depth(view_normals, view_offsets, points3, front=None) -> np.ndarray:
    """Where the sight line through a screen point crosses the body's front: the largest bound of its
    facing cells (`front`, if already known), -inf if none. Where the line meets the body, that is
    where it enters. Shapes as in `depth_bounds`."""
    n = np.asarray(view_normals, dtype=np.float64)
    front = facing(n) if front is None else front
    return np.max(np.where(front, depth_bounds(n, view_offsets, points3), -np.inf), axis=-1)


def clip_units(view_normals, view_offsets, face_cells) -> tuple[np.ndarray, np.ndarray]:
    """The clip units of convex bodies: per 2-face (F, 2 cells), a screen plane [m1, m2, m3, c] (unit m)
    and whether the face is a silhouette ridge (between a facing and a non-facing cell).

    The plane through a ridge that contains the sight lines is the combination s_a n_b - s_b n_a of its
    facing cell a and its other cell b (s = -n_w, how much a cell faces the viewer): it has no w part,
    so it meets the screen in a plane, with the body on its negative side; the intersection of a body's
    units is its projected outline, the region it may hide. Any leading axes (bodies) on the
    half-spaces (..., C, 4), (..., C); planes (..., F, 4), ridge (..., F).
    """
    n = np.asarray(view_normals, dtype=np.float64)
    c = np.asarray(view_offsets, dtype=np.float64)
    fc = np.asarray(face_cells)
    front = facing(n)
    f0, f1 = fc[:, 0], fc[:, 1]
    ridge = front[..., f0] != front[..., f1]
    first_facing = front[..., f0]
    a = np.where(first_facing, f0, f1)
    b = np.where(first_facing, f1, f0)
    n_a = np.take_along_axis(n, a[..., None], axis=-2) if n.ndim > 2 else n[a]
    n_b = np.take_along_axis(n, b[..., None], axis=-2) if n.ndim > 2 else n[b]
    c_a = np.take_along_axis(c, a, axis=-1) if c.ndim > 1 else c[a]
    c_b = np.take_along_axis(c, b, axis=-1) if c.ndim > 1 else c[b]
    s_a, s_b = -n_a[..., 3:4], -n_b[..., 3:4]
    m = s_a * n_b[..., :3] - s_b * n_a[..., :3]
    off = s_a[..., 0] * c_b - s_b[..., 0] * c_a
    norm = np.sqrt(np.sum(m * m, axis=-1))
    ridge &= norm > 1e-12
    safe = np.where(norm > 1e-12, norm, 1.0)
    planes = np.concatenate([m, off[..., None]], axis=-1) / safe[..., None]
    return planes, ridge

"""Visibility for drawing (paper §4.3): back-cell culling, McIntosh's clip units, which object is in front,
and subtracting a hidden region from polygons and segments.

Both projections are handled the same way: perspective is orthographic visibility after the projective
map of `projection.perspective_points` (sight lines become parallel to w, the screen stays fixed). Every
function takes `eye_distance`: None for orthographic, d > 0 for the eye at (0, 0, 0, -d).

A renderer's frame: for each object, draw `visible_faces` / `visible_edges` of its world polytope,
projected with `projection.project`; for each pair with `relations(...)[a, b] == FRONT`, remove from b's
polygons and segments the region a hides, `subtract_polygon(poly, clip_units(a))` /
`subtract_segment(seg, clip_units(a))`.
"""
from __future__ import annotations

from enum import IntEnum

import numpy as np
from scipy.optimize import linprog

from . import halfspace, tolerance
from .halfspace import FACING, view_halfspaces as _view
from .polytope import Polytope
from .projection import perspective_points
from .segment import clip_segment


class Relation(IntEnum):
    """How object a stands to object b, seen from the viewer."""

    BEHIND = -1        # b is nearer on every sight line that meets both
    APART = 0          # no sight line meets both interiors: neither hides the other
    FRONT = 1          # a is nearer on every sight line that meets both: a may hide b
    INTERSECTING = 2   # the interiors overlap in 4D: no order exists


# ---- per object ----------------------------------------------------------------------------------


def view_halfspaces(poly: Polytope, eye_distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(normals, offsets) in view space: as is (orthographic) or mapped for perspective (unit normals)."""
    return _view(poly.normals, poly.offsets, eye_distance)


def view_vertices(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """Vertices in view space; their first three coordinates are the projection on the screen."""
    return poly.vertices if eye_distance is None else perspective_points(poly.vertices, eye_distance)


def facing_cells(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """(C,) bool: the cell's outward normal points toward the viewer (back-cell culling keeps these).

    Orthographic: n_w < 0. Perspective: the eye lies outside the cell's half-space, n.e > c. Edge-on
    cells (normal orthogonal to the sight lines) are not front-facing.
    """
    return halfspace.facing(view_halfspaces(poly, eye_distance)[0])


def visible_faces(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """Indices of the 2-faces that bound at least one front-facing cell (the faces to draw)."""
    front = facing_cells(poly, eye_distance)
    fc = poly.topology.face_cells
    return np.nonzero(front[fc[:, 0]] | front[fc[:, 1]])[0]


def visible_edges(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """Indices into poly.edges of the edges of visible faces."""
    topo = poly.topology
    front = facing_cells(poly, eye_distance)
    face_shown = front[topo.face_cells[:, 0]] | front[topo.face_cells[:, 1]]
    shown = np.zeros(len(topo.edges), dtype=bool)
    shown[topo.face_edges[face_shown[topo.side_faces]]] = True
    return np.nonzero(shown)[0]


def silhouette_faces(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """Indices of the silhouette ridges: 2-faces between a front-facing and a not-front-facing cell."""
    front = facing_cells(poly, eye_distance)
    fc = poly.topology.face_cells
    return np.nonzero(front[fc[:, 0]] != front[fc[:, 1]])[0]


def clip_units(poly: Polytope, eye_distance: float | None = None) -> np.ndarray:
    """(M, 4) rows [m1, m2, m3, c], unit m: the clip units of a convex object as screen half-spaces m.x <= c,
    one per silhouette ridge (`halfspace.clip_units`); their intersection is the object's projected
    silhouette, the region it hides from objects behind it."""
    planes, ridge = halfspace.clip_units(*view_halfspaces(poly, eye_distance), poly.topology.face_cells)
    return planes[ridge]


def in_region(units: np.ndarray, points3, tol: float | None = None) -> np.ndarray:
    """(N,) bool: which screen points lie in the region hidden by an object with these clip units (within
    tol; default the shared tolerance for the coordinates' size)."""
    p = np.atleast_2d(np.asarray(points3, dtype=np.float64))
    tol = _tol(p, units) if tol is None else tol
    return np.all(p @ units[:, :3].T <= units[:, 3] + tol, axis=1)


# ---- front / behind ------------------------------------------------------------------------------


def relation(a: Polytope, b: Polytope, eye_distance: float | None = None) -> Relation:
    """Exact relation of convex objects a and b (see Relation); linear programs decide the hard cases."""
    return Relation(relations([a, b], eye_distance)[0, 1])


def relations(polys: list[Polytope], eye_distance: float | None = None, units: list | None = None) -> np.ndarray:
    """(n, n) int matrix of Relation values, r[a, b] = relation of a to b (r[b, a] = -r[a, b] for FRONT).

    Cheap certificates first: projected bounding boxes apart, or a clip unit separating the projected
    vertices, mean APART; a cell whose hyperplane separates the two objects gives the order (a is in
    front when the viewer is on a's side of it), confirmed by a point common to both projections. Pairs
    left undecided go to two small linear programs (`_relation_lp`). `units`: the objects' clip units if
    already computed for drawing (else computed here, only for objects whose boxes overlap another's).
    """
    count = len(polys)
    out = np.zeros((count, count), dtype=np.int64)
    if count < 2:
        return out
    verts = [view_vertices(p, eye_distance) for p in polys]
    views = [None] * count
    units = list(units) if units is not None else [None] * count
    all_v = np.vstack(verts)
    tol = tolerance.of(tolerance.extent(all_v))
    sizes = np.array([len(v) for v in verts])
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    lo = np.minimum.reduceat(all_v[:, :3], starts, axis=0)
    hi = np.maximum.reduceat(all_v[:, :3], starts, axis=0)
    owner = np.repeat(np.arange(count), sizes)
    # Probe points: each object's vertices and edge midpoints pulled slightly toward its centre, so
    # they are interior points of the object and of its projection.
    centers4 = np.add.reduceat(all_v, starts, axis=0) / sizes[:, None]
    mids = np.vstack([(v[p.edges[:, 0]] + v[p.edges[:, 1]]) / 2 for v, p in zip(verts, polys)])
    mid_owner = np.repeat(np.arange(count), [len(p.edges) for p in polys])
    probes = np.vstack([all_v, mids])
    probe_owner = np.r_[owner, mid_owner]
    probes = np.vstack([probes + 1e-3 * (centers4[probe_owner] - probes), centers4])
    probe_owner = np.r_[probe_owner, np.arange(count)]
    # sep4[a, b]: +1/-1 if a cell of a separates b (a in front / behind), 0 if none does.
    sep4 = np.zeros((count, count), dtype=np.int64)
    apart = np.zeros((count, count), dtype=bool)
    overlap = np.zeros((count, count), dtype=bool)    # a point common to both projections is known
    meet = np.zeros((count, count), dtype=bool)       # a point common to both interiors is known
    boxes_apart = np.any((lo[:, None] >= hi[None] - tol) | (hi[:, None] <= lo[None] + tol), axis=2)
    for i in range(count):
        others = np.nonzero(~boxes_apart[i])[0]
        others = others[others != i]
        if not len(others):
            continue
        views[i] = view_halfspaces(polys[i], eye_distance)
        if units[i] is None:
            units[i] = clip_units(polys[i], eye_distance)
        v = all_v[np.isin(owner, others)]
        at = np.r_[0, np.cumsum(sizes[others])[:-1]]
        pr = np.isin(probe_owner, others)
        probe, probe_of = probes[pr], probe_owner[pr]
        n, c = views[i]
        gap = np.minimum.reduceat(v @ n.T - c, at, axis=0)               # (others, cells of i)
        separating = gap >= -tol
        # Viewer on i's side of the separating hyperplane: its normal points away from the viewer.
        ahead = (separating & (n[:, 3] > FACING)).any(axis=1)
        behind = (separating & (n[:, 3] < -FACING)).any(axis=1)
        sep4[i, others] = np.where(ahead & ~behind, 1, np.where(behind & ~ahead, -1, 0))
        meet[i, probe_of[np.all(probe @ n.T < c - tol, axis=1)]] = True
        m = units[i]
        gap3 = np.minimum.reduceat(v[:, :3] @ m[:, :3].T - m[:, 3], at, axis=0)
        apart[i, others] = (gap3 >= -tol).any(axis=1)
        overlap[i, probe_of[np.all(probe[:, :3] @ m[:, :3].T < m[:, 3] - tol, axis=1)]] = True
    apart = apart | apart.T | boxes_apart
    meet = meet | meet.T
    out[meet & ~apart] = Relation.INTERSECTING
    order = np.where(sep4 != 0, sep4, -sep4.T)
    decided = ~apart & ~meet & (order != 0) & (overlap | overlap.T)
    out[decided] = order[decided]
    for i, j in zip(*np.nonzero(np.triu(~apart & ~meet & ~decided, k=1))):
        r = _relation_lp(views[i], views[j])
        out[i, j] = r
        out[j, i] = -r if r in (Relation.FRONT, Relation.BEHIND) else r
    np.fill_diagonal(out, 0)
    return out


def _relation_lp(ha, hb) -> Relation:
    """Exact relation from two linear programs over view-space half-spaces (normals unit length)."""
    (na, ca), (nb, cb) = ha, hb
    # 1: the deepest common point of a and b; positive depth means the interiors intersect.
    a_ub = np.vstack([np.hstack([na, np.ones((len(na), 1))]), np.hstack([nb, np.ones((len(nb), 1))])])
    res = linprog(np.r_[np.zeros(4), -1.0], A_ub=a_ub, b_ub=np.r_[ca, cb],
                  bounds=[(None, None)] * 4 + [(None, 1.0)], method="highs")
    if res.status == 0 and res.x[4] > 1e-7:
        return Relation.INTERSECTING
    # 2: a screen point x3 with sight-line points (x3, wa) deep in a and (x3, wb) deep in b.
    za, zb = np.zeros((len(na), 1)), np.zeros((len(nb), 1))
    a_ub = np.vstack([np.hstack([na[:, :3], na[:, 3:], za, np.ones((len(na), 1))]),
                      np.hstack([nb[:, :3], zb, nb[:, 3:], np.ones((len(nb), 1))])])
    res = linprog(np.r_[np.zeros(5), -1.0], A_ub=a_ub, b_ub=np.r_[ca, cb],
                  bounds=[(None, None)] * 5 + [(None, 1.0)], method="highs")
    if res.status != 0 or res.x[5] <= 1e-7:
        return Relation.APART
    x3 = res.x[:3]
    # On that sight line the two intervals are disjoint (no intersection): the nearer one is in front.
    mid_a = np.mean(_interval(na, ca, x3))
    mid_b = np.mean(_interval(nb, cb, x3))
    return Relation.FRONT if mid_a < mid_b else Relation.BEHIND


def _interval(n, c, x3):
    """[enter, leave] in w of the line (x3, w) through the half-spaces n.x <= c (assumed to meet it)."""
    enter, leave, _ = halfspace.ray_interval(n, c, x3, start=None)
    return float(enter), float(leave)


# ---- subtracting a hidden region -----------------------------------------------------------------


def subtract_polygon(polygon, units: np.ndarray, eps: float = 1e-12) -> list[np.ndarray]:
    """The part of a convex planar 3D polygon (k,3) outside the region ∩ {m.x <= c} of `units` (M,4).

    Returned as convex polygons (each (k_i,3), cyclic order): piece_j = P ∩ h_1..h_{j-1} ∩ not h_j.
    An empty list means the polygon is entirely hidden; [polygon] means untouched.
    """
    poly = np.asarray(polygon, dtype=np.float64)
    if not len(units):
        return []
    tol = _tol(poly, units)
    side = poly @ units[:, :3].T - units[:, 3]                          # (k, M)
    if np.any(np.all(side >= -tol, axis=0)):
        return [poly]                                                   # entirely outside one unit
    if np.all(side <= tol):
        return []                                                       # entirely hidden
    pieces, rest = [], poly
    for j in np.nonzero(np.any(side > tol, axis=0))[0]:
        m, c = units[j, :3], units[j, 3]
        out = _clip(rest, -m, -c)
        if len(out) >= 3 and _area(out) > eps:
            pieces.append(out)
        rest = _clip(rest, m, c)
        if len(rest) < 3 or _area(rest) <= eps:
            break
    return pieces


def subtract_segment(segment, units: np.ndarray) -> list[np.ndarray]:
    """The part of a 3D segment (2,3) outside the region ∩ {m.x <= c} of `units`, as (2,3) segments: what
    is left either side of the hidden stretch (`segment.clip_segment` to the region shrunk by the shared
    tolerance, so a segment lying on the region's boundary stays whole, as a polygon touching it does)."""
    seg = np.asarray(segment, dtype=np.float64)
    if not len(units):
        return []
    tol = _tol(seg, units)
    p0, d = seg[0], seg[1] - seg[0]
    t0, t1 = clip_segment(p0, seg[1], units[:, :3], units[:, 3], -tol)
    length = float(np.linalg.norm(d))
    if t0 > t1 or (t1 - t0) * length <= tol:
        return [seg]                                                    # nothing of it hidden
    return [np.array([p0 + a * d, p0 + b * d]) for a, b in ((0.0, t0), (t1, 1.0)) if (b - a) * length > tol]


def _tol(points, units: np.ndarray) -> float:
    """The shared tolerance for screen points and clip units: rounding grows with the coordinates."""
    return tolerance.of(tolerance.extent(points, units[:, 3]))


def _clip(poly: np.ndarray, m: np.ndarray, c: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of a convex polygon where m.x <= c."""
    if len(poly) == 0:
        return poly
    f = poly @ m - c
    keep = f <= 0
    if keep.all():
        return poly
    if not keep.any():
        return poly[:0]
    out = []
    k = len(poly)
    for i in range(k):
        j = (i + 1) % k
        if keep[i]:
            out.append(poly[i])
        if keep[i] != keep[j]:
            t = f[i] / (f[i] - f[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.array(out)


def _area(poly: np.ndarray) -> float:
    """Area of a planar 3D polygon."""
    p = poly - poly[0]
    return 0.5 * float(np.linalg.norm(np.cross(p[1:-1], p[2:]).sum(axis=0)))

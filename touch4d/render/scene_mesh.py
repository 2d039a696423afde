"""CPU frame build (paper §4.3): back-cell culling, clip units between bodies, convex pieces, vertex arrays.

Every convex part of every object is a *body*. Bodies with the same local polytope are transformed,
culled and cut together in numpy. Perspective is handled by `projection.perspective_points`, which
maps the scene so that perspective becomes orthographic: afterwards every point is (u, v) with u its
3D screen position and v a depth that grows away from the viewer and varies linearly across a flat
face, so clipping and depth comparisons are the same code for both projections.

Clip units: where a front cell f meets a back cell b of a body, the half-space
m = n_b,w n_f - n_f,w n_b (a non-negative mix of the two cells, with no w part) holds the body and
has the shared 2-face on its boundary, orthogonal to the screen; the silhouette units intersect in the
body's 3D outline. A face or edge of another body is cut by that outline, and the part inside is
dropped when, at an interior point, it lies deeper than the body's front there.

The arrays are small and the cutting runs in short sequential passes, so numpy's per-call cost
dominates: hot paths gather rows with `take`/`compress` (about twice as fast as fancy or boolean
indexing on rows of a few floats) and reduce short axes after moving them first (`_short_axis_first`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from touch4d.geometry.polytope import Polytope
from touch4d.geometry.projection import perspective_halfspaces, perspective_points

FLOATS_PER_VERTEX = 7          # x, y, z, r, g, b, a
_EPS = 1e-9
_TOUCH = 1e-9                 # screen units: closer to an outline than this counts as on it

# Centre copies are colour-coded per cell (local cell index), so a cell keeps its colour as it turns.
CELL_PALETTE = np.array([
    [0.95, 0.33, 0.25], [0.25, 0.70, 0.95], [0.98, 0.80, 0.20], [0.55, 0.35, 0.90],
    [0.20, 0.85, 0.45], [0.95, 0.45, 0.75], [0.10, 0.55, 0.55], [0.90, 0.60, 0.25],
    [0.60, 0.80, 0.20], [0.35, 0.40, 0.95], [0.85, 0.20, 0.45], [0.55, 0.95, 0.85],
])


def cell_color(index) -> np.ndarray:
    """The RGB colour of the centre copy of local cell `index` (array-valued for arrays)."""
    return CELL_PALETTE[np.asarray(index) % len(CELL_PALETTE)]


@dataclass(frozen=True)
class Style:
    """How the scene is drawn: alphas of fills, edges and centre copies; what is shown."""

    fill_alpha: float = 0.18
    edge_alpha: float = 1.0
    centre_scale: float = 0.3
    centre_alpha: float = 0.55
    cell_colors: bool = True      # centre copies in per-cell colours; False: the object's colour
    centres: bool = True
    clip: bool = True             # hidden-hypersurface removal between bodies


@dataclass(frozen=True)
class Body:
    """One convex part of one object, placed: world = orientation @ (size * local) + position."""

    polytope: Polytope
    orientation: np.ndarray
    position: np.ndarray
    size: float
    color: np.ndarray
    object_index: int = 0


@dataclass
class SceneMesh:
    """Vertex arrays (float32, FLOATS_PER_VERTEX per vertex) for one frame, and what was seen."""

    fills: np.ndarray         # triangles of visible 2-faces
    centres: np.ndarray       # triangles of the centre copies of visible cells
    edges: np.ndarray         # line segments (vertex pairs)
    visible_cells: list = field(default_factory=list)   # per body: local indices of front cells
    bounds: np.ndarray | None = None                     # per body (2,3) screen bounding box

    @property
    def counts(self) -> dict:
        return {"fill_triangles": len(self.fills) // 3, "centre_triangles": len(self.centres) // 3,
                "edge_segments": len(self.edges) // 2}


def empty_vertices() -> np.ndarray:
    return np.zeros((0, FLOATS_PER_VERTEX), np.float32)


class _Template:
    """What a local polytope needs per frame, precomputed once: padded faces, edge-cell incidence."""

    def __init__(self, poly: Polytope):
        self.polytope = poly           # keeps the topology alive while cached by id
        topo = poly.topology
        faces = topo.faces
        self.vertices = poly.vertices
        self.normals = poly.normals
        self.offsets = poly.offsets
        self.face_cells = np.asarray(topo.face_cells)
        width = max(len(f) for f in faces)
        # Padding repeats a face's first vertex: bounding boxes and inside tests stay exact.
        self.face_index = np.array([np.r_[f, np.full(width - len(f), f[0])] for f in faces], np.int64)
        self.face_count = np.array([len(f) for f in faces], np.int64)
        n_cells = len(poly.normals)
        cells_of_edge = [np.unique(self.face_cells[fs]) for fs in topo.edge_faces]
        width = max(len(c) for c in cells_of_edge)
        # The cells around each edge, padded by repeating one: an edge shows if any of them faces us.
        self.edge_cells = np.array([np.r_[c, np.full(width - len(c), c[0])] for c in cells_of_edge], np.int64)
        self.edges = np.asarray(topo.edges)
        self.centre_face = np.concatenate([np.asarray(fs) for fs in topo.cell_faces]).astype(np.int64)
        self.centre_cell = np.repeat(np.arange(n_cells), [len(fs) for fs in topo.cell_faces])
        self.cell_centroids = np.array([poly.vertices[vs].mean(axis=0) for vs in topo.cell_vertices])


@dataclass
class _Frame:
    """What the last clipped build cut, kept so that bodies whose pose and hiders stay can reuse it."""

    setting: tuple
    keys: list
    hides: np.ndarray
    polys: tuple          # pieces: vertices, counts, body, index among the body's polygons
    segs: tuple           # pieces: vertices, body, index among the body's segments


class MeshBuilder:
    """Builds `SceneMesh` frames; keeps the per-shape templates, and the last frame's cut pieces so
    that a body whose pose did not change (nor that of any body in front of it) is not cut again."""

    def __init__(self):
        self._templates: dict[int, _Template] = {}
        self._frame: _Frame | None = None

    def template(self, poly: Polytope) -> _Template:
        key = id(poly.topology)
        t = self._templates.get(key)
        if t is None or t.polytope.topology is not poly.topology or t.polytope.vertices is not poly.vertices:
            if len(self._templates) > 256:
                self._templates.clear()
            t = self._templates[key] = _Template(poly)
        return t

    def build(self, bodies: list[Body], projection: str = "orthographic", eye_distance: float = 3.0,
              style: Style = Style()) -> SceneMesh:
        """One frame's vertex arrays from the bodies (world placement, colours) and the projection."""
        perspective = projection == "perspective"
        groups: dict[int, list[int]] = {}
        for i, body in enumerate(bodies):
            groups.setdefault(id(self.template(body.polytope)), []).append(i)

        polys, segs, clips = [], [], []
        visible = [None] * len(bodies)
        bounds = np.zeros((len(bodies), 2, 3))
        for members in groups.values():
            t = self.template(bodies[members[0]].polytope)
            g = _place_group(t, [bodies[i] for i in members], perspective, eye_distance, style)
            ids = np.asarray(members)
            polys.append(_with_body(g["polys"], ids))
            segs.append(_with_body(g["segs"], ids))
            clips.append((ids, g["clip"]))
            for k, i in enumerate(members):
                visible[i] = np.nonzero(g["front"][k])[0]
            bounds[ids] = g["bounds"]

        poly_v, poly_c, poly_rgba, poly_body, poly_kind = _concat_polys(polys)
        seg_v, seg_rgba, seg_body = _concat_segs(segs)
        frame, self._frame = self._frame, None
        if style.clip and len(bodies) > 1:
            setting = (perspective, float(eye_distance) if perspective else 0.0, style)
            # The template object itself (compared by identity) and the exact pose: colours may change freely.
            keys = [(self.template(b.polytope), np.asarray(b.orientation, float).tobytes(),
                     np.asarray(b.position, float).tobytes(), float(b.size)) for b in bodies]
            if frame is None or frame.setting != setting or len(frame.keys) != len(keys):
                frame, changed = None, np.ones(len(bodies), bool)
            else:
                changed = np.array([k != old for k, old in zip(keys, frame.keys)], bool)
            occ = _Occluders(clips, bounds, len(bodies), None if frame is None else (frame.hides, changed))
            redo = changed.copy()
            if frame is not None:         # a body is cut again if it moved or a moved body hid or hides it
                redo |= (frame.hides[changed] | occ.hides[changed]).any(axis=0)
                if redo.all():
                    frame = None
            poly_v, poly_c, src, pieces = _cut_reusing(
                lambda sel: _cut_polygons(poly_v[sel], poly_c[sel], poly_body[sel], occ),
                poly_body, redo, None if frame is None else frame.polys)
            poly_rgba, poly_kind = poly_rgba.take(src, axis=0), poly_kind.take(src)
            seg_v, src, seg_pieces = _cut_reusing(
                lambda sel: _cut_segments(seg_v[sel], seg_body[sel], occ),
                seg_body, redo, None if frame is None else frame.segs)
            seg_rgba = seg_rgba.take(src, axis=0)
            self._frame = _Frame(setting, keys, occ.hides, pieces, seg_pieces)
        fills = _triangles(*_compress(poly_kind == 0, poly_v, poly_c, poly_rgba))
        centres = _triangles(*_compress(poly_kind == 1, poly_v, poly_c, poly_rgba))
        edges = np.empty((len(seg_v), 2, FLOATS_PER_VERTEX), np.float32)
        edges[..., :3] = seg_v[..., :3]
        edges[..., 3:] = seg_rgba[:, None]
        return SceneMesh(fills, centres, edges.reshape(-1, FLOATS_PER_VERTEX), visible, bounds)


def _cut_reusing(cut, body: np.ndarray, redo: np.ndarray, previous: tuple | None):
    """Cut the items (polygons or segments, owner `body`) of the bodies in `redo` with `cut(selection)`
    (-> arrays of pieces..., source index into the selection) and take the others' pieces from
    `previous`. Returns the pieces' arrays, their source indices (ascending; a source's pieces keep
    the order the cut made them in) and what the next frame may reuse."""
    n_bodies = len(redo)
    order = np.argsort(body, kind="stable")
    starts = np.searchsorted(body[order], np.arange(n_bodies))
    local = np.empty(len(body), np.int64)
    local[order] = np.arange(len(body)) - starts[body[order]]
    if previous is None:
        *parts, src = cut(slice(None))
    else:
        sel = np.nonzero(redo[body])[0]
        *parts, src = cut(sel)
        src = sel[src]
        *old_parts, old_body, old_local = previous
        keep = ~redo[old_body]
        parts = [_join_items(new, old[keep]) for new, old in zip(parts, old_parts)]
        src = np.concatenate([src, order[starts[old_body[keep]] + old_local[keep]]])
    by_src = np.argsort(src, kind="stable")
    parts, src = [p.take(by_src, axis=0) for p in parts], src.take(by_src)
    return (*parts, src, (*parts, body[src], local[src]))


def _join_items(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Concatenate item arrays; polygons (P, K, 4) of different widths are padded first."""
    if a.ndim == 3 and a.shape[1] != b.shape[1]:
        width = max(a.shape[1], b.shape[1])
        a, b = _pad_width(a, width), _pad_width(b, width)
    return np.concatenate([a, b])


def _with_body(arrays: dict, ids: np.ndarray) -> dict:
    out = dict(arrays)
    out["body"] = ids[arrays["group_index"]]
    return out


def _place_group(t: _Template, bodies: list[Body], perspective: bool, eye: float, style: Style) -> dict:
    """Transform, cull and collect the drawable polygons, segments and clip units of same-shape bodies."""
    rot = np.stack([b.orientation for b in bodies])
    pos = np.stack([b.position for b in bodies])
    size = np.array([b.size for b in bodies], dtype=float)
    color = np.stack([b.color for b in bodies])
    n_g = len(bodies)

    world = size[:, None, None] * np.matmul(t.vertices, rot.transpose(0, 2, 1)) + pos[:, None]
    normals = np.matmul(t.normals, rot.transpose(0, 2, 1))
    offsets = size[:, None] * t.offsets + np.einsum("gci,gi->gc", normals, pos)
    centroids = size[:, None, None] * np.matmul(t.cell_centroids, rot.transpose(0, 2, 1)) + pos[:, None]
    if perspective:
        # Map to the space where perspective is orthographic; depth v = w / (w + d).
        world_mapped = perspective_points(world, eye)
        normals, offsets = perspective_halfspaces(normals, offsets, eye)
    else:
        world_mapped = world

    front = normals[..., 3] < -_EPS                                    # (G, C) back-cell culling
    f0, f1 = t.face_cells[:, 0], t.face_cells[:, 1]
    face_vis = front[:, f0] | front[:, f1]
    around = front[:, t.edge_cells]                                    # (G, E, cells per edge)
    edge_vis = around[..., 0].copy()
    for k in range(1, around.shape[2]):                                # a few columns: faster than any()
        edge_vis |= around[..., k]

    gi, fi = np.nonzero(face_vis)
    n_v = world.shape[1]
    face_v = _take_points(world_mapped.reshape(-1, 4), gi[:, None] * n_v + t.face_index[fi])  # (Pf, K, 4)
    face_rgba = _with_alpha(color, gi, style.fill_alpha)

    parts_v, parts_c, parts_rgba, parts_g, parts_kind = [face_v], [t.face_count[fi]], [face_rgba], [gi], [np.zeros(len(gi), int)]
    if style.centres:
        gc, pc = np.nonzero(front[:, t.centre_cell])
        cell = t.centre_cell[pc]
        cen = centroids[gc, cell][:, None]
        corners = _take_points(world.reshape(-1, 4), gc[:, None] * n_v + t.face_index[t.centre_face[pc]])
        centre_world = cen + style.centre_scale * (corners - cen)
        centre_v = perspective_points(centre_world, eye) if perspective else centre_world
        rgb = cell_color(cell) if style.cell_colors else color[gc, :3]
        parts_v.append(centre_v)
        parts_c.append(t.face_count[t.centre_face[pc]])
        parts_rgba.append(_with_alpha(color, gc, style.centre_alpha, rgb))
        parts_g.append(gc)
        parts_kind.append(np.ones(len(gc), int))

    ge, ei = np.nonzero(edge_vis)
    seg_v = _take_points(world_mapped.reshape(-1, 4), ge[:, None] * n_v + t.edges[ei])   # (S, 2, 4)
    seg_rgba = _with_alpha(color, ge, style.edge_alpha)

    # Clip units on silhouette faces (front cell against back cell), compacted per body.
    sil = front[:, f0] != front[:, f1]
    fr = np.where(front[:, f0], f0, f1)
    bk = np.where(front[:, f0], f1, f0)
    g_idx = np.arange(n_g)[:, None]
    n_f, n_b = normals[g_idx, fr], normals[g_idx, bk]
    d_f, d_b = offsets[g_idx, fr], offsets[g_idx, bk]
    m = n_b[..., 3:4] * n_f - n_f[..., 3:4] * n_b
    dm = n_b[..., 3] * d_f - n_f[..., 3] * d_b
    norm = np.sqrt(m[..., 0] ** 2 + m[..., 1] ** 2 + m[..., 2] ** 2)
    sil &= norm > 1e-12
    planes = np.concatenate([m[..., :3], dm[..., None]], axis=-1) / np.where(norm > 1e-12, norm, 1.0)[..., None]
    order = np.argsort(~sil, axis=1, kind="stable")
    width = max(int(sil.sum(axis=1).max(initial=0)), 1)
    planes = np.take_along_axis(planes, order[..., None], axis=1)[:, :width]
    keep = np.take_along_axis(sil, order, axis=1)[:, :width]
    planes[~keep] = _DUMMY_PLANE

    return {
        "front": front,
        "bounds": np.stack(_extent(world_mapped), axis=1),
        "polys": {"v": np.concatenate(parts_v), "count": np.concatenate(parts_c),
                  "rgba": np.concatenate(parts_rgba), "group_index": np.concatenate(parts_g),
                  "kind": np.concatenate(parts_kind)},
        "segs": {"v": seg_v, "rgba": seg_rgba, "group_index": ge},
        "clip": {"planes": planes, "normals": normals, "offsets": offsets, "front": front,
                 "vertices": world_mapped},
    }


def _with_alpha(color: np.ndarray, index: np.ndarray, alpha: float, rgb: np.ndarray | None = None) -> np.ndarray:
    """RGBA rows for bodies `index`: their colour (or `rgb`) with their alpha scaled by `alpha`."""
    out = np.empty((len(index), 4))
    picked = color.take(index, axis=0)
    out[:, :3] = picked[:, :3] if rgb is None else rgb
    out[:, 3] = picked[:, 3] * alpha
    return out


# A plane every point is inside of (0.x - 1 <= 0): pads clip-unit lists.
_DUMMY_PLANE = np.array([0.0, 0.0, 0.0, 1.0])


def _concat_polys(polys: list[dict]):
    if not polys or sum(len(p["v"]) for p in polys) == 0:
        return (np.zeros((0, 3, 4)), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0, np.int64),
                np.zeros(0, np.int64))
    width = max(p["v"].shape[1] for p in polys)
    vs = [_pad_width(p["v"], width) for p in polys]
    return (np.concatenate(vs), np.concatenate([p["count"] for p in polys]),
            np.concatenate([p["rgba"] for p in polys]), np.concatenate([p["body"] for p in polys]),
            np.concatenate([p["kind"] for p in polys]))


def _concat_segs(segs: list[dict]):
    if not segs:
        return np.zeros((0, 2, 4)), np.zeros((0, 4)), np.zeros(0, np.int64)
    return (np.concatenate([s["v"] for s in segs]), np.concatenate([s["rgba"] for s in segs]),
            np.concatenate([s["body"] for s in segs]))


def _compress(mask: np.ndarray, *arrays: np.ndarray) -> tuple:
    """The items (first axis) of each array where `mask` holds; `compress` copies rows about twice
    as fast as boolean indexing."""
    return tuple(a.compress(mask, axis=0) for a in arrays)


def _short_axis_first(a: np.ndarray, axis: int = 1) -> np.ndarray:
    """`a` with its short `axis` moved first, as a contiguous copy, to be reduced over axis 0.

    numpy reduces a short axis lying inside each row several times slower than one running across
    long contiguous rows; the copy costs less than the difference (measured 3-4x on the builder's
    vertex arrays)."""
    return np.ascontiguousarray(np.moveaxis(a, axis, 0))


def _extent(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Screen bounding boxes (lo, hi), each (N, 3), of point sets v (N, K, >=3)."""
    u = _short_axis_first(v[..., :3])
    return u.min(axis=0), u.max(axis=0)


def _pad_width(v: np.ndarray, width: int) -> np.ndarray:
    """Pad polygons (P, K, 4) to `width` vertices by repeating each polygon's first vertex."""
    if v.shape[1] >= width:
        return v
    return np.concatenate([v, np.repeat(v[:, :1], width - v.shape[1], axis=1)], axis=1)


class _Occluders:
    """Every body's clip units (padded), front cells (for depth) and screen bounds, indexed by body."""

    def __init__(self, clips: list, bounds: np.ndarray, n_bodies: int, previous: tuple | None = None):
        m_width = max(c["planes"].shape[1] for _, c in clips)
        c_width = max(c["normals"].shape[1] for _, c in clips)
        self.planes = np.tile(_DUMMY_PLANE, (n_bodies, m_width, 1))
        self.normals = np.zeros((n_bodies, c_width, 4))
        self.normals[..., 3] = -1.0
        self.offsets = np.zeros((n_bodies, c_width))
        self.front = np.zeros((n_bodies, c_width), bool)
        v_width = max(c["vertices"].shape[1] for _, c in clips)
        self.vertices = np.zeros((n_bodies, v_width, 4))
        for ids, c in clips:
            self.vertices[ids] = _pad_width(c["vertices"], v_width)
            self.planes[ids, :c["planes"].shape[1]] = c["planes"]
            self.normals[ids, :c["normals"].shape[1]] = c["normals"]
            self.offsets[ids, :c["offsets"].shape[1]] = c["offsets"]
            self.front[ids, :c["front"].shape[1]] = c["front"]
        self.bounds = bounds
        lo, hi = bounds[:, 0], bounds[:, 1]
        overlap = np.ones((n_bodies, n_bodies), bool)
        for axis in range(3):            # per axis, not all() over a length-3 axis: several times faster
            overlap &= (lo[:, None, axis] <= hi[None, :, axis] + 1e-9) & (hi[:, None, axis] >= lo[None, :, axis] - 1e-9)
        np.fill_diagonal(overlap, False)
        self.overlap = overlap
        self.hides = self._order(overlap, previous)

    def _order(self, overlap: np.ndarray, previous: tuple | None) -> np.ndarray:
        """hides[a, b]: body a may hide body b (a is in front of b where they overlap, or unknown).

        Two disjoint convex bodies are ordered the same at every screen point they share; such a
        point is the mean of the vertices of each that project inside the other's outline.
        `previous` (hides, changed): the last frame's order, kept for pairs of bodies that did not move."""
        hides = overlap.copy()
        i, j = np.nonzero(np.triu(overlap))
        if previous is not None:
            old, changed = previous
            moved = changed[i] | changed[j]
            i_old, j_old = i[~moved], j[~moved]
            hides[i_old, j_old], hides[j_old, i_old] = old[i_old, j_old], old[j_old, i_old]
            i, j = i[moved], j[moved]
        if len(i) == 0:
            return hides
        # Most overlapping boxes hold bodies whose outlines are apart: the first test settles those,
        # so the second direction and the depth test run on the few pairs left.
        v_i = self.vertices.take(i, axis=0)
        in_j, apart = self._inside(v_i, j)
        hides[i[apart], j[apart]] = hides[j[apart], i[apart]] = False
        i, j, v_i, in_j = i[~apart], j[~apart], v_i[~apart], in_j[~apart]
        v_j = self.vertices.take(j, axis=0)
        in_i, apart = self._inside(v_j, i)
        hides[i[apart], j[apart]] = hides[j[apart], i[apart]] = False
        i, j, v_i, v_j, in_i, in_j = i[~apart], j[~apart], v_i[~apart], v_j[~apart], in_i[~apart], in_j[~apart]
        total = (_short_axis_first(v_i * in_j[..., None]).sum(axis=0)
                 + _short_axis_first(v_j * in_i[..., None]).sum(axis=0))
        n = _short_axis_first(in_j).sum(axis=0) + _short_axis_first(in_i).sum(axis=0)
        known = n > 0
        p = total[known, :3] / n[known, None]
        i, j = i[known], j[known]
        di, dj = self.front_depth(i, p), self.front_depth(j, p)
        i_front, j_front = di < dj - 1e-7, dj < di - 1e-7
        hides[j[i_front], i[i_front]] = False
        hides[i[j_front], j[j_front]] = False
        return hides

    def _inside(self, points: np.ndarray, body: np.ndarray):
        """For points (Q, V, 4) and bodies (Q,): which project inside the body's outline (Q, V), and
        whether all lie beyond one of its clip units (Q,), so the two outlines are apart."""
        planes = self.planes.take(body, axis=0)
        s = _plane_values(planes, points)                                      # (M, V, Q)
        return (s.max(axis=0) <= _TOUCH).T, (s.min(axis=1) > _TOUCH).any(axis=0)

    def front_depth(self, body: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Depth v where the sight line through screen point u (Q,3) enters `body` (Q,): its front."""
        n = self.normals.take(body, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (self.offsets.take(body, axis=0) - np.matmul(n[..., :3], u[..., None])[..., 0]) / n[..., 3]
        return _short_axis_first(np.where(self.front.take(body, axis=0), depth, -np.inf)).max(axis=0)

    def candidates(self, lo: np.ndarray, hi: np.ndarray, own: np.ndarray):
        """(item, body, rank) for items (bounding boxes lo, hi (N,3), owner body) that other bodies may hide."""
        hidden, hider = np.nonzero(self.hides.T)                    # grouped by the hidden body
        starts = np.searchsorted(hidden, np.arange(len(self.hides) + 1))
        n_hiders = np.diff(starts)[own]
        item = np.repeat(np.arange(len(own)), n_hiders)
        first = np.repeat(starts[own], n_hiders)
        b = hider[first + np.arange(len(item)) - np.repeat(np.cumsum(n_hiders) - n_hiders, n_hiders)]
        b_box = self.bounds.take(b, axis=0)
        meets = (lo.take(item, axis=0) <= b_box[:, 1] + 1e-9) & (hi.take(item, axis=0) >= b_box[:, 0] - 1e-9)
        hit = meets[:, 0] & meets[:, 1] & meets[:, 2]
        item, b = item[hit], b[hit]
        rank = np.arange(len(item)) - np.searchsorted(item, item)   # 0, 1, ... within each item
        return item, b, rank


def _plane_values(planes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """n.u - d for planes (Q, M, 4) and points (Q, K, >=3), as (M, K, Q): positive outside.

    The pair axis Q comes last so that reductions over planes or vertices (short axes) run along
    long contiguous rows; numpy reduces a short innermost axis an order of magnitude slower. The
    points go in homogeneous (u, -1), so one stacked matmul on contiguous operands gives n.u - d
    (measured ~1.4x faster than a matmul on strided xyz views followed by a subtraction)."""
    q, k = points.shape[:2]
    homogeneous = np.empty((q, 4, k))
    homogeneous[:, :3] = points[..., :3].transpose(0, 2, 1)
    homogeneous[:, 3] = -1.0
    s = np.matmul(planes, homogeneous)                                        # (Q, M, K)
    return np.ascontiguousarray(s.transpose(1, 2, 0))


def _cut_polygons(v: np.ndarray, count: np.ndarray, body: np.ndarray, occ: _Occluders):
    """Remove what other bodies hide from convex polygons; returns pieces and each piece's source index."""
    src = np.arange(len(v))
    if len(v) == 0:
        return v, count, src
    item, b, rank = occ.candidates(*_extent(v), body)
    # Drop pairs where the polygon lies outside one clip unit; keep each pair's straddled units.
    # A polygon lying on the outline's boundary counts as inside, so coplanar faces get hidden.
    s = _plane_values(occ.planes.take(b, axis=0), v.take(item, axis=0))
    near = (s.min(axis=1) <= _TOUCH).all(axis=0)
    item, b = item[near], b[near]
    if len(item) == 0:
        return v, count, src
    rank = np.arange(len(item)) - np.searchsorted(item, item)

    # Only polygons some body may hide take part; the others pass unchanged.
    touched = np.zeros(len(v), bool)
    touched[item] = True
    work_src = np.nonzero(touched)[0]
    wv, wc = v.take(work_src, axis=0), count.take(work_src)
    for r in range(int(rank.max()) + 1):
        at = rank == r
        pair_of_src = np.full(len(v), -1)
        pair_of_src[item[at]] = np.nonzero(at)[0]
        pair = pair_of_src[work_src]
        act = pair >= 0
        pv, pc, parent = _subtract(*_compress(act, wv, wc), b[pair[act]], occ)
        rest_v, rest_c, rest_src = _compress(~act, wv, wc, work_src)
        wv = np.concatenate([_pad_width(rest_v, pv.shape[1]), _pad_width(pv, wv.shape[1])])
        wc = np.concatenate([rest_c, pc])
        work_src = np.concatenate([rest_src, work_src[act][parent]])
    keep = ~touched
    width = max(v.shape[1], wv.shape[1])
    v, count, src = _compress(keep, v, count, src)
    return (np.concatenate([_pad_width(v, width), _pad_width(wv, width)]),
            np.concatenate([count, wc]), np.concatenate([src, work_src]))


def _subtract(v, count, body, occ: _Occluders):
    """Pieces of each polygon outside `body`'s outline if it is behind the body there.

    Only the clip units that cross a polygon cut it, one after the other: piece j lies inside units
    1..j-1 and outside unit j; what is left is inside the outline. Returns (pieces, counts, parent
    index into the inputs)."""
    planes = occ.planes.take(body, axis=0)
    s_all = _plane_values(planes, v)                                           # (M, K, Q)
    low, high = s_all.min(axis=1), s_all.max(axis=1)                           # (M, Q)
    straddle = (high > _TOUCH) & (low < -_TOUCH)
    # Per polygon, the units crossing it, the one it reaches farthest beyond first: the big cuts
    # come early and often leave the rest inside later units, which then need no cut (fewer pieces).
    order = np.argsort(np.where(straddle, -high, np.inf), axis=0, kind="stable")
    apart = (low > _TOUCH).any(axis=0)                           # outside one unit: nothing hidden
    n_cuts = np.where(apart, 0, straddle.sum(axis=0))
    rem_v, rem_c = v.copy(), np.where(apart, 0, count)
    outs_v, outs_c, outs_p = [], [], []
    for j in range(int(n_cuts.max(initial=0))):
        rows = np.nonzero((n_cuts > j) & (rem_c >= 3))[0]
        if len(rows) == 0:
            break
        if j == 0:
            s = s_all[order[0, rows], :, rows]
        else:
            plane = planes[rows, order[j, rows]]
            s = np.matmul(rem_v.take(rows, axis=0)[..., :3], plane[:, :3, None])[..., 0] - plane[:, 3:4]
            need = s.max(axis=1) > _TOUCH             # earlier cuts may have left it inside this unit
            rows, s = rows[need], s[need]
            if len(rows) == 0:
                continue
        in_v, in_c, out_v, out_c = _split(rem_v.take(rows, axis=0), rem_c[rows], s, rem_v.shape[1])
        outs_v.append(out_v)
        outs_c.append(out_c)
        outs_p.append(rows)
        rem_v = _pad_width(rem_v, in_v.shape[1])        # grows only when a cut adds a vertex
        rem_v[rows] = in_v
        rem_c[rows] = in_c
    # Depth test at an interior point of the overlap: the mean of the remainder's vertices.
    overlap = rem_c >= 3
    k = np.arange(rem_v.shape[1])[None] < rem_c[:, None]
    mean = _short_axis_first(rem_v * k[..., None]).sum(axis=0) / np.maximum(rem_c, 1)[:, None]
    hidden = overlap & (mean[:, 3] > occ.front_depth(body, mean[:, :3]) + 1e-9)

    width = max([o.shape[1] for o in outs_v] + [v.shape[1]])
    shown_v, shown_c = _compress(~hidden, v, count)
    keep_v, keep_c, keep_p = [_pad_width(shown_v, width)], [shown_c], [np.nonzero(~hidden)[0]]
    for ov, oc, op in zip(outs_v, outs_c, outs_p):
        h = hidden[op] & (oc >= 3)
        keep_v.append(_pad_width(ov.compress(h, axis=0), width))
        keep_c.append(oc[h])
        keep_p.append(op[h])
    return np.concatenate(keep_v), np.concatenate(keep_c), np.concatenate(keep_p)


def _split(v: np.ndarray, count: np.ndarray, s: np.ndarray, width: int = 1):
    """Sutherland-Hodgman for a batch of convex polygons, each against its own plane.

    Returns the pieces with s <= 0 and with s >= 0, as (vertices, counts) each, at least `width`
    vertices wide."""
    q, k = s.shape
    rows = np.arange(q)[:, None]
    col = np.arange(k)[None]
    valid = col < count[:, None]
    nxt = rows * k + (col + 1) % np.maximum(count, 1)[:, None]   # flat index of the next vertex
    s_n = s.reshape(-1).take(nxt)
    inside = s <= 0
    cross = valid & (inside != (s_n <= 0))
    t = s / np.where(cross, s - s_n, 1.0)       # only used where the edge crosses
    # Each vertex emits itself (if on the kept side) and then the crossing on its edge (if any).
    pts = np.empty((q, k, 2, 4))
    pts[:, :, 0] = v
    pts[:, :, 1] = v + t[..., None] * (_take_points(v.reshape(-1, 4), nxt) - v)
    emit = np.empty((2, q, k, 2), bool)
    emit[0, :, :, 0] = valid & inside
    emit[1, :, :, 0] = valid & ~inside
    emit[:, :, :, 1] = cross
    out, new_count = _compact(pts.reshape(q, 2 * k, 4), emit.reshape(2, q, 2 * k), width)
    return out[0], new_count[0], out[1], new_count[1]


def _compact(pts: np.ndarray, emit: np.ndarray, min_width: int = 1):
    """Keep the emitted points (emit (S, Q, L)) of each row of pts (Q, L, 4) in order, padded with
    the row's first kept point; returns (S, Q, width >= min_width, 4) and counts (S, Q).

    Built by one gather: output slot c of a row takes the row's c-th emitted point (its first one
    past the end); rows with no point are zeros."""
    n_sides, q, length = emit.shape
    flat = np.flatnonzero(emit)                                  # sorted: row by row, in order
    per_row = np.bincount(flat // length, minlength=n_sides * q)   # not a sum over the short axis: slow
    counts = per_row.reshape(n_sides, q)
    width = max(int(per_row.max(initial=0)), min_width)
    if len(flat) == 0:
        return np.zeros((n_sides, q, width, 4)), counts
    starts = np.cumsum(per_row) - per_row
    col = np.arange(width)
    slot = np.minimum(starts[:, None] + np.where(col < per_row[:, None], col, 0), len(flat) - 1)
    out = _as_points(pts.reshape(-1, 4)).take((flat % (q * length)).take(slot))
    empty = per_row == 0
    if empty.any():
        out[empty] = np.zeros((), _POINT)
    return out.view(np.float64).reshape(n_sides, q, width, 4), counts


# One 4D point (4 float64) as a single opaque item: numpy gathers and scatters such items 2-4x faster
# than rows of a (N, 4) float array, and the splitting loop moves little else.
_POINT = np.dtype((np.void, 4 * 8))


def _as_points(a: np.ndarray) -> np.ndarray:
    """View (N, 4) float64 points as N opaque items (copying first if not contiguous)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(_POINT)[:, 0]


def _take_points(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a[index] for points a (N, 4): float64 array of shape index.shape + (4,)."""
    return _as_points(a).take(index).view(np.float64).reshape(*np.shape(index), 4)


def _cut_segments(v: np.ndarray, body: np.ndarray, occ: _Occluders):
    """Remove what other bodies hide from segments (S, 2, 4); returns pieces and source indices."""
    src = np.arange(len(v))
    if len(v) == 0:
        return v, src
    item, b, rank = occ.candidates(*_extent(v), body)
    for r in range(int(rank.max(initial=-1)) + 1):
        at = rank == r
        pair_of_src = np.full(len(body), -1)
        pair_of_src[item[at]] = b[at]
        occluder = pair_of_src[src]
        act = occluder >= 0
        if not act.any():
            continue
        pv, parent = _subtract_segments(v.compress(act, axis=0), occluder[act], occ)
        rest_v, rest_src = _compress(~act, v, src)
        v = np.concatenate([rest_v, pv])
        src = np.concatenate([rest_src, src[act][parent]])
    return v, src


def _subtract_segments(v: np.ndarray, body: np.ndarray, occ: _Occluders):
    """Cyrus-Beck: the part of each segment inside the body's outline, dropped where behind the body."""
    a, d = v[:, 0], v[:, 1] - v[:, 0]
    s = _plane_values(occ.planes.take(body, axis=0), v)              # (M, 2, Q): units along rows
    sa, sb = s[:, 0], s[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = sa / (sa - sb)
    t0 = np.where((sa > 0) & (sb <= 0), t, 0.0).max(axis=0)
    t1 = np.where((sb > 0) & (sa <= 0), t, 1.0).min(axis=0)
    outside = ((sa > _TOUCH) & (sb > _TOUCH)).any(axis=0)
    overlap = ~outside & (t1 - t0 > 1e-9)
    mid = a + 0.5 * (t0 + t1)[:, None] * d
    hidden = overlap & (mid[:, 3] > occ.front_depth(body, mid[:, :3]) + 1e-9)
    idx = np.arange(len(v))
    head = hidden & (t0 > 1e-9)
    tail = hidden & (t1 < 1 - 1e-9)
    pieces = np.concatenate([
        v[~hidden],
        np.stack([a[head], a[head] + t0[head, None] * d[head]], axis=1),
        np.stack([a[tail] + t1[tail, None] * d[tail], v[tail, 1]], axis=1),
    ])
    parent = np.concatenate([idx[~hidden], idx[head], idx[tail]])
    return pieces, parent


def _triangles(v: np.ndarray, count: np.ndarray, rgba: np.ndarray) -> np.ndarray:
    """Fan-triangulate convex polygons into (3T, FLOATS_PER_VERTEX) float32 vertices."""
    if len(v) == 0:
        return empty_vertices()
    p, jj = np.nonzero(np.arange(v.shape[1] - 2)[None] + 2 < count[:, None])
    out = np.empty((len(p), 3, FLOATS_PER_VERTEX), np.float32)        # written in place: no temporaries
    points, first = v.reshape(-1, 4), p * v.shape[1]
    out[:, 0, :3] = _take_points(points, first)[:, :3]
    out[:, 1, :3] = _take_points(points, first + jj + 1)[:, :3]
    out[:, 2, :3] = _take_points(points, first + jj + 2)[:, :3]
    out[:, :, 3:] = rgba.take(p, axis=0)[:, None]
    return out.reshape(-1, FLOATS_PER_VERTEX)

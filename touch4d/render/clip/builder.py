"""The clip-unit frame build (paper §4.3): culled, cut, triangulated vertex arrays for one frame.

Every convex part of every object is a *body*. Bodies with the same local polytope are placed,
culled and cut together in numpy (`place`); `occluders` orders the bodies that overlap on the
screen, `cutting` removes what nearer bodies hide. The builder keeps the last frame's pieces, so a
body whose pose did not change (nor that of any body in front of it) is not cut again.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from touch4d.geometry.polytope import Polytope
from touch4d.render.frame import FLOATS_PER_VERTEX, Style

from .arrays import compress, pad_width, take_points
from .cutting import cut_polygons, cut_segments
from .occluders import Occluders
from .place import Body, Template, place_group


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
        self._templates: dict[int, Template] = {}
        self._frame: _Frame | None = None

    def template(self, poly: Polytope) -> Template:
        key = id(poly.topology)
        t = self._templates.get(key)
        if t is None or t.polytope.topology is not poly.topology or t.polytope.vertices is not poly.vertices:
            if len(self._templates) > 256:
                self._templates.clear()
            t = self._templates[key] = Template(poly)
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
            g = place_group(t, [bodies[i] for i in members], perspective, eye_distance, style)
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
            occ = Occluders(clips, bounds, len(bodies), None if frame is None else (frame.hides, changed))
            redo = changed.copy()
            if frame is not None:         # a body is cut again if it moved or a moved body hid or hides it
                redo |= (frame.hides[changed] | occ.hides[changed]).any(axis=0)
                if redo.all():
                    frame = None
            poly_v, poly_c, src, pieces = _cut_reusing(
                lambda sel: cut_polygons(poly_v[sel], poly_c[sel], poly_body[sel], occ),
                poly_body, redo, None if frame is None else frame.polys)
            poly_rgba, poly_kind = poly_rgba.take(src, axis=0), poly_kind.take(src)
            seg_v, src, seg_pieces = _cut_reusing(
                lambda sel: cut_segments(seg_v[sel], seg_body[sel], occ),
                seg_body, redo, None if frame is None else frame.segs)
            seg_rgba = seg_rgba.take(src, axis=0)
            self._frame = _Frame(setting, keys, occ.hides, pieces, seg_pieces)
        fills = _triangles(*compress(poly_kind == 0, poly_v, poly_c, poly_rgba))
        centres = _triangles(*compress(poly_kind == 1, poly_v, poly_c, poly_rgba))
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
        a, b = pad_width(a, width), pad_width(b, width)
    return np.concatenate([a, b])


def _with_body(arrays: dict, ids: np.ndarray) -> dict:
    out = dict(arrays)
    out["body"] = ids[arrays["group_index"]]
    return out




def _concat_polys(polys: list[dict]):
    if not polys or sum(len(p["v"]) for p in polys) == 0:
        return (np.zeros((0, 3, 4)), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0, np.int64),
                np.zeros(0, np.int64))
    width = max(p["v"].shape[1] for p in polys)
    vs = [pad_width(p["v"], width) for p in polys]
    return (np.concatenate(vs), np.concatenate([p["count"] for p in polys]),
            np.concatenate([p["rgba"] for p in polys]), np.concatenate([p["body"] for p in polys]),
            np.concatenate([p["kind"] for p in polys]))


def _concat_segs(segs: list[dict]):
    if not segs:
        return np.zeros((0, 2, 4)), np.zeros((0, 4)), np.zeros(0, np.int64)
    return (np.concatenate([s["v"] for s in segs]), np.concatenate([s["rgba"] for s in segs]),
            np.concatenate([s["body"] for s in segs]))



def _triangles(v: np.ndarray, count: np.ndarray, rgba: np.ndarray) -> np.ndarray:
    """Fan-triangulate convex polygons into (3T, FLOATS_PER_VERTEX) float32 vertices."""
    if len(v) == 0:
        return empty_vertices()
    p, jj = np.nonzero(np.arange(v.shape[1] - 2)[None] + 2 < count[:, None])
    out = np.empty((len(p), 3, FLOATS_PER_VERTEX), np.float32)        # written in place: no temporaries
    points, first = v.reshape(-1, 4), p * v.shape[1]
    out[:, 0, :3] = take_points(points, first)[:, :3]
    out[:, 1, :3] = take_points(points, first + jj + 1)[:, :3]
    out[:, 2, :3] = take_points(points, first + jj + 2)[:, :3]
    out[:, :, 3:] = rgba.take(p, axis=0)[:, None]
    return out.reshape(-1, FLOATS_PER_VERTEX)

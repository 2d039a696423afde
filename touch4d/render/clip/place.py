"""Per shape and per frame: bodies placed in view space, back-cell culling, the drawable polygons and
segments, the cells' centre copies and the clip units (paper §4.3), for all bodies of a shape at once.

Perspective is handled by `projection.perspective_points`, which maps the scene so that perspective
becomes orthographic: afterwards every point is (u, v) with u its 3D screen position and v a depth
that grows away from the viewer and varies linearly across a flat face, so clipping and depth
comparisons are the same code for both projections. Facing cells and clip units come from the
shared half-space kernel (`touch4d.geometry.halfspace`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from touch4d.geometry import halfspace
from touch4d.geometry.polytope import Polytope
from touch4d.geometry.projection import perspective_points
from touch4d.render.frame import Style, cell_color

from .arrays import extent, take_points


@dataclass(frozen=True)
class Body:
    """One convex part of one object, placed: world = orientation @ (size * local) + position."""

    polytope: Polytope
    orientation: np.ndarray
    position: np.ndarray
    size: float
    color: np.ndarray
    object_index: int = 0


class Template:
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


def place_group(t: Template, bodies: list[Body], perspective: bool, eye: float, style: Style) -> dict:
    """Transform, cull and collect the drawable polygons, segments and clip units of same-shape bodies."""
    rot = np.stack([b.orientation for b in bodies])
    pos = np.stack([b.position for b in bodies])
    size = np.array([b.size for b in bodies], dtype=float)
    color = np.stack([b.color for b in bodies])

    world = size[:, None, None] * np.matmul(t.vertices, rot.transpose(0, 2, 1)) + pos[:, None]
    normals = np.matmul(t.normals, rot.transpose(0, 2, 1))
    offsets = size[:, None] * t.offsets + np.einsum("gci,gi->gc", normals, pos)
    centroids = size[:, None, None] * np.matmul(t.cell_centroids, rot.transpose(0, 2, 1)) + pos[:, None]
    # Map to the space where perspective is orthographic; depth v = w / (w + d).
    world_mapped = perspective_points(world, eye) if perspective else world
    normals, offsets = halfspace.view_halfspaces(normals, offsets, eye if perspective else None)

    front = halfspace.facing(normals)                                  # (G, C) back-cell culling
    f0, f1 = t.face_cells[:, 0], t.face_cells[:, 1]
    face_vis = front[:, f0] | front[:, f1]
    around = front[:, t.edge_cells]                                    # (G, E, cells per edge)
    edge_vis = around[..., 0].copy()
    for k in range(1, around.shape[2]):                                # a few columns: faster than any()
        edge_vis |= around[..., k]

    gi, fi = np.nonzero(face_vis)
    n_v = world.shape[1]
    face_v = take_points(world_mapped.reshape(-1, 4), gi[:, None] * n_v + t.face_index[fi])  # (Pf, K, 4)
    face_rgba = _with_alpha(color, gi, style.fill_alpha)

    parts_v, parts_c, parts_rgba, parts_g, parts_kind = [face_v], [t.face_count[fi]], [face_rgba], [gi], [np.zeros(len(gi), int)]
    if style.centres:
        gc, pc = np.nonzero(front[:, t.centre_cell])
        cell = t.centre_cell[pc]
        cen = centroids[gc, cell][:, None]
        corners = take_points(world.reshape(-1, 4), gc[:, None] * n_v + t.face_index[t.centre_face[pc]])
        centre_world = cen + style.centre_scale * (corners - cen)
        centre_v = perspective_points(centre_world, eye) if perspective else centre_world
        rgb = cell_color(cell) if style.cell_colors else color[gc, :3]
        parts_v.append(centre_v)
        parts_c.append(t.face_count[t.centre_face[pc]])
        parts_rgba.append(_with_alpha(color, gc, style.centre_alpha, rgb))
        parts_g.append(gc)
        parts_kind.append(np.ones(len(gc), int))

    ge, ei = np.nonzero(edge_vis)
    seg_v = take_points(world_mapped.reshape(-1, 4), ge[:, None] * n_v + t.edges[ei])   # (S, 2, 4)
    seg_rgba = _with_alpha(color, ge, style.edge_alpha)

    # Clip units on silhouette faces (front cell against back cell), compacted per body.
    planes, sil = halfspace.clip_units(normals, offsets, t.face_cells)
    order = np.argsort(~sil, axis=1, kind="stable")
    width = max(int(sil.sum(axis=1).max(initial=0)), 1)
    planes = np.take_along_axis(planes, order[..., None], axis=1)[:, :width]
    keep = np.take_along_axis(sil, order, axis=1)[:, :width]
    planes[~keep] = DUMMY_PLANE

    return {
        "front": front,
        "bounds": np.stack(extent(world_mapped), axis=1),
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
DUMMY_PLANE = np.array([0.0, 0.0, 0.0, 1.0])


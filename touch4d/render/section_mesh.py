"""The slice view's solid: every body's cross-section at w = c as opaque triangles [x, y, z, r, g, b, a]
in 3D screen coordinates, each face in the colour of the cell it cuts (the centre copies' palette),
shaded by how it faces a fixed light so the solid reads as one.

Bodies of one shape are cut together by `touch4d.geometry.section.SectionKernel` (a few array
operations per shape, whatever the number of bodies). Perspective places the section where the
projection draws the points at w = c: scaled by d / (d + c) about the screen's centre.
"""
from __future__ import annotations

import numpy as np

from touch4d.geometry.section import kernel

from .frame import FLOATS_PER_VERTEX, cell_color

LIGHT = np.array([0.35, 0.8, 0.5]) / np.linalg.norm([0.35, 0.8, 0.5])   # from above, right, front
AMBIENT = 0.55                                                          # share of the colour unlit


def section_triangles(layer, c: float) -> np.ndarray:
    """(3T, 7) float32 triangles of every body's section at w = c, for a `SceneLayer` (its geometry's
    local parts placed by its transforms); empty where the hyperplane misses every body."""
    return section_mesh(layer, c)[0]


def section_mesh(layer, c: float) -> tuple[np.ndarray, tuple[float, float] | None]:
    """`section_triangles`, and the w the bodies span (None without bodies), found on the way."""
    t = np.asarray(layer.transforms, dtype=np.float64)
    out = []
    lo, hi = np.inf, -np.inf
    behind_eye = layer.projection == "perspective" and c <= -layer.eye_distance   # nothing there is seen
    for group in _groups(layer.geometry):
        obj = group.body_object
        rotation, size, position = t[obj, :4], t[obj, 5, 0], t[obj, 4]      # rotation[b, k] = column k of R
        vertices = np.matmul(group.vertices * size[:, None, None], rotation) + position[:, None]   # local @ R^T
        w = vertices[..., 3]
        lo, hi = min(lo, w.min()), max(hi, w.max())
        if behind_eye:
            continue
        normals = np.matmul(group.normals, rotation)
        tris, body, cell = group.kernel.triangles(vertices, normals, c)     # bodies w = c misses give none
        if not len(tris):
            continue
        n3 = normals[body, cell, :3]                              # each triangle's cell, lit: its face colour
        lit = np.clip(n3 @ LIGHT / np.maximum(np.linalg.norm(n3, axis=1), 1e-12), 0.0, 1.0)
        rows = np.empty((len(tris), 3, FLOATS_PER_VERTEX), np.float32)
        rows[..., :3] = tris
        rows[..., 3:6] = (group.colors[cell] * (AMBIENT + (1 - AMBIENT) * lit)[:, None])[:, None]
        rows[..., 6] = 1.0
        out.append(rows.reshape(-1, FLOATS_PER_VERTEX))
    mesh = np.concatenate(out) if out else np.zeros((0, FLOATS_PER_VERTEX), np.float32)
    if layer.projection == "perspective":
        mesh[:, :3] *= layer.eye_distance / (layer.eye_distance + c)
    return mesh, ((float(lo), float(hi)) if np.isfinite(lo) else None)


class _Group:
    """The bodies of one shape in a scene geometry: their section kernel and stacked local arrays."""

    def __init__(self, parts, bodies, body_object):
        self.kernel = kernel(parts[0].topology)
        self.body_object = np.asarray(body_object)[bodies]
        self.vertices = np.stack([p.vertices for p in parts])     # (B, V, 4)
        self.normals = np.stack([p.normals for p in parts])       # (B, C, 4)
        self.colors = cell_color(np.arange(self.normals.shape[1]))  # (C, 3): the centre copies' palette


_GROUPS: dict[int, tuple[object, list[_Group]]] = {}


def _groups(geometry) -> list[_Group]:
    """The geometry's bodies grouped by shape, built once per scene geometry (a revision of its shapes)."""
    entry = _GROUPS.get(id(geometry))
    if entry is None or entry[0] is not geometry:
        if len(_GROUPS) > 16:
            _GROUPS.clear()
        by_topology: dict[int, list[int]] = {}
        for b, part in enumerate(geometry.parts):
            by_topology.setdefault(id(part.topology), []).append(b)
        groups = [_Group([geometry.parts[b] for b in bodies], bodies, geometry.body_object)
                  for bodies in by_topology.values()]
        entry = _GROUPS[id(geometry)] = (geometry, groups)
    return entry[1]



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
    g = layer.geometry
    t = np.asarray(layer.transforms, dtype=np.float64)
    rotation = t[:, :4].transpose(0, 2, 1)                 # (O, 4, 4): world = R (size local) + p
    out = []
    groups: dict[int, list[int]] = {}
    for b, part in enumerate(g.parts):
        groups.setdefault(id(part.topology), []).append(b)
    for bodies in groups.values():
        parts = [g.parts[b] for b in bodies]
        obj = g.body_object[bodies]
        r, p, size = rotation[obj], t[obj, 4], t[obj, 5, 0]
        local_v = np.stack([q.vertices for q in parts])    # (B, V, 4)
        local_n = np.stack([q.normals for q in parts])     # (B, C, 4)
        vertices = np.einsum("bij,bvj->bvi", r, local_v * size[:, None, None]) + p[:, None]
        normals = np.einsum("bij,bcj->bci", r, local_n)
        tris, ok = kernel(parts[0].topology).triangles(vertices, normals, c)
        if not ok.any():
            continue
        cell = np.broadcast_to(np.arange(tris.shape[1])[None, :, None], ok.shape)[ok]
        corners = tris[ok]                                  # (T, 3, 3)
        n3 = np.broadcast_to(normals[:, :, None, :3], (*ok.shape, 3))[ok]
        light = AMBIENT + (1 - AMBIENT) * np.clip(n3 @ LIGHT / np.linalg.norm(n3, axis=-1), 0.0, 1.0)
        rgb = cell_color(cell) * light[:, None]
        rows = np.empty((len(corners), 3, FLOATS_PER_VERTEX), np.float32)
        rows[..., :3] = corners
        rows[..., 3:6] = rgb[:, None]
        rows[..., 6] = 1.0
        out.append(rows.reshape(-1, FLOATS_PER_VERTEX))
    mesh = np.concatenate(out) if out else np.zeros((0, FLOATS_PER_VERTEX), np.float32)
    if layer.projection == "perspective":
        mesh[:, :3] *= layer.eye_distance / (layer.eye_distance + c)
    return mesh


def w_range(layer) -> tuple[float, float] | None:
    """The w the scene's bodies span (where a slice finds something), or None without bodies."""
    g = layer.geometry
    if not g.parts:
        return None
    t = np.asarray(layer.transforms, dtype=np.float64)
    lo, hi = np.inf, -np.inf
    for part, o in zip(g.parts, g.body_object):
        w = (part.vertices * t[o, 5, 0]) @ t[o, :4, 3] + t[o, 4, 3]   # row 3 of R: columns' w components
        lo, hi = min(lo, w.min()), max(hi, w.max())
    return float(lo), float(hi)

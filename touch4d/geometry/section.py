"""Cross-sections of convex 4-polytopes by the hyperplane w = c: the slice view's solid and what a hand
presses in it.

A body n.x <= d cut by w = c is the convex polyhedron n3.u <= d - n_w c in u = (x, y, z): one more
half-space computation (`section_halfspaces`). Its boundary is exact and cheap from the body's
combinatorics: the hyperplane meets each cell in a polygon whose corners are where the cell's edges
cross w = c; each polygon is a face of the section, coloured by the cell it cuts. `SectionKernel`
does this for many bodies of one shape at once (the renderer, whenever the scene moves);
`cross_section` gives one body's section with shared vertices and its volume (the `touch4d scene
slice` command, the tests); `SectionCaster` is what the hand presses in the slice view.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .halfspace import GRAZE
from .polytope import Polytope, Topology

ON_PLANE = 1e-9      # |w - c| below this (screen units): a vertex lies in the cutting hyperplane
PARALLEL = 1e-9      # |n3| of a unit cell normal below this: the cell is parallel to the hyperplane


def section_halfspaces(normals, offsets, c: float) -> tuple[np.ndarray, np.ndarray]:
    """The half-spaces (n3, d - n_w c) of the cross-section at w = c in 3D, from a body's n.x <= d (any
    leading axes on (..., C, 4) and (..., C)). A cell parallel to the hyperplane gives n3 = 0: then the
    section is empty where d - n_w c < 0."""
    n = np.asarray(normals, dtype=np.float64)
    return n[..., :3], np.asarray(offsets, dtype=np.float64) - n[..., 3] * float(c)


def w_extent(vertices) -> tuple[float, float]:
    """The range of w a body (or all the vertices given) spans: the c at which it has a section."""
    w = np.asarray(vertices, dtype=np.float64)[..., 3]
    return float(w.min()), float(w.max())


class SectionKernel:
    """The per-shape tables of the cross-section: each cell's edges, padded to the widest cell, so that
    the polygons of every cell of many bodies come out of a few array operations."""

    def __init__(self, topology: Topology):
        edges = np.asarray(topology.edges)
        cell_edges = []
        for faces in topology.cell_faces:
            sides = np.concatenate([topology.face_edges[topology.face_starts[f]:topology.face_starts[f + 1]]
                                    for f in faces])
            cell_edges.append(np.unique(sides))
        width = max(len(e) for e in cell_edges)
        self.edges = edges
        self.cell_edges = np.full((len(cell_edges), width), -1, np.int64)
        for k, e in enumerate(cell_edges):
            self.cell_edges[k, :len(e)] = e
        self.pad = self.cell_edges < 0
        self.cell_edges[self.pad] = 0
        self.width = width

    def polygons(self, vertices, normals, c: float):
        """The section's faces for bodies of this shape: vertices (B, V, 4) and cell normals (B, C, 4) in
        the world. Only the cells the hyperplane cuts come out: their corners (K, S, 3), in cyclic order
        counterclockwise seen from outside the section (along +n3), how many there are (K,) (a cell's
        polygon is corners[k, :count[k]]; S is the most any has), and the body (K,) and cell (K,) each
        comes from. A corner shared by several edges (a vertex in the plane) repeats; `cross_section`
        merges such repeats."""
        x = np.asarray(vertices, dtype=np.float64)
        n = np.asarray(normals, dtype=np.float64)
        dw = x[..., 3] - c                                          # (B, V)
        on = np.abs(dw) <= ON_PLANE
        a, b = self.edges[:, 0], self.edges[:, 1]
        wa, wb = dw[:, a], dw[:, b]                                 # (B, E)
        cross = (wa * wb < 0) & ~on[:, a] & ~on[:, b]
        # A corner per edge: where it crosses w = c, or its end a in the plane; with vertices in the
        # plane (rare), a second per edge, its end b, so that no corner is lost (repeats are harmless).
        ends_too = bool(on.any())
        slots_per_edge = 2 if ends_too else 1
        valid = np.stack([cross | on[:, a], on[:, b]], axis=2) if ends_too else (cross | on[:, a])[..., None]
        slots = valid[:, self.cell_edges] & ~self.pad[None, :, :, None]          # (B, C, W, 1 or 2)
        n_slots = self.width * slots_per_edge
        count = slots.reshape(*slots.shape[:2], n_slots).sum(axis=-1)
        n3 = n[..., :3]
        norm = np.linalg.norm(n3, axis=-1)
        body, cell = np.nonzero((count >= 3) & (norm > PARALLEL))
        if not len(body):
            empty = np.zeros(0, np.int64)
            return np.zeros((0, 3, 3)), empty, empty, empty
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(cross, wa / (wa - wb), 0.0)
        xa, xb = x[:, a, :3], x[:, b, :3]
        ends = (np.stack([xa + t[..., None] * (xb - xa), xb], axis=2) if ends_too
                else (xa + t[..., None] * (xb - xa))[:, :, None])                 # (B, E, 1 or 2, 3)
        pts = ends[body[:, None], self.cell_edges[cell]].reshape(len(body), n_slots, 3)
        ok = slots[body, cell].reshape(len(body), n_slots)
        k = count[body, cell]
        centre = np.einsum("ks,ksj->kj", ok.astype(np.float64), pts) / k[:, None]
        # Cyclic order: angles in the coordinate plane (i, j) that drops the normal's largest component
        # m_k, (i, j, k) cyclic; they grow counterclockwise about +e_k, so about n3 when m_k > 0.
        m = n3[body, cell]
        drop = np.argmax(np.abs(m), axis=-1)
        rel = pts - centre[:, None]
        rows = np.arange(len(body))
        u = np.take_along_axis(rel, ((drop + 1) % 3)[:, None, None], axis=2)[..., 0]
        v = np.take_along_axis(rel, ((drop + 2) % 3)[:, None, None], axis=2)[..., 0]
        angle = np.arctan2(v, u) * np.sign(m[rows, drop])[:, None]
        order = np.argsort(np.where(ok, angle, np.inf), axis=-1)[:, :k.max()]
        corners = pts[rows[:, None], order]
        return corners, k, body, cell

    def triangles(self, vertices, normals, c: float):
        """The section's faces as fans of triangles wound counterclockwise seen from outside: corners
        (T, 3, 3), and the body (T,) and cell (T,) each comes from."""
        corners, count, body, cell = self.polygons(vertices, normals, c)
        face, i = np.nonzero(np.arange(1, corners.shape[1] - 1)[None, :] + 1 < count[:, None])
        i = i + 1
        tris = np.stack([corners[face, 0], corners[face, i], corners[face, i + 1]], axis=1)
        return tris, body[face], cell[face]


_KERNELS: dict[int, tuple[Topology, SectionKernel]] = {}


def kernel(topology: Topology) -> SectionKernel:
    """The `SectionKernel` of a shape's topology, built once (topologies are shared by every copy)."""
    entry = _KERNELS.get(id(topology))
    if entry is None or entry[0] is not topology:
        if len(_KERNELS) > 256:
            _KERNELS.clear()
        entry = _KERNELS[id(topology)] = (topology, SectionKernel(topology))
    return entry[1]


@dataclass(frozen=True)
class Section:
    """The cross-section of one body at w = c: a convex polyhedron in (x, y, z).

    `vertices` (N, 3); `faces` lists of vertex indices, counterclockwise seen from outside; `face_cell`
    (F,) the body's cell each face cuts; `volume` (0 where the hyperplane misses the body or only touches
    it)."""

    c: float
    vertices: np.ndarray
    faces: list
    face_cell: np.ndarray
    volume: float

    @property
    def empty(self) -> bool:
        return self.volume <= 0.0


def cross_section(body: Polytope, c: float, tol: float = 1e-9) -> Section:
    """The exact cross-section of a world polytope by w = c (corners merged within `tol`; faces of no
    area, where the hyperplane only touches a cell, left out)."""
    corners, count, _, cut = kernel(body.topology).polygons(body.vertices[None], body.normals[None], c)
    points, faces, cells, seen = [], [], [], set()
    for k, cell in enumerate(cut):
        face = []
        for p in corners[k, :count[k]]:
            index = _merge(points, p, tol)
            if not face or (index != face[-1] and index != face[0]):
                face.append(index)
        if len(face) >= 3 and frozenset(face) not in seen:   # a 2-face in the plane: both its cells give it
            seen.add(frozenset(face))
            faces.append(face)
            cells.append(int(cell))
    vertices = np.array(points, dtype=np.float64).reshape(-1, 3)
    keep = [k for k, f in enumerate(faces) if _area(vertices[f]) > tol]
    faces = [faces[k] for k in keep]
    face_cell = np.array([cells[k] for k in keep], dtype=np.int64)
    volume = _volume(vertices, faces) if len(faces) >= 4 else 0.0
    if faces:
        used = np.unique(np.concatenate(faces))
        remap = np.full(len(vertices), -1)
        remap[used] = np.arange(len(used))
        vertices, faces = vertices[used], [remap[f].tolist() for f in faces]
    else:
        vertices = np.zeros((0, 3))
    return Section(float(c), vertices, faces, face_cell, max(volume, 0.0))


def _merge(points: list, p: np.ndarray, tol: float) -> int:
    for i, q in enumerate(points):
        if np.max(np.abs(q - p)) <= tol:
            return i
    points.append(p)
    return len(points) - 1


def _area(polygon: np.ndarray) -> float:
    """Area of a planar polygon in 3D (corners in order)."""
    rel = polygon - polygon[0]
    return 0.5 * float(np.linalg.norm(np.sum(np.cross(rel[1:-1], rel[2:]), axis=0)))


def _volume(vertices: np.ndarray, faces: list) -> float:
    """Volume of a closed polyhedron with outward-wound faces (divergence theorem: signed tetrahedra
    from the centroid over each face's fan)."""
    o = vertices.mean(axis=0)
    total = 0.0
    for f in faces:
        p = vertices[f] - o
        total += float(np.sum(np.einsum("ij,ij->i", p[0][None], np.cross(p[1:-1], p[2:])))) / 6.0
    return total


class SectionCaster:
    """Touch of the slice view: the cross-sections at w = c as solids the hand presses. Answers what
    `RayCaster.cast` answers, so the tactile model (eq. 1-7) runs unchanged: a screen point inside an
    object's section is in contact (t = 0, the strongest stimulus, as for a point inside a body in the
    projection), elsewhere it touches nothing (NaN, -1). Where the slice is drawn in perspective, at
    d / (d + c) of its size, a screen point u stands for the world point u (d + c) / d; a cut at or
    behind the eye (c <= -d) is seen nowhere and touches nothing.
    """

    def __init__(self, world_parts: list[tuple[int, Polytope]], c: float, eye_distance: float | None = None):
        self.c = float(c)
        self.scale = 1.0 if eye_distance is None else (float(eye_distance) + self.c) / float(eye_distance)
        if self.scale <= 0:
            world_parts = []
        self.part_object = np.array([int(i) for i, _ in world_parts], dtype=np.int64)
        rows = [section_halfspaces(p.normals, p.offsets, self.c) for _, p in world_parts]
        self._normals = np.vstack([n for n, _ in rows]) if rows else np.zeros((0, 3))
        self._offsets = np.concatenate([d for _, d in rows]) if rows else np.zeros(0)
        self._starts = np.r_[0, np.cumsum([len(d) for _, d in rows])[:-1]].astype(np.int64)

    @property
    def n_parts(self) -> int:
        return len(self.part_object)

    def cast(self, points3) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) screen points -> (t (N,): 0 inside a section, NaN elsewhere; hit (N,) object or -1)."""
        p = np.asarray(points3, dtype=np.float64).reshape(-1, 3) * self.scale
        n = len(p)
        if not self.n_parts or not n:
            return np.full(n, np.nan), np.full(n, -1, dtype=np.int64)
        ok = p @ self._normals.T <= self._offsets + GRAZE                       # (N, half-spaces)
        inside = np.logical_and.reduceat(ok, self._starts, axis=1)             # (N, parts)
        found = inside.any(axis=1)
        hit = np.where(found, self.part_object[inside.argmax(axis=1)], -1)
        return np.where(found, 0.0, np.nan), hit

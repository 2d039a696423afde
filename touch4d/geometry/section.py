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

from touch4d.jit import lazy_njit

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
    """The per-shape table of the cross-section: the cells around each edge (padded with -1), so that
    the polygons of every cut cell of many bodies come out of a few array operations."""

    def __init__(self, topology: Topology):
        self.edges = np.asarray(topology.edges)
        face_cells = np.asarray(topology.face_cells)
        around = [np.unique(face_cells[faces]) for faces in topology.edge_faces]
        self.edge_cells = np.full((len(around), max(len(a) for a in around)), -1, np.int64)
        for e, cells in enumerate(around):
            self.edge_cells[e, :len(cells)] = cells
        self.n_cells = len(topology.cell_faces)
        # The edges of each cell, padded with E (no edge): the table `triangles` walks.
        mine = [np.flatnonzero((self.edge_cells == c).any(axis=1)) for c in range(self.n_cells)]
        self.cell_edges = np.full((self.n_cells, max(len(m) for m in mine)), len(self.edges), np.int64)
        for c, m in enumerate(mine):
            self.cell_edges[c, :len(m)] = m

    def polygons(self, vertices, normals, c: float):
        """The section's faces for bodies of this shape: vertices (B, V, 4) and cell normals (B, C, 4) in
        the world. Only the cells the hyperplane cuts come out, K of them: the corners (N, 3) of all
        their polygons one after the other, each polygon in cyclic order counterclockwise seen from
        outside the section (along +n3), where each starts (K + 1,), and the body (K,) and cell (K,)
        each comes from. A corner shared by several edges (a vertex in the plane) repeats;
        `cross_section` merges such repeats."""
        x = np.asarray(vertices, dtype=np.float64)
        n3 = np.asarray(normals, dtype=np.float64)[..., :3]
        dw = x[..., 3] - c                                          # (B, V)
        on = np.abs(dw) <= ON_PLANE
        a, b = self.edges[:, 0], self.edges[:, 1]
        wa, wb = dw[:, a], dw[:, b]                                 # (B, E)
        cross = (wa * wb < 0) & ~on[:, a] & ~on[:, b]
        # The corners: where an edge crosses w = c, and the ends of edges in the plane (rare); each
        # is a corner of the polygon of every cell around its edge.
        body, edge = np.nonzero(cross | on[:, a])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(cross[body, edge], wa[body, edge] / (wa[body, edge] - wb[body, edge]), 0.0)
        xa = x[body, a[edge], :3]
        points = xa + t[:, None] * (x[body, b[edge], :3] - xa)
        if on.any():
            body_b, edge_b = np.nonzero(on[:, b])
            body, edge = np.r_[body, body_b], np.r_[edge, edge_b]
            points = np.vstack([points, x[body_b, b[edge_b], :3]])
        cells = self.edge_cells[edge]                               # (P, M)
        has = cells >= 0
        corner_body = np.broadcast_to(body[:, None], cells.shape)[has]
        key = corner_body * self.n_cells + cells[has]               # (N,): the body's cell each corner is on
        pts = np.broadcast_to(points[:, None], (*cells.shape, 3))[has]
        # Cells with 3 corners or more, not parallel to the hyperplane, are cut in a polygon.
        count = np.bincount(key, minlength=len(x) * self.n_cells)
        m = n3.reshape(-1, 3)
        cut = (count >= 3) & (np.abs(m).max(axis=1) > PARALLEL)
        keep = cut[key]
        key, pts = key[keep], pts[keep]
        if not len(key):
            empty = np.zeros(0, np.int64)
            return np.zeros((0, 3)), np.zeros(1, np.int64), empty, empty
        centre = np.stack([np.bincount(key, pts[:, j], minlength=len(count)) for j in range(3)], axis=1)
        centre /= np.maximum(count, 1)[:, None]
        # Cyclic order: angles in the coordinate plane (i, j) that drops the normal's largest component
        # m_k, (i, j, k) cyclic; they grow counterclockwise about +e_k, so about n3 when m_k > 0.
        mk = m[key]
        drop = np.argmax(np.abs(mk), axis=1)
        rel = pts - centre[key]
        rows = np.arange(len(key))
        angle = np.arctan2(rel[rows, (drop + 2) % 3], rel[rows, (drop + 1) % 3]) * np.sign(mk[rows, drop])
        order = np.argsort(key + (angle + 4.0) / 8.0)              # by cell, then by angle (|angle| <= pi < 4)
        key = key[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        faces = key[starts]
        return pts[order], np.r_[starts, len(key)], faces // self.n_cells, faces % self.n_cells

    def triangles(self, vertices, normals, c: float):
        """The section's faces as fans of triangles wound counterclockwise seen from outside: corners
        (T, 3, 3), and the body (T,) and cell (T,) each comes from. Where no vertex lies in the plane
        (the generic case) one compiled pass over the bodies' cells (`_cut_fans`, 5-10x the array
        operations of `polygons` on 64 tesseracts: bench/bench_slice.py); otherwise from `polygons`."""
        x = np.ascontiguousarray(vertices, dtype=np.float64)
        n3 = np.ascontiguousarray(np.asarray(normals, dtype=np.float64)[..., :3])
        if not len(x):
            return np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        if np.any(np.abs(x[..., 3] - c) <= ON_PLANE):
            return self.fans(*self.polygons(x, n3, c))
        return _cut_fans(x, n3, self.edges, self.cell_edges, float(c), PARALLEL)

    @staticmethod
    def fans(corners, starts, body, cell):
        """`polygons`' output as fans of triangles: corners (T, 3, 3), body (T,), cell (T,)."""
        fans = np.diff(starts) - 2                                 # a polygon of k corners: k - 2 triangles
        face = np.repeat(np.arange(len(fans)), fans)
        first = starts[face]
        i = first + 1 + np.arange(len(face)) - np.repeat(np.cumsum(fans) - fans, fans)   # 1 .. k - 2 in each
        tris = np.stack([corners[first], corners[i], corners[i + 1]], axis=1)
        return tris, body[face], cell[face]


@lazy_njit(cache=True, nogil=True)
def _cut_fans(x, n3, edges, cell_edges, c, parallel):
    """`SectionKernel.triangles` where no vertex lies in the plane w = c: per body, where each edge
    crosses it; per cell cut in 3 corners or more (and not parallel to it), its corners ordered by
    angle about their mean as `polygons` orders them, and their fan."""
    n_bodies, n_edges = x.shape[0], edges.shape[0]
    n_cells, most = cell_edges.shape
    cap = n_bodies * n_cells * max(most - 2, 0)
    tris = np.empty((cap, 3, 3))
    body = np.empty(cap, np.int64)
    cell = np.empty(cap, np.int64)
    point = np.empty((n_edges, 3))
    crosses = np.zeros(n_edges, np.bool_)
    corner = np.empty((most, 3))
    angle = np.empty(most)
    order = np.empty(most, np.int64)
    n = 0
    for b in range(n_bodies):
        for e in range(n_edges):
            wa, wb = x[b, edges[e, 0], 3] - c, x[b, edges[e, 1], 3] - c
            crosses[e] = wa * wb < 0.0
            if crosses[e]:
                t = wa / (wa - wb)
                for j in range(3):
                    point[e, j] = x[b, edges[e, 0], j] + t * (x[b, edges[e, 1], j] - x[b, edges[e, 0], j])
        for k in range(n_cells):
            drop = 0                                  # the normal's largest component
            for j in range(1, 3):
                if abs(n3[b, k, j]) > abs(n3[b, k, drop]):
                    drop = j
            if abs(n3[b, k, drop]) <= parallel:
                continue
            count = 0
            cx = cy = cz = 0.0
            for s in range(most):
                e = cell_edges[k, s]
                if e < n_edges and crosses[e]:
                    corner[count, 0], corner[count, 1], corner[count, 2] = point[e, 0], point[e, 1], point[e, 2]
                    cx += point[e, 0]
                    cy += point[e, 1]
                    cz += point[e, 2]
                    count += 1
            if count < 3:
                continue
            centre = (cx / count, cy / count, cz / count)
            i, j = (drop + 1) % 3, (drop + 2) % 3
            sign = 1.0 if n3[b, k, drop] > 0 else -1.0
            for s in range(count):                    # insertion sort by angle: a handful of corners
                a = np.arctan2(corner[s, j] - centre[j], corner[s, i] - centre[i]) * sign
                r = s
                while r > 0 and angle[r - 1] > a:
                    angle[r], order[r] = angle[r - 1], order[r - 1]
                    r -= 1
                angle[r], order[r] = a, s
            for s in range(1, count - 1):
                for q in range(3):
                    tris[n, 0, q] = corner[order[0], q]
                    tris[n, 1, q] = corner[order[s], q]
                    tris[n, 2, q] = corner[order[s + 1], q]
                body[n], cell[n] = b, k
                n += 1
    return tris[:n], body[:n], cell[:n]


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
    corners, starts, _, cut = kernel(body.topology).polygons(body.vertices[None], body.normals[None], c)
    # Each corner merged into the first one within tol (the corners of a vertex in the plane repeat).
    near = np.abs(corners[:, None] - corners[None]).max(axis=2) <= tol
    used, label = np.unique(near.argmax(axis=1) if len(corners) else np.zeros(0, np.int64), return_inverse=True)
    faces, cells, seen = [], [], set()
    for k, cell in enumerate(cut):
        face = []
        for index in label[starts[k]:starts[k + 1]].tolist():
            if not face or (index != face[-1] and index != face[0]):
                face.append(index)
        if len(face) >= 3 and frozenset(face) not in seen:   # a 2-face in the plane: both its cells give it
            seen.add(frozenset(face))
            faces.append(face)
            cells.append(int(cell))
    vertices = corners[used].reshape(-1, 3)
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

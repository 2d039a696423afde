"""Convex 4-polytopes: the whole boundary (cells, 2-faces, edges, vertices) from vertices or half-spaces.

A `Polytope` keeps its combinatorics (which vertices lie on which cell, faces in cyclic order, the two
cells meeting at each face) in a shared `Topology`, so `transformed` only moves arrays and costs no hull.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

from touch4d.errors import Touch4dError

from . import tolerance


class GeometryError(Touch4dError, ValueError):
    """Input that does not describe a bounded, full-dimensional convex 4-polytope."""


@dataclass(frozen=True, eq=False)
class Topology:
    """Combinatorics of a convex 4-polytope; independent of position, orientation and size."""

    edges: np.ndarray            # (E, 2) vertex indices
    faces: tuple                 # F arrays of vertex indices, cyclic order
    face_cells: np.ndarray       # (F, 2) the two cells meeting at each 2-face
    cell_faces: tuple            # C arrays of face indices
    cell_vertices: tuple         # C arrays of vertex indices
    face_edges: np.ndarray       # (sum of face sizes,) edge index of each polygon side, faces concatenated
    face_starts: np.ndarray      # (F + 1,) where each face's sides start in face_edges
    side_faces: np.ndarray       # (sum of face sizes,) the face each entry of face_edges belongs to
    edge_faces: tuple            # E arrays of face indices


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


class Polytope:
    """One convex 4-polytope: `normals @ x <= offsets`, with its vertices and whole boundary.

    `vertices` (V,4); `normals` (C,4) unit, outward; `offsets` (C,); `edges` (E,2); `faces` list of
    vertex-index arrays in cyclic order; `face_cells` (F,2); `cell_faces` list of face-index arrays.
    """

    __slots__ = ("vertices", "normals", "offsets", "topology")

    def __init__(self, vertices: np.ndarray, normals: np.ndarray, offsets: np.ndarray, topology: Topology):
        self.vertices = _readonly(np.asarray(vertices, dtype=np.float64))
        self.normals = _readonly(np.asarray(normals, dtype=np.float64))
        self.offsets = _readonly(np.asarray(offsets, dtype=np.float64))
        self.topology = topology

    # ---- the boundary -------------------------------------------------------------------------------
    edges = property(lambda self: self.topology.edges)
    faces = property(lambda self: list(self.topology.faces))
    face_cells = property(lambda self: self.topology.face_cells)
    cell_faces = property(lambda self: list(self.topology.cell_faces))
    cell_vertices = property(lambda self: list(self.topology.cell_vertices))

    @property
    def counts(self) -> tuple[int, int, int, int]:
        """(vertices, edges, faces, cells)."""
        return len(self.vertices), len(self.edges), len(self.topology.faces), len(self.normals)

    @property
    def halfspaces(self) -> np.ndarray:
        """(C, 5) rows [n1, n2, n3, n4, d] meaning n.x <= d."""
        return np.hstack([self.normals, self.offsets[:, None]])

    @property
    def edge_directions(self) -> np.ndarray:
        """(D, 4) the distinct unit directions of the edges, each once (its first clear coordinate > 0)."""
        v = self.vertices
        d = v[self.edges[:, 1]] - v[self.edges[:, 0]]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        lead = np.argmax(np.abs(d) > tolerance.ANGLE, axis=1)
        d *= np.where(d[np.arange(len(d)), lead] < 0, -1.0, 1.0)[:, None]
        _, first = np.unique(np.round(d, 9), axis=0, return_index=True)
        return d[np.sort(first)]

    @property
    def face_planes(self) -> np.ndarray:
        """(P, 2, 4) the distinct planes of the 2-faces, each as two orthonormal vectors spanning it."""
        v = self.vertices
        spans, keys = [], []
        for face in self.topology.faces:
            p0 = v[face[0]]
            e1 = v[face[1]] - p0
            e1 /= np.linalg.norm(e1)
            rest = v[face[2:]] - p0
            rest -= np.outer(rest @ e1, e1)
            e2 = rest[np.argmax(np.linalg.norm(rest, axis=1))]
            e2 /= np.linalg.norm(e2)
            spans.append((e1, e2))
            keys.append(np.round(np.outer(e1, e1) + np.outer(e2, e2), 9).ravel())   # the plane's projector
        _, first = np.unique(np.array(keys), axis=0, return_index=True)
        return np.array(spans)[np.sort(first)]

    @property
    def center(self) -> np.ndarray:
        """Mean of the vertices: an interior point."""
        return self.vertices.mean(axis=0)

    def contains(self, points: np.ndarray, tol: float | None = None) -> np.ndarray:
        """Which of the (N,4) points lie in the closed polytope (within tol; default the shared tolerance
        for its size)."""
        points = np.atleast_2d(points)
        tol = tolerance.of(tolerance.size(self.vertices)) if tol is None else tol
        return np.all(points @ self.normals.T <= self.offsets + tol, axis=1)

    def transformed(self, orientation=None, position=None, size: float = 1.0) -> "Polytope":
        """World copy: x_world = orientation @ (size * x_local) + position; topology shared, no hull."""
        r = np.eye(4) if orientation is None else np.asarray(orientation, dtype=np.float64)
        p = np.zeros(4) if position is None else np.asarray(position, dtype=np.float64)
        size = float(size)
        vertices = size * self.vertices @ r.T + p
        normals = self.normals @ r.T
        offsets = size * self.offsets + normals @ p
        return Polytope(vertices, normals, offsets, self.topology)

    def __repr__(self) -> str:
        v, e, f, c = self.counts
        return f"Polytope(V={v}, E={e}, F={f}, C={c})"

    # ---- construction -------------------------------------------------------------------------------
    @classmethod
    def from_vertices(cls, points, tol: float | None = None) -> "Polytope":
        """Convex hull of (N,4) points (Qhull), coplanar hull facets merged into cells."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 4 or len(points) < 5:
            raise GeometryError(f"expected at least 5 points of 4 coordinates, got shape {points.shape}")
        if not np.all(np.isfinite(points)):
            raise GeometryError("vertices must be finite numbers")
        scale = tolerance.size(points)
        if scale == 0:
            raise GeometryError("all points coincide")
        tol = tolerance.HULL * scale if tol is None else tol
        try:
            hull = ConvexHull(points)
        except QhullError as exc:
            raise GeometryError("points do not span 4 dimensions (the hull is flat)") from exc
        candidates = points[hull.vertices]
        eq = hull.equations
        # Facets of the triangulated hull that hold the same vertices form one cell.
        on_plane = np.abs(candidates @ eq[:, :4].T + eq[:, 4]) <= tol          # (V, facets)
        _, first, cell_of = np.unique(np.packbits(on_plane.T, axis=1), axis=0, return_index=True,
                                      return_inverse=True)
        order = np.argsort(first)
        cells = first[order]
        incidence = on_plane[:, cells].T                                        # (C, V)
        # A cell's plane is Qhull's (outward, unit) facet equation, averaged over the facets it merges.
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        cell_of = rank[cell_of.reshape(-1)]
        planes = np.zeros((len(cells), 5))
        np.add.at(planes, cell_of, eq)
        planes /= np.linalg.norm(planes[:, :4], axis=1, keepdims=True)
        # Keep only true vertices: points on cells whose normals span 4 dimensions.
        keep = np.array([np.linalg.matrix_rank(planes[incidence[:, i], :4], tol=1e-6) == 4
                         for i in range(len(candidates))])
        vertices = candidates[keep]
        incidence = incidence[:, keep]
        return cls._build(vertices, incidence, planes[:, :4], -planes[:, 4])

    @classmethod
    def from_halfspaces(cls, halfspaces, tol: float | None = None) -> "Polytope":
        """Intersection of (K,5) half-spaces [n1,n2,n3,n4,d] meaning n.x <= d (redundant ones dropped)."""
        h = np.asarray(halfspaces, dtype=np.float64)
        if h.ndim != 2 or h.shape[1] != 5 or len(h) < 5:
            raise GeometryError(f"expected at least 5 half-spaces [n1,n2,n3,n4,d], got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            raise GeometryError("half-spaces must be finite numbers")
        norms = np.linalg.norm(h[:, :4], axis=1)
        if np.any(norms == 0):
            raise GeometryError("a half-space has a zero normal")
        h = h / norms[:, None]
        # Chebyshev centre: the deepest interior point, needed by Qhull's half-space intersection.
        res = linprog(np.r_[np.zeros(4), -1.0], A_ub=np.hstack([h[:, :4], np.ones((len(h), 1))]),
                      b_ub=h[:, 4], bounds=[(None, None)] * 4 + [(0, None)], method="highs")
        if res.status == 3:
            raise GeometryError("the half-spaces do not bound a finite region")
        if res.status != 0 or res.x[4] <= 1e-9 * max(1.0, np.abs(h[:, 4]).max()):
            raise GeometryError("the half-spaces have no interior (empty or flat intersection)")
        try:
            hs = HalfspaceIntersection(np.hstack([h[:, :4], -h[:, 4:]]), res.x[:4])
        except QhullError as exc:
            raise GeometryError("the half-spaces do not bound a finite region") from exc
        pts = hs.intersections
        if not np.all(np.isfinite(pts)) or np.abs(pts).max() > 1e9:
            raise GeometryError("the half-spaces do not bound a finite region")
        return cls.from_vertices(pts, tol)

    @classmethod
    def _build(cls, vertices: np.ndarray, incidence: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> "Polytope":
        """Faces, edges and the rest of the boundary from the vertex-cell incidence (C, V) and the cells' planes."""
        # Two cells of a convex 4-polytope meet in a 2-face exactly when they share >= 3 vertices
        # (an edge has only two vertices).
        inc = incidence.astype(np.int32)
        shared = inc @ inc.T
        ca, cb = np.nonzero(np.triu(shared >= 3, k=1))
        faces = []
        for a, b in zip(ca, cb):
            idx = np.nonzero(incidence[a] & incidence[b])[0]
            faces.append(_cyclic(vertices, idx))
        face_cells = np.stack([ca, cb], axis=1).astype(np.int64) if len(ca) else np.zeros((0, 2), np.int64)
        sides = np.concatenate([np.stack([f, np.roll(f, -1)], axis=1) for f in faces])
        sides.sort(axis=1)
        edges, side_edge = np.unique(sides, axis=0, return_inverse=True)
        side_edge = side_edge.reshape(-1)
        starts = np.r_[0, np.cumsum([len(f) for f in faces])]
        face_of_side = np.repeat(np.arange(len(faces)), np.diff(starts))
        order = np.argsort(side_edge, kind="stable")
        edge_faces = np.split(face_of_side[order], np.cumsum(np.bincount(side_edge, minlength=len(edges)))[:-1])
        cell_faces = [np.nonzero((face_cells == c).any(axis=1))[0] for c in range(len(incidence))]
        topology = Topology(
            edges=_readonly(edges.astype(np.int64)),
            faces=tuple(_readonly(f) for f in faces),
            face_cells=_readonly(face_cells),
            cell_faces=tuple(_readonly(f) for f in cell_faces),
            cell_vertices=tuple(_readonly(np.nonzero(row)[0]) for row in incidence),
            face_edges=_readonly(side_edge.astype(np.int64)),
            face_starts=_readonly(starts.astype(np.int64)),
            side_faces=_readonly(face_of_side.astype(np.int64)),
            edge_faces=tuple(_readonly(f) for f in edge_faces),
        )
        return cls(vertices, normals, offsets, topology)


def not_corners(points, polytope: Polytope) -> list[tuple[int, str]]:
    """The given points that are not corners of `polytope` (built from them), each with where it lies.

    `from_vertices` takes the convex hull, so a point pushed in (a dent) or inside is dropped without
    a word; a scene file refuses such a list rather than touch a shape its author did not give.
    Returns (index, "inside the hull" | "on the hull's boundary but not a corner").
    """
    points = np.asarray(points, dtype=np.float64)
    tol = tolerance.POINT * tolerance.size(points)
    dist = np.linalg.norm(points[:, None, :] - polytope.vertices[None, :, :], axis=2).min(axis=1)
    out = []
    for i in np.nonzero(dist > tol)[0]:
        inside = np.all(polytope.normals @ points[i] < polytope.offsets - tol)
        out.append((int(i), "inside the hull" if inside else "on the hull's boundary but not a corner"))
    return out


def _cyclic(vertices: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The vertex indices of a planar convex polygon, sorted by angle around its centre."""
    pts = vertices[idx]
    mean = pts.mean(axis=0)
    basis = np.linalg.svd(pts - mean)[2][:2]
    local = (pts - mean) @ basis.T
    return idx[np.argsort(np.arctan2(local[:, 1], local[:, 0]))].astype(np.int64)


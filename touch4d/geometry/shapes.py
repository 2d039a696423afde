"""The shape catalog: regular 4-polytopes, prisms, duoprisms, pyramids, and the paper's look-alikes.

Size convention for every catalog shape: at size 1 the shape fits the tesseract [-1/2, 1/2]^4 and
touches its boundary (the largest |coordinate| of a vertex is 1/2), centred on the origin. So the
tesseract's size is its edge length, and a tesseract of size 1 at (0,0,0,1.5) has its front cell at
w = 1.0 with outward normal (0,0,0,-1), facing the viewer who looks along +w.
Shapes with an apex (pyramid, cone) point it toward the viewer, at w = -1/2.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.spatial import ConvexHull

from .polytope import GeometryError, Polytope

PHI = (1 + 5 ** 0.5) / 2


@dataclass(frozen=True)
class Shape:
    """A catalog shape: convex parts in local coordinates (unscaled) and what its size means."""

    name: str
    params: dict
    parts: list[Polytope]
    doc: str

    @property
    def convex(self) -> bool:
        return len(self.parts) == 1


@dataclass(frozen=True)
class _Entry:
    build: object
    defaults: dict = field(default_factory=dict)
    doc: str = ""


# ---- polyhedra (3D bases) -----------------------------------------------------------------------


def _even_permutations(v):
    out = []
    for p in itertools.permutations(range(len(v))):
        inversions = sum(p[i] > p[j] for i in range(len(p)) for j in range(i + 1, len(p)))
        if inversions % 2 == 0:
            out.append([v[i] for i in p])
    return out


def _signs(v):
    """Every sign change of the nonzero entries of v."""
    nz = [i for i, x in enumerate(v) if x != 0]
    out = []
    for s in itertools.product((1, -1), repeat=len(nz)):
        w = list(v)
        for i, si in zip(nz, s):
            w[i] = si * w[i]
        out.append(w)
    return out


def _unique_rows(a, decimals=9):
    _, idx = np.unique(np.round(a, decimals), axis=0, return_index=True)
    return a[np.sort(idx)]


def _fit(points: np.ndarray) -> np.ndarray:
    """Scale points (centred on the origin) so their largest |coordinate| is 1/2."""
    return points * (0.5 / np.abs(points).max())


def icosphere(subdivisions: int) -> np.ndarray:
    """Vertices of a geodesic sphere of radius 1/2: an icosahedron, each triangle split in 4, n times."""
    verts = _icosahedron_raw()
    tris = ConvexHull(verts).simplices
    for _ in range(subdivisions):
        index = {tuple(np.round(v, 12)): i for i, v in enumerate(verts)}
        pts = list(verts)

        def mid(i, j):
            m = pts[i] + pts[j]
            m = m / np.linalg.norm(m)
            key = tuple(np.round(m, 12))
            if key not in index:
                index[key] = len(pts)
                pts.append(m)
            return index[key]

        new = []
        for a, b, c in tris:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        verts, tris = np.array(pts), np.array(new)
    return 0.5 * verts / np.linalg.norm(verts, axis=1, keepdims=True)


def _icosahedron_raw() -> np.ndarray:
    v = []
    for p in ([0, 1, PHI], [1, PHI, 0], [PHI, 0, 1]):
        v += _signs(p)
    v = np.array(v, dtype=float)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


POLYHEDRA = ("tetrahedron", "cube", "octahedron", "dodecahedron", "icosahedron", "ball")


def polyhedron(name: str, subdivisions: int = 1) -> np.ndarray:
    """Vertices (N,3) of a polyhedron fitting [-1/2,1/2]^3 (the ball: radius 1/2, geodesic)."""
    if name == "tetrahedron":
        v = [p for p in itertools.product((1, -1), repeat=3) if np.prod(p) > 0]
    elif name == "cube":
        v = list(itertools.product((1, -1), repeat=3))
    elif name == "octahedron":
        v = [s * np.eye(3)[i] for i in range(3) for s in (1, -1)]
    elif name == "dodecahedron":
        v = list(itertools.product((1, -1), repeat=3))
        for p in ([0, 1 / PHI, PHI], [1 / PHI, PHI, 0], [PHI, 0, 1 / PHI]):
            v += _signs(p)
    elif name == "icosahedron":
        v = _icosahedron_raw()
    elif name == "ball":
        return icosphere(_count("subdivisions", subdivisions, 0, 3))
    else:
        raise GeometryError(f"unknown polyhedron {name!r}; expected one of {', '.join(POLYHEDRA)}")
    return _fit(np.array(v, dtype=float))


# ---- regular 4-polytopes ------------------------------------------------------------------------


def _five_cell() -> np.ndarray:
    # The unit vectors of R^5 lie in the hyperplane sum = 1: express them in a basis of it.
    e = np.eye(5) - 0.2
    basis = np.linalg.svd(e)[2][:4]
    return e @ basis.T


def _six_hundred_cell_raw() -> np.ndarray:
    v = [s * np.eye(4)[i] for i in range(4) for s in (1, -1)]
    v += list(itertools.product((0.5, -0.5), repeat=4))
    for p in _even_permutations([PHI / 2, 0.5, 1 / (2 * PHI), 0.0]):
        v += _signs(p)
    return _unique_rows(np.array(v, dtype=float))


@lru_cache(maxsize=None)
def _six_hundred_cell() -> Polytope:
    return Polytope.from_vertices(_fit(_six_hundred_cell_raw()))


def _regular(name: str) -> Polytope:
    if name == "5-cell":
        return Polytope.from_vertices(_fit(_five_cell()))
    if name == "tesseract":
        return Polytope.from_vertices(_fit(np.array(list(itertools.product((1, -1), repeat=4)), float)))
    if name == "16-cell":
        return Polytope.from_vertices(_fit(np.vstack([np.eye(4), -np.eye(4)])))
    if name == "24-cell":
        v = []
        for i, j in itertools.combinations(range(4), 2):
            for si, sj in itertools.product((1, -1), repeat=2):
                p = np.zeros(4)
                p[i], p[j] = si, sj
                v.append(p)
        return Polytope.from_vertices(_fit(np.array(v)))
    if name == "600-cell":
        return _six_hundred_cell()
    if name == "120-cell":
        # The 120-cell is the dual of the 600-cell: its vertices point at the 600-cell's cells.
        return Polytope.from_vertices(_fit(_six_hundred_cell().normals))
    raise AssertionError(name)


# ---- products, pyramids, look-alikes -------------------------------------------------------------


def _count(key, value, low, high) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise GeometryError(f"parameter {key!r}: expected an integer {low}..{high}, got {value!r}")
    return int(value)


def _prism(base: str, subdivisions: int) -> list[Polytope]:
    b = polyhedron(base, subdivisions)
    v = np.vstack([np.c_[b, np.full(len(b), -0.5)], np.c_[b, np.full(len(b), 0.5)]])
    return [Polytope.from_vertices(v)]


def _polygon(n: int) -> np.ndarray:
    a = 2 * np.pi * np.arange(n) / n
    return 0.5 * np.c_[np.cos(a), np.sin(a)]


def _duoprism(p: int, q: int) -> list[Polytope]:
    a, b = _polygon(_count("p", p, 3, 64)), _polygon(_count("q", q, 3, 64))
    v = np.array([[x, y, z, w] for x, y in a for z, w in b])
    return [Polytope.from_vertices(v)]


def _pyramid(base: str, subdivisions: int) -> list[Polytope]:
    b = polyhedron(base, subdivisions)
    v = np.vstack([np.c_[b, np.full(len(b), 0.5)], [[0, 0, 0, -0.5]]])
    return [Polytope.from_vertices(v)]


def _cone(subdivisions: int) -> list[Polytope]:
    return _pyramid("ball", subdivisions)


def _flat_front(subdivisions: int) -> list[Polytope]:
    return _prism("ball", subdivisions)


HOLLOW_DEPTH = 0.75


def _hollow_front(subdivisions: int) -> list[Polytope]:
    """Ball x [-1/2, 1/2] minus a cone dug into its front: the front w = -1/2 + depth (1 - g(x)).

    g is the gauge of the polyhedral ball (g = a_i . x on the sector over its facet i), so the solid
    is the union over facets i of the convex pieces {x in sector i, w >= -1/2 + depth (1 - a_i.x),
    w <= 1/2}: one convex part per facet of the ball.
    """
    ball = polyhedron("ball", subdivisions)
    hull = ConvexHull(ball)
    parts = []
    for tri, eq in zip(hull.simplices, hull.equations):
        a = eq[:3] / -eq[3]                       # facet plane a . x = 1
        rows = []
        corners = ball[tri]
        for i in range(3):
            m = np.cross(corners[i], corners[(i + 1) % 3])
            if m @ corners[(i + 2) % 3] > 0:
                m = -m
            rows.append([*m, 0.0, 0.0])          # m . x <= 0: the sector's side through the origin
        rows.append([*a, 0.0, 1.0])
        rows.append([0, 0, 0, 1.0, 0.5])
        rows.append([*(-HOLLOW_DEPTH * a), -1.0, 0.5 - HOLLOW_DEPTH])
        parts.append(Polytope.from_halfspaces(np.array(rows)))
    return parts


_BALL_DOC = "over a geodesic ball of radius 1/2 (icosahedron split `subdivisions` times, default 1)"

CATALOG: dict[str, _Entry] = {
    "5-cell": _Entry(lambda: [_regular("5-cell")], {}, "regular simplex (5 tetrahedra); size 1: largest |coordinate| 1/2"),
    "tesseract": _Entry(lambda: [_regular("tesseract")], {}, "hypercube (8 cubes); size = edge length, vertices (+-1/2)^4"),
    "16-cell": _Entry(lambda: [_regular("16-cell")], {}, "cross-polytope (16 tetrahedra); size 1: vertices +-1/2 on the axes"),
    "24-cell": _Entry(lambda: [_regular("24-cell")], {}, "24 octahedra; size 1: vertices permutations of (+-1/2, +-1/2, 0, 0)"),
    "120-cell": _Entry(lambda: [_regular("120-cell")], {}, "120 dodecahedra; size 1: largest |coordinate| 1/2"),
    "600-cell": _Entry(lambda: [_regular("600-cell")], {}, "600 tetrahedra; size 1: largest |coordinate| 1/2"),
    "prism": _Entry(_prism, {"base": "cube", "subdivisions": 1},
                    f"a polyhedron `base` ({', '.join(POLYHEDRA)}) in xyz, fitting [-1/2,1/2]^3, times w in [-1/2, 1/2]"),
    "duoprism": _Entry(_duoprism, {"p": 3, "q": 4},
                       "a p-gon in the xy plane times a q-gon in the zw plane, both of circumradius 1/2"),
    "pyramid": _Entry(_pyramid, {"base": "cube", "subdivisions": 1},
                      "pyramid over a polyhedron `base` fitting [-1/2,1/2]^3 at w = 1/2, apex (0,0,0,-1/2) toward the viewer"),
    "cone": _Entry(_cone, {"subdivisions": 1},
                   f"the paper's 4D cone (convex front): pyramid {_BALL_DOC} at w = 1/2, apex (0,0,0,-1/2) toward the viewer"),
    "flat-front": _Entry(_flat_front, {"subdivisions": 1},
                         f"flat front look-alike of the cone: prism {_BALL_DOC}, w in [-1/2, 1/2]"),
    "hollow-front": _Entry(_hollow_front, {"subdivisions": 1},
                           f"concave front look-alike of the cone (a union): prism {_BALL_DOC}, w in [-1/2, 1/2], with a cone "
                           f"dug into its front down to w = {HOLLOW_DEPTH - 0.5} at the centre; one convex part per ball facet"),
}


def list_shapes() -> list[str]:
    """Names of the catalog shapes."""
    return list(CATALOG)


def shape_params(name: str) -> dict:
    """The parameters a catalog shape takes, with their defaults."""
    return dict(_entry(name).defaults)


def _entry(name: str) -> _Entry:
    try:
        return CATALOG[name]
    except (KeyError, TypeError):
        raise GeometryError(f"unknown shape {name!r}; expected one of {', '.join(CATALOG)}") from None


def get_shape(name: str, **params) -> Shape:
    """The catalog shape `name` with its parameters (unknown parameters are an error); cached."""
    entry = _entry(name)
    unknown = set(params) - set(entry.defaults)
    if unknown:
        expected = ", ".join(entry.defaults) or "no parameters"
        raise GeometryError(f"shape {name!r}: unknown parameter(s) {', '.join(sorted(unknown))}; expected {expected}")
    full = {**entry.defaults, **params}
    return _cached(name, tuple(sorted(full.items())))


@lru_cache(maxsize=64)
def _cached(name: str, items: tuple) -> Shape:
    entry = CATALOG[name]
    params = dict(items)
    return Shape(name=name, params=params, parts=list(entry.build(**params)), doc=entry.doc)

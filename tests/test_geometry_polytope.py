"""Convex 4-polytopes and the shape catalog: counts, Euler, faces, cells, size convention."""
import itertools

import numpy as np
import pytest

from touch4d.geometry.polytope import GeometryError, Polytope
from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.shapes import get_shape, list_shapes

REGULAR = {
    "5-cell": (5, 10, 10, 5),
    "tesseract": (16, 32, 24, 8),
    "16-cell": (8, 24, 32, 16),
    "24-cell": (24, 96, 96, 24),
    "120-cell": (600, 1200, 720, 120),
    "600-cell": (120, 720, 1200, 600),
}
CELL_SIZES = {"5-cell": 4, "tesseract": 6, "16-cell": 4, "24-cell": 8, "120-cell": 12, "600-cell": 4}
EVERY_SHAPE = [(name, {}) for name in list_shapes()] + [
    ("prism", {"base": b}) for b in ("tetrahedron", "octahedron", "dodecahedron", "icosahedron", "ball")
] + [("duoprism", {"p": 5, "q": 7}), ("pyramid", {"base": "dodecahedron"}), ("cone", {"subdivisions": 0})]


@pytest.mark.parametrize("name", REGULAR)
def test_regular_polytope_counts_and_cells(name):
    (poly,) = get_shape(name).parts
    assert poly.counts == REGULAR[name]
    # Every cell of a regular polytope is the same regular polyhedron.
    assert {len(f) for f in poly.cell_faces} == {CELL_SIZES[name]}


def test_regular_polytopes_have_equal_edges():
    for name in REGULAR:
        (poly,) = get_shape(name).parts
        lengths = np.linalg.norm(poly.vertices[poly.edges[:, 0]] - poly.vertices[poly.edges[:, 1]], axis=1)
        assert np.ptp(lengths) < 1e-9, name


@pytest.mark.parametrize("name,params", EVERY_SHAPE, ids=lambda x: str(x))
def test_every_part_is_a_closed_convex_boundary(name, params):
    shape = get_shape(name, **params)
    for poly in shape.parts:
        v, e, f, c = poly.counts
        assert v - e + f - c == 0
        # Outward unit normals; every vertex inside, the centre strictly inside.
        assert np.allclose(np.linalg.norm(poly.normals, axis=1), 1)
        assert poly.contains(poly.vertices, tol=1e-9).all()
        assert np.all(poly.normals @ poly.center < poly.offsets - 1e-6)
        for k, face in enumerate(poly.faces):
            pts = poly.vertices[face]
            # Planar: the face lies on both of its cells' hyperplanes, and spans exactly 2 dimensions.
            for cell in poly.face_cells[k]:
                assert np.allclose(pts @ poly.normals[cell], poly.offsets[cell], atol=1e-9)
            sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
            assert sv[1] > 1e-6 and sv[2] < 1e-9
            # Convex in cyclic order: consecutive turns all have the same orientation in the face plane.
            basis = np.linalg.svd(pts - pts.mean(axis=0))[2][:2]
            q = (pts - pts.mean(axis=0)) @ basis.T
            d1 = np.roll(q, -1, axis=0) - q
            d2 = np.roll(q, -2, axis=0) - np.roll(q, -1, axis=0)
            turns = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
            assert np.all(turns > 1e-12) or np.all(turns < -1e-12)
        # Each face's sides are edges; each edge lies on at least 3 faces (a 4-polytope is 4-dimensional).
        assert min(len(x) for x in poly.topology.edge_faces) >= 3
        # Each cell is a closed polyhedron: each of its faces meets the others along all sides.
        for cell_faces in poly.cell_faces:
            sides = np.concatenate([poly.topology.face_edges[poly.topology.face_starts[f]:poly.topology.face_starts[f + 1]]
                                    for f in cell_faces])
            assert np.all(np.bincount(sides)[np.unique(sides)] == 2)


@pytest.mark.parametrize("name,params", EVERY_SHAPE, ids=lambda x: str(x))
def test_size_one_fits_the_unit_tesseract_and_touches_it(name, params):
    shape = get_shape(name, **params)
    v = np.vstack([p.vertices for p in shape.parts])
    assert np.abs(v).max() == pytest.approx(0.5)
    assert shape.doc


def test_tesseract_front_cell_convention():
    (t,) = get_shape("tesseract").parts
    world = t.transformed(position=[0, 0, 0, 1.5], size=1.0)
    front = np.nonzero(np.isclose(world.normals @ [0, 0, 0, -1], 1))[0]
    assert len(front) == 1
    assert world.offsets[front[0]] == pytest.approx(-1.0)        # -w <= -1: the cell at w = 1.0
    assert np.sort(np.unique(np.round(t.vertices, 12))).tolist() == [-0.5, 0.5]


def test_cone_points_at_viewer_and_look_alikes_share_the_silhouette():
    cone = get_shape("cone").parts[0]
    assert np.argmin(cone.vertices[:, 3]) == np.argmin(np.linalg.norm(cone.vertices[:, :3], axis=1))
    assert cone.vertices[:, 3].min() == pytest.approx(-0.5)
    flat = get_shape("flat-front").parts[0]
    hollow = np.vstack([p.vertices for p in get_shape("hollow-front").parts])
    rim = lambda v: np.unique(np.round(v[np.linalg.norm(v[:, :3], axis=1) > 0.49, :3], 9), axis=0)
    assert np.array_equal(rim(cone.vertices), rim(flat.vertices))
    assert np.array_equal(rim(flat.vertices), rim(hollow))
    # Flat front at w = -1/2; the hollow's front reaches w = 1/4 at the centre.
    assert flat.vertices[:, 3].min() == pytest.approx(-0.5)
    centre = [p for p in get_shape("hollow-front").parts if p.contains([[0, 0, 0, 0.3]], tol=1e-9).all()]
    assert centre and not any(p.contains([[0, 0, 0, 0.2]], tol=-1e-9).all() for p in get_shape("hollow-front").parts)


def test_from_halfspaces_equals_from_vertices_and_drops_redundant_ones():
    cube = np.array(list(itertools.product((0.5, -0.5), repeat=4)))
    a = Polytope.from_vertices(np.vstack([cube, 0.1 * cube]))          # interior points are not vertices
    rows = [[*s * np.eye(4)[i], 0.5] for i in range(4) for s in (1, -1)] + [[1, 1, 0, 0, 5.0]]
    b = Polytope.from_halfspaces(np.array(rows))
    assert a.counts == b.counts == (16, 32, 24, 8)
    key = lambda p: sorted(map(tuple, np.round(p.vertices, 9)))
    assert key(a) == key(b)


def test_transformed_moves_vertices_and_half_spaces_together():
    (poly,) = get_shape("24-cell").parts
    r = rotation_from_list([["xw", 20], ["yz", 35], ["zw", -50]])
    world = poly.transformed(r, [0.1, -0.2, 0.3, 2.0], 1.7)
    assert np.allclose(world.vertices, 1.7 * poly.vertices @ r.T + [0.1, -0.2, 0.3, 2.0])
    assert world.contains(world.vertices, tol=1e-9).all()
    assert world.topology is poly.topology
    for cell, verts in enumerate(world.cell_vertices):
        assert np.allclose(world.vertices[verts] @ world.normals[cell], world.offsets[cell])


@pytest.mark.parametrize("points,reason", [
    (np.zeros((3, 4)), "at least 5"),
    (np.c_[np.random.default_rng(0).normal(size=(8, 3)), np.zeros(8)], "span 4"),
    (np.r_[np.eye(4), [[np.nan, 0, 0, 0]]], "finite"),
])
def test_bad_vertices_are_rejected(points, reason):
    with pytest.raises(GeometryError, match=reason):
        Polytope.from_vertices(points)


@pytest.mark.parametrize("rows,reason", [
    ([[1, 0, 0, 0, 1]] * 5, "finite region"),
    ([[s * e for e in np.eye(4)[i]] + [-0.5] for i in range(4) for s in (1, -1)], "no interior"),
    ([[0, 0, 0, 0, 1]] * 5, "zero normal"),
])
def test_bad_halfspaces_are_rejected(rows, reason):
    with pytest.raises(GeometryError, match=reason):
        Polytope.from_halfspaces(np.array(rows, dtype=float))


def test_catalog_rejects_unknown_names_and_parameters():
    with pytest.raises(GeometryError, match="unknown shape 'hyperdonut'"):
        get_shape("hyperdonut")
    with pytest.raises(GeometryError, match="unknown parameter"):
        get_shape("tesseract", edge=2)
    with pytest.raises(GeometryError, match="'p': expected an integer"):
        get_shape("duoprism", p=2)
    with pytest.raises(GeometryError, match="unknown polyhedron"):
        get_shape("prism", base="torus")


def test_edge_directions_and_face_planes_belong_to_the_polytope():
    # a tesseract turned in xw: its edges run along the 4 turned axes, its 2-faces lie in the 6 planes of
    # two of them (closed form: the turned axes are the rotation's columns)
    c, s = np.cos(0.5), np.sin(0.5)
    r = np.eye(4)
    r[0, 0], r[0, 3], r[3, 0], r[3, 3] = c, -s, s, c
    poly = get_shape("tesseract").parts[0].transformed(r, [0.3, 0, 0, 1.0], 0.4)
    dirs = poly.edge_directions
    assert dirs.shape == (4, 4)
    np.testing.assert_allclose(np.abs(dirs @ r), np.eye(4)[np.argmax(np.abs(dirs @ r), axis=1)], atol=1e-12)
    planes = poly.face_planes
    assert planes.shape == (6, 2, 4)
    spanned = sorted(tuple(np.nonzero(np.round((p @ r) ** 2, 9).sum(axis=0))[0]) for p in planes)
    assert spanned == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]       # each pair of turned axes once
    np.testing.assert_allclose(np.einsum("pik,pjk->pij", planes, planes), np.tile(np.eye(2), (6, 1, 1)), atol=1e-12)

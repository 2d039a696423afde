"""Back-cell culling, clip units, front/behind, and subtracting hidden regions."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.rotation import PLANES, plane_rotation
from touch4d.geometry.shapes import get_shape
from touch4d.geometry.visibility import (Relation, _relation_lp, clip_units, facing_cells, in_region, relation,
                                         relations, silhouette_faces, subtract_polygon, subtract_segment,
                                         view_halfspaces, visible_edges, visible_faces)


def place(name, position, size=1.0, orientation=None, **params):
    return get_shape(name, **params).parts[0].transformed(orientation, position, size)


def random_rotation(angles):
    r = np.eye(4)
    for plane, a in zip(PLANES, angles):
        r = plane_rotation(plane, a) @ r
    return r


# ---- culling -------------------------------------------------------------------------------------


def test_culling_an_upright_tesseract_keeps_its_front_cell():
    t = place("tesseract", [0, 0, 0, 1.5])
    front = facing_cells(t)
    assert front.sum() == 1 and np.allclose(t.normals[front][0], [0, 0, 0, -1])
    assert len(visible_faces(t)) == 6 and len(visible_edges(t)) == 12
    assert len(silhouette_faces(t)) == 6
    # In perspective from the axis, the side cells are seen edge-on-or-away: still only the front cell.
    assert facing_cells(t, 3.0).sum() == 1


def test_culling_a_tesseract_turned_in_xw_shows_two_cells():
    r = plane_rotation("xw", np.radians(30))
    t = place("tesseract", [0, 0, 0, 1.5], orientation=r)
    expected = np.array([(-r[:, 0]), (-r[:, 3])])
    got = t.normals[facing_cells(t)]
    assert len(got) == 2
    assert all(np.isclose(got @ e, 1).any() for e in expected)
    assert len(visible_faces(t)) == 11                    # two cubes sharing one square


def test_perspective_shows_the_inner_side_of_an_off_axis_tesseract():
    t = place("tesseract", [1.5, 0, 0, 1.5])
    assert facing_cells(t).sum() == 1
    seen = t.normals[facing_cells(t, eye_distance=3.0)]
    assert len(seen) == 2 and np.isclose(seen @ [-1, 0, 0, 0], 1).any()


# ---- clip units ----------------------------------------------------------------------------------


def test_clip_units_of_an_upright_tesseract_are_its_cube():
    units = clip_units(place("tesseract", [0.2, 0, 0, 1.5], 0.5))
    assert len(units) == 6
    inside = in_region(units, [[0.2, 0, 0], [0.44, 0.24, -0.24], [0.46, 0, 0], [-0.1, 0, 0]])
    assert inside.tolist() == [True, True, False, False]


@settings(max_examples=30, deadline=None)
@given(shape=st.sampled_from(["tesseract", "5-cell", "24-cell", "cone", "duoprism"]),
       angles=st.lists(st.floats(-np.pi, np.pi), min_size=6, max_size=6),
       offset=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
       perspective=st.booleans())
def test_clip_region_is_the_projected_silhouette(shape, angles, offset, perspective):
    eye = 2.5 if perspective else None
    params = {"subdivisions": 0} if shape == "cone" else {}
    poly = place(shape, [*offset, 1.5], 1.0, random_rotation(angles), **params)
    units = clip_units(poly, eye)
    from touch4d.geometry.projection import project
    image = project(poly.vertices, "perspective" if perspective else "orthographic", eye)
    lo, hi = image.min(axis=0), image.max(axis=0)
    points = np.random.default_rng(1).uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (3000, 3))
    # The silhouette: screen points whose sight line meets the object.
    _, hit = RayCaster([(0, poly)], eye_distance=eye).cast(points)
    margin = (points @ units[:, :3].T - units[:, 3]).max(axis=1)
    clear = np.abs(margin) > 1e-6
    assert np.array_equal(in_region(units, points)[clear], (hit >= 0)[clear])
    assert 150 < (hit >= 0).sum() < 2900


# ---- front / behind ------------------------------------------------------------------------------


def test_stacked_side_by_side_and_interpenetrating():
    near = place("tesseract", [0, 0, 0, 1.0], 0.5)
    far = place("tesseract", [0.1, 0, 0, 2.5])
    beside = place("tesseract", [0.8, 0, 0, 1.0], 0.5)
    through = place("tesseract", [0.2, 0, 0, 1.2], 0.5, plane_rotation("xw", 0.5))
    assert relation(near, far) == Relation.FRONT and relation(far, near) == Relation.BEHIND
    assert relation(near, beside) == Relation.APART
    assert relation(near, through) == Relation.INTERSECTING
    r = relations([near, far, beside, through])
    assert r[0, 1] == 1 and r[1, 0] == -1 and r[0, 2] == 0 and r[0, 3] == 2 and r[3, 0] == 2
    assert np.all(np.diag(r) == 0)


def test_perspective_order_follows_the_eye():
    # Eye at w = -1. far: x in [-0.5, 0.5], w in [2.5, 3.5]; its image is |x| <= 0.5 / 3.5 = 0.143.
    far = place("tesseract", [0.0, 0, 0, 3.0])
    # x in [0.35, 0.45], w in [0.95, 1.05]: overlaps far orthographically; its image starts at
    # 0.35 / 2.05 = 0.171, beside far's.
    near = place("tesseract", [0.4, 0, 0, 1.0], 0.1)
    assert relation(near, far) == Relation.FRONT
    assert relation(near, far, eye_distance=1.0) == Relation.APART
    # x in [0.65, 0.75] at w = 3 and x in [0.25, 0.35] at w = 1: apart orthographically, but the images
    # 0.144..0.214 and 0.122..0.179 overlap, the nearer one in front.
    back = place("tesseract", [0.7, 0, 0, 3.0], 0.1)
    front = place("tesseract", [0.3, 0, 0, 1.0], 0.1)
    assert relation(front, back) == Relation.APART
    assert relation(front, back, eye_distance=1.0) == Relation.FRONT
    assert relation(back, front, eye_distance=1.0) == Relation.BEHIND


pair = st.tuples(st.lists(st.floats(-np.pi, np.pi), min_size=6, max_size=6),
                 st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(0.8, 2.5)))


@settings(max_examples=40, deadline=None)
@given(a=pair, b=pair, shape=st.sampled_from(["tesseract", "24-cell", "5-cell"]), perspective=st.booleans())
def test_relation_agrees_with_sight_lines_and_the_exact_programs(a, b, shape, perspective):
    eye = 2.0 if perspective else None
    pa = place(shape, a[1], 0.6, random_rotation(a[0]))
    pb = place(shape, b[1], 0.6, random_rotation(b[0]))
    got = relations([pa, pb], eye)[0, 1]
    assert got == _relation_lp(view_halfspaces(pa, eye), view_halfspaces(pb, eye))
    points = np.random.default_rng(2).uniform(-1.2, 1.2, (4000, 3))
    enter, leave = RayCaster([(0, pa), (1, pb)], eye_distance=eye).intervals(points)
    both = ~np.isnan(enter).any(axis=1)
    deep = both & (leave[:, 0] - enter[:, 0] > 1e-6) & (leave[:, 1] - enter[:, 1] > 1e-6)
    if got == Relation.FRONT:
        assert np.all(leave[both, 0] <= enter[both, 1] + 1e-7)
    elif got == Relation.BEHIND:
        assert np.all(leave[both, 1] <= enter[both, 0] + 1e-7)
    elif got == Relation.APART:
        assert not deep.any()


# ---- subtracting hidden regions ------------------------------------------------------------------


def area(poly):
    p = poly - poly[0]
    return 0.5 * np.linalg.norm(np.cross(p[1:-1], p[2:]).sum(axis=0))


def clip_inside(poly, units):
    from touch4d.geometry.visibility import _clip
    for m in units:
        poly = _clip(poly, m[:3], m[3])
    return poly


@settings(max_examples=60, deadline=None)
@given(angles=st.lists(st.floats(-np.pi, np.pi), min_size=6, max_size=6), seed=st.integers(0, 10**6))
def test_subtract_polygon_leaves_exactly_the_visible_part(angles, seed):
    rng = np.random.default_rng(seed)
    units = clip_units(place("24-cell", [0, 0, 0, 1.5], 1.0, random_rotation(angles)))
    # A random convex polygon: a regular hexagon in a random plane through a random centre.
    u, v = np.linalg.qr(rng.normal(size=(3, 2)))[0].T
    a = np.linspace(0, 2 * np.pi, 7)[:-1]
    poly = rng.uniform(-0.4, 0.4, 3) + 0.5 * (np.outer(np.cos(a), u) + np.outer(np.sin(a), v))
    pieces = subtract_polygon(poly, units)
    hidden = clip_inside(poly, units)
    hidden_area = area(hidden) if len(hidden) >= 3 else 0.0
    assert sum(area(p) for p in pieces) == pytest.approx(area(poly) - hidden_area, abs=1e-9)
    for p in pieces:
        assert len(p) >= 3
        # Each piece is convex, planar with the polygon, and outside the hidden region.
        assert not in_region(units, p.mean(axis=0)[None], tol=-1e-9)[0]
        assert np.allclose((p - poly[0]) @ np.cross(u, v), 0, atol=1e-9)


def test_subtract_polygon_untouched_and_hidden():
    units = clip_units(place("tesseract", [0, 0, 0, 1.5], 1.0))
    far = np.array([[2, 0, 0], [3, 0, 0], [3, 1, 0.0]])
    assert len(subtract_polygon(far, units)) == 1 and subtract_polygon(far, units)[0] is not None
    assert subtract_polygon(0.1 * far, units) == []


def test_subtract_segment():
    units = clip_units(place("tesseract", [0, 0, 0, 1.5], 1.0))
    pieces = subtract_segment([[-1, 0.1, 0], [2, 0.1, 0]], units)
    assert len(pieces) == 2
    assert np.allclose(pieces[0], [[-1, 0.1, 0], [-0.5, 0.1, 0]])
    assert np.allclose(pieces[1], [[0.5, 0.1, 0], [2, 0.1, 0]])
    assert subtract_segment([[-0.2, 0, 0], [0.2, 0.1, 0.1]], units) == []
    (whole,) = subtract_segment([[0.6, -1, 0], [0.6, 1, 0]], units)
    assert np.allclose(whole, [[0.6, -1, 0], [0.6, 1, 0]])
    # Along the boundary of the region (on one unit's plane): kept, like a polygon touching it.
    assert len(subtract_segment([[0.5, -0.2, 0], [0.5, 0.2, 0]], units)) == 1
    assert subtract_segment([[0.5 - 1e-6, -0.2, 0], [0.5 - 1e-6, 0.2, 0]], units) == []

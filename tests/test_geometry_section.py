"""Cross-sections of convex 4-polytopes by w = c, against closed forms and an independent computation."""
import itertools
import json

import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from touch4d.geometry.rotation import PLANES, is_rotation, plane_rotation, rotation_from_list
from touch4d.geometry.section import SectionCaster, cross_section, kernel, w_extent
from touch4d.geometry.shapes import get_shape, list_shapes

from test_geometry_cli import run


def shape(name, size=1.0, orientation=None, position=None, **params):
    return get_shape(name, **params).parts[0].transformed(orientation, position, size)


def turn(rng):
    """A 4D rotation through all six planes by angles the seeded generator picks: the same matrix
    wherever the test runs (a library's random rotation may differ with its version or its BLAS)."""
    r = rotation_from_list(zip(PLANES, rng.uniform(0.0, 360.0, len(PLANES))))
    assert is_rotation(r)
    return r


def same_points(a, b, tol=1e-7):
    """Whether two point sets are equal as sets."""
    a, b = np.asarray(a), np.asarray(b)
    if len(a) != len(b):
        return False
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return bool(np.all(d.min(axis=0) < tol) and np.all(d.min(axis=1) < tol))


def independent_section(vertices4, c):
    """The section as the hull of where every segment between two vertices crosses w = c (each edge of
    the polytope is such a segment; the other segments lie inside it): vertices of the 3D hull, volume."""
    v = np.asarray(vertices4)
    points = [p[:3] for p in v if abs(p[3] - c) < 1e-12]
    for a, b in itertools.combinations(v, 2):
        if (a[3] - c) * (b[3] - c) < 0:
            t = (c - a[3]) / (b[3] - a[3])
            points.append((a + t * (b - a))[:3])
    hull = ConvexHull(np.array(points))
    return hull.points[hull.vertices], hull.volume


@pytest.mark.parametrize("c", [0.0, 0.2, -0.41, 0.499])
@pytest.mark.parametrize("size", [1.0, 2.5])
def test_a_tesseract_cut_within_half_its_size_is_a_cube_of_its_size(c, size):
    section = cross_section(shape("tesseract", size, position=[0.3, -0.2, 0.1, 1.5]), 1.5 + c * size)
    cube = np.array(list(itertools.product([-0.5, 0.5], repeat=3))) * size + [0.3, -0.2, 0.1]
    assert same_points(section.vertices, cube)
    assert len(section.faces) == 6 and all(len(f) == 4 for f in section.faces)
    assert section.volume == pytest.approx(size ** 3, rel=1e-12)


def test_the_24_cell_cut_at_w_0_is_the_cuboctahedron_of_its_vertices_with_w_0():
    cell24 = shape("24-cell", 2.0)          # vertices: the permutations of (+-1, +-1, 0, 0)
    expected = [p for p in set(itertools.permutations([1, 1, 0, 0]))]
    corners = {tuple(np.array(p) * s) for p in expected for s in itertools.product([1, -1], repeat=4)}
    assert same_points(cell24.vertices, sorted(corners))
    section = cross_section(cell24, 0.0)
    in_plane = cell24.vertices[np.abs(cell24.vertices[:, 3]) < 1e-12, :3]
    assert len(in_plane) == 12 and same_points(section.vertices, in_plane)
    sizes = sorted(len(f) for f in section.faces)
    assert sizes == [3] * 8 + [4] * 6                        # a cuboctahedron: 8 triangles, 6 squares
    assert section.volume == pytest.approx(5 * np.sqrt(2) / 3 * np.sqrt(2) ** 3)   # edge sqrt(2)


@pytest.mark.parametrize("c", [0.0, 0.3, -0.75])
def test_the_16_cell_cut_is_an_octahedron(c):
    section = cross_section(shape("16-cell", 2.0), c)        # |x| + |y| + |z| <= 1 - |c|
    r = 1 - abs(c)
    assert same_points(section.vertices, np.vstack([np.eye(3) * r, -np.eye(3) * r]))
    assert len(section.faces) == 8
    assert section.volume == pytest.approx(4 / 3 * r ** 3)


@pytest.mark.parametrize("degrees", [10, 30, 44])
def test_a_tesseract_turned_in_xw_is_cut_in_a_longer_box(degrees):
    theta = np.radians(degrees)                              # the square's chord through its centre: 1 / cos
    section = cross_section(shape("tesseract", orientation=plane_rotation("xw", theta)), 0.0)
    assert section.volume == pytest.approx(1 / np.cos(theta))
    assert np.ptp(section.vertices, axis=0) == pytest.approx([1 / np.cos(theta), 1, 1])


@pytest.mark.parametrize("name", [n for n in list_shapes() if n not in ("120-cell", "600-cell")] + ["600-cell"])
def test_turned_shapes_match_the_hull_of_the_crossings(name):
    rng = np.random.default_rng(sum(map(ord, name)))
    for trial in range(3):
        r = turn(rng)
        body = shape(name, 1.3, r, rng.uniform(-0.5, 0.5, 4))
        lo, hi = w_extent(body.vertices)
        c = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
        section = cross_section(body, c)
        vertices, volume = independent_section(body.vertices, c)
        assert same_points(section.vertices, vertices, 1e-6), (name, trial)
        assert section.volume == pytest.approx(volume, rel=1e-9), (name, trial)
        # every face lies on the cell it is said to cut, at w = c
        for face, cell in zip(section.faces, section.face_cell):
            x = np.c_[section.vertices[face], np.full(len(face), c)]
            assert np.allclose(x @ body.normals[cell], body.offsets[cell], atol=1e-9)


@pytest.mark.parametrize("name,volume4", [("tesseract", 1.0), ("16-cell", 2 / 3 / 16), ("24-cell", 0.5)])
def test_the_sections_volumes_integrate_to_the_4d_volume(name, volume4):
    body = shape(name, 1.0, turn(np.random.default_rng(5)))
    # Between two successive vertex heights the section's volume is a cubic in c: Gauss-Legendre with
    # 3 nodes per piece integrates it exactly.
    nodes, weights = np.polynomial.legendre.leggauss(3)
    heights = np.unique(body.vertices[:, 3])
    integral = sum((hi - lo) / 2 * sum(wk * cross_section(body, (lo + hi) / 2 + (hi - lo) / 2 * x).volume
                                       for x, wk in zip(nodes, weights))
                   for lo, hi in zip(heights[:-1], heights[1:]))
    # 16-cell: 2^4 / 4! r^4, r = 1/2; 24-cell: 2 a^4, a = 1/sqrt(2)
    assert integral == pytest.approx(volume4, rel=1e-9)


def test_outside_its_w_extent_a_body_has_no_section():
    body = shape("tesseract", position=[0, 0, 0, 2])
    assert w_extent(body.vertices) == pytest.approx((1.5, 2.5))
    for c in (1.4, 2.6):
        section = cross_section(body, c)
        assert section.empty and section.faces == [] and len(section.vertices) == 0


def test_a_touching_hyperplane_gives_no_volume():
    body = shape("16-cell", 2.0)                             # w = 1 only touches the vertex (0, 0, 0, 1)
    assert cross_section(body, 1.0).volume == 0.0


def test_the_section_caster_agrees_with_the_hull():
    rng = np.random.default_rng(3)
    body = shape("24-cell", 1.0, turn(rng))
    c = 0.1
    vertices, _ = independent_section(body.vertices, c)
    points = rng.uniform(-0.8, 0.8, (4000, 3))
    expected = Delaunay(vertices).find_simplex(points) >= 0
    got = SectionCaster([(0, body)], c).cast(points)[1] == 0
    assert got.shape == (4000,) and 200 < expected.sum() < 3800
    assert np.array_equal(got, expected)


@pytest.mark.parametrize("name,c", [("tesseract", 0.05), ("24-cell", 0.05), ("duoprism", 0.05), ("5-cell", 0.05),
                                    ("tesseract", 0.5)])     # the unturned one: its vertices in the plane
def test_the_batched_triangles_cover_each_section_surface(name, c):
    """Many bodies cut at once (compiled, or where vertices lie in the plane from `polygons`): per body
    the surface and the volume of the hull of the crossings, every face wound outward; a body that
    w = c misses gets no triangle."""
    rng = np.random.default_rng(11)
    base = get_shape(name).parts[0]
    bodies = []
    for fraction in (0.2, 0.4, 0.6, 0.8):    # turned, and moved along w so that c cuts it at this fraction
        r = turn(rng)
        lo, hi = w_extent(base.transformed(r).vertices)
        bodies.append(base.transformed(r, [0, 0, 0, c - lo - fraction * (hi - lo)]))
    bodies.append(base)                      # unturned at the origin: every catalog shape spans w -1/2 .. 1/2
    missed = base.transformed(turn(rng))
    bodies.append(missed.transformed(position=[0, 0, 0, c + 0.1 - w_extent(missed.vertices)[0]]))   # all above c
    k = kernel(base.topology)
    tris, owner, cell = k.triangles(np.stack([b.vertices for b in bodies]), np.stack([b.normals for b in bodies]), c)
    assert not (owner == len(bodies) - 1).any()
    for i, body in enumerate(bodies[:-1]):
        lo, hi = w_extent(body.vertices)
        assert lo < c <= hi, (name, i)
        t = tris[owner == i]
        assert set(cell[owner == i]) <= set(range(len(body.normals)))
        area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=-1)
        vertices, volume = independent_section(body.vertices, c)
        hull = ConvexHull(vertices)
        assert area.sum() == pytest.approx(hull.area, rel=1e-9) and hull.area > 0, (name, i)
        # divergence theorem over the outward-wound fans: the hull's volume
        assert np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6 == pytest.approx(volume, rel=1e-9)
        # wound counterclockwise seen from outside: each normal points away from the section's centre
        normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        big = area > 1e-12
        assert np.all(np.einsum("ij,ij->i", normal[big], t[big, 0] - vertices.mean(axis=0)) > 0)


def test_scene_slice_prints_each_objects_section(capsys):
    assert run(["scene", "slice", "config/scenes/hypercube.yaml", "--w", "1.5", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    part = data["objects"][0]["parts"][0]
    assert data["w"] == 1.5 and len(part["vertices"]) == 8 and len(part["faces"]) == 6
    assert part["volume"] == pytest.approx(1.2 ** 3)         # the scene's tesseract has size 1.2
    assert data["objects"][0]["w_extent"] == pytest.approx([0.9, 2.1])
    assert {f["cell"] for f in part["faces"]} <= set(range(8))
    assert run(["scene", "slice", "config/scenes/hypercube.yaml", "--w", "5"]) == 0
    assert "empty" in capsys.readouterr().out


def test_a_scene_file_names_a_bad_view_or_cut():
    from touch4d.errors import ConfigError
    from touch4d.geometry.scene import parse_scene

    objects = [{"shape": "tesseract", "position": [0, 0, 0, 1.5]}]
    with pytest.raises(ConfigError, match=r"'view'.*projection.*slice.*both"):
        parse_scene({"objects": objects, "view": "sideways"}, "s.yaml")
    with pytest.raises(ConfigError, match="slice_w"):
        parse_scene({"objects": objects, "slice_w": "deep"}, "s.yaml")
    with pytest.raises(ConfigError, match="slice_touch"):
        parse_scene({"objects": objects, "slice_touch": "both"}, "s.yaml")
    scene = parse_scene({"objects": objects, "view": "slice", "slice_w": 1.25, "slice_touch": "projection"})
    assert (scene.view, scene.slice_w, scene.slice_touch) == ("slice", 1.25, "projection")


def test_scene_check_names_the_view(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text("view: both\nslice_w: 1.4\nobjects:\n  - shape: tesseract\n    position: [0, 0, 0, 1.5]\n")
    assert run(["scene", "check", str(path)]) == 0
    assert "orthographic projection; both view at w = 1.4 (touch: section)" in capsys.readouterr().out

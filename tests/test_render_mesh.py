"""The renderer's CPU frame build (no GL): culling, centre copies and clipping, checked against the
geometry core's one-polygon-at-a-time reference (touch4d.geometry.visibility)."""
from __future__ import annotations

import numpy as np
import pytest

from touch4d.geometry import visibility
from touch4d.geometry.projection import project
from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.shapes import get_shape
from touch4d.render.clip import Body, MeshBuilder
from touch4d.render.frame import FLOATS_PER_VERTEX, Style

TESSERACT = get_shape("tesseract").parts[0]
RED, GREEN, BLUE = np.array([1.0, 0, 0, 1]), np.array([0, 1.0, 0, 1]), np.array([0, 0, 1.0, 1])
PLANES = ("xy", "xz", "xw", "yz", "yw", "zw")


def random_rotation(rng, spread=0.7):
    r = np.eye(4)
    for plane in PLANES:
        r = plane_rotation(plane, rng.uniform(-spread, spread)) @ r
    return r


def eye_of(projection):
    return 3.0 if projection == "perspective" else None


def triangle_area(vertices: np.ndarray, color) -> float:
    tri = vertices.reshape(-1, 3, FLOATS_PER_VERTEX)
    tri = tri[np.all(np.abs(tri[:, 0, 3:6] - color[:3]) < 1e-6, axis=1)]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1, :3] - tri[:, 0, :3], tri[:, 2, :3] - tri[:, 0, :3]), axis=1).sum())


def segment_length(vertices: np.ndarray, color) -> float:
    seg = vertices.reshape(-1, 2, FLOATS_PER_VERTEX)
    seg = seg[np.all(np.abs(seg[:, 0, 3:6] - color[:3]) < 1e-6, axis=1)]
    return float(np.linalg.norm(seg[:, 1, :3] - seg[:, 0, :3], axis=1).sum())


def polygon_area(p: np.ndarray) -> float:
    return float(0.5 * np.linalg.norm(np.cross(p[1:-1] - p[0], p[2:] - p[0]).sum(axis=0)))


def reference(world: list, projection: str):
    """Visible area and edge length of each body after clipping, the geometry core's way."""
    eye = eye_of(projection)
    rel = visibility.relations(world, eye)
    areas, lengths = [], []
    for b, poly in enumerate(world):
        hiders = [visibility.clip_units(world[a], eye) for a in range(len(world)) if rel[a, b] == visibility.Relation.FRONT]
        area = 0.0
        for f in visibility.visible_faces(poly, eye):
            pieces = [project(poly.vertices[poly.faces[f]], projection, eye)]
            for units in hiders:
                pieces = [q for p in pieces for q in visibility.subtract_polygon(p, units)]
            area += sum(polygon_area(p) for p in pieces)
        length = 0.0
        for e in visibility.visible_edges(poly, eye):
            pieces = [project(poly.vertices[poly.edges[e]], projection, eye)]
            for units in hiders:
                pieces = [q for p in pieces for q in visibility.subtract_segment(p, units)]
            length += sum(float(np.linalg.norm(p[1] - p[0])) for p in pieces)
        areas.append(area)
        lengths.append(length)
    return areas, lengths


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_front_cells_match_back_cell_culling(projection):
    rng = np.random.default_rng(3)
    builder = MeshBuilder()
    for _ in range(10):
        body = Body(TESSERACT, random_rotation(rng, 1.5), np.r_[rng.uniform(-0.3, 0.3, 3), 2.0], 1.0, GREEN)
        mesh = builder.build([body], projection, 3.0)
        world = TESSERACT.transformed(body.orientation, body.position, body.size)
        expected = np.nonzero(visibility.facing_cells(world, eye_of(projection)))[0]
        assert mesh.visible_cells[0].tolist() == expected.tolist()
        n_faces = len(visibility.visible_faces(world, eye_of(projection)))
        assert mesh.counts["fill_triangles"] == 2 * n_faces          # tesseract faces are squares
        assert mesh.counts["edge_segments"] == len(visibility.visible_edges(world, eye_of(projection)))
        assert mesh.counts["centre_triangles"] == 12 * len(expected)   # 6 squares per centre cube


def test_centre_copy_is_the_cell_scaled_about_its_centroid():
    body = Body(TESSERACT, np.eye(4), np.array([0.0, 0, 0, 2]), 1.0, GREEN)
    mesh = MeshBuilder().build([body], style=Style(centre_scale=0.3))
    centre = mesh.centres.reshape(-1, FLOATS_PER_VERTEX)[:, :3]
    # The front cell is the cube [-1/2, 1/2]^3 at w = 1.5; its copy spans 0.3 of it about the centre.
    assert np.allclose(centre.min(axis=0), -0.15) and np.allclose(centre.max(axis=0), 0.15)
    fills = mesh.fills.reshape(-1, FLOATS_PER_VERTEX)[:, :3]
    assert np.allclose(fills.min(axis=0), -0.5) and np.allclose(fills.max(axis=0), 0.5)


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_clipping_matches_reference_subtraction(projection):
    """Random pairs and triples of disjoint tesseracts: the visible area and edge length of every body
    after clipping equal the reference subtraction (culling, clip units, front/behind, convex pieces)."""
    rng = np.random.default_rng(11)
    builder = MeshBuilder()
    colors = [GREEN, RED, BLUE]
    compared = 0
    for trial in range(12):
        n = 2 + trial % 2
        bodies = [Body(TESSERACT, random_rotation(rng), np.r_[rng.uniform(-0.35, 0.35, 3), 1.2 + 1.0 * k], 0.55,
                       colors[k]) for k in range(n)]
        world = [TESSERACT.transformed(b.orientation, b.position, b.size) for b in bodies]
        mesh = builder.build(bodies, projection, 3.0, Style(centres=False))
        areas, lengths = reference(world, projection)
        for k in range(n):
            assert triangle_area(mesh.fills, colors[k]) == pytest.approx(areas[k], rel=1e-6, abs=1e-9)
            assert segment_length(mesh.edges, colors[k]) == pytest.approx(lengths[k], rel=1e-6, abs=1e-9)
        unclipped = builder.build(bodies, projection, 3.0, Style(centres=False, clip=False))
        compared += sum(triangle_area(unclipped.fills, colors[k]) > areas[k] + 1e-6 for k in range(n))
    assert compared >= 5          # the trials really hid something


def test_hidden_centre_copies_are_clipped_too():
    front = Body(TESSERACT, np.eye(4), np.array([0.0, 0, 0, 1.5]), 1.0, GREEN)
    back = Body(TESSERACT, np.eye(4), np.array([0.0, 0, 0, 3.0]), 0.5, RED)
    style = Style(cell_colors=False)
    mesh = MeshBuilder().build([front, back], style=style)
    assert triangle_area(mesh.centres, RED) == 0.0 and triangle_area(mesh.fills, RED) == 0.0
    assert triangle_area(mesh.centres, GREEN) > 0
    # Swapped in depth, the small one is in front and nothing of it is hidden.
    mesh = MeshBuilder().build([Body(TESSERACT, np.eye(4), np.array([0.0, 0, 0, 3.5]), 1.0, GREEN),
                                Body(TESSERACT, np.eye(4), np.array([0.0, 0, 0, 1.5]), 0.5, RED)], style=style)
    assert triangle_area(mesh.fills, RED) == pytest.approx(6 * 0.25)


def test_120_cell_builds_with_its_visible_cells():
    cell120 = get_shape("120-cell").parts[0]
    rng = np.random.default_rng(5)
    body = Body(cell120, random_rotation(rng), np.array([0.0, 0, 0, 2.0]), 1.5, BLUE)
    mesh = MeshBuilder().build([body])
    world = cell120.transformed(body.orientation, body.position, body.size)
    assert len(mesh.visible_cells[0]) == int(visibility.facing_cells(world).sum()) > 30
    assert mesh.fills.dtype == np.float32 and mesh.fills.shape[1] == FLOATS_PER_VERTEX


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_reused_pieces_equal_a_fresh_build_as_bodies_move(projection):
    """The builder reuses the last frame's cut pieces of bodies that kept their pose; every frame of a
    sequence in which single bodies move, recolour or change their front/behind order must equal a
    build from scratch, vertex for vertex."""
    rng = np.random.default_rng(21)
    grid = [(x, y) for x in (-0.3, 0.0, 0.3) for y in (-0.3, 0.3)]
    bodies = [Body(TESSERACT, random_rotation(rng), np.array([x, y, 0.0, 1.2 + 0.5 * (k % 3)]), 0.45,
                   np.r_[rng.uniform(0.2, 1, 3), 1.0], k) for k, (x, y) in enumerate(grid)]
    builder = MeshBuilder()

    def moved(k, rotation=None, position=None, color=None):
        b = bodies[k]
        bodies[k] = Body(b.polytope, b.orientation if rotation is None else rotation @ b.orientation,
                         b.position if position is None else np.asarray(position, float), b.size,
                         b.color if color is None else color, b.object_index)

    steps = [lambda: None,
             lambda: moved(0, rotation=plane_rotation("xw", 0.2)),
             lambda: moved(3, position=bodies[3].position + [0.05, 0, 0, 0]),
             lambda: moved(1, position=np.r_[bodies[1].position[:3], 3.0]),     # from the front row to the back
             lambda: moved(4, position=np.r_[bodies[4].position[:3], 0.9]),     # to the very front
             lambda: moved(2, color=BLUE),
             lambda: moved(5, rotation=plane_rotation("yz", 0.4))]
    previous = None
    for step in steps:
        step()
        mesh = builder.build(bodies, projection, 3.0)
        fresh = MeshBuilder().build(bodies, projection, 3.0)
        for name in ("fills", "centres", "edges"):
            assert np.array_equal(getattr(mesh, name), getattr(fresh, name)), name
        if previous is not None and step is not steps[0]:
            assert not np.array_equal(mesh.fills, previous.fills)      # each step changed the picture
        previous = mesh
    assert triangle_area(mesh.fills, BLUE) > 0
    bigger = Style(centre_scale=0.5)                   # same poses, another style: the centres change
    assert np.array_equal(builder.build(bodies, projection, 3.0, bigger).centres,
                          MeshBuilder().build(bodies, projection, 3.0, bigger).centres)

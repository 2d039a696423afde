"""A vertex list is one convex shape: points its hull would drop (a dent, an inner point, a point on
an edge) are refused with their index, never silently replaced by the hull."""
import numpy as np
import pytest
import yaml

from touch4d.cli import main
from touch4d.geometry.polytope import Polytope, not_corners

CORNERS = [[x, y, z, w] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5) for w in (-.5, .5)]


def dented() -> list:
    """The tesseract with its last corner (+,+,+,+) pushed in towards the centre: concave."""
    return [*CORNERS[:15], [0.2, 0.2, 0.2, 0.2]]


def test_not_corners_names_inner_and_boundary_points():
    points = np.array([*CORNERS, [0.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.0], [0.5, 0.5, 0.5, 0.5]])
    poly = Polytope.from_vertices(points)
    assert poly.counts[0] == 16
    # The centre is inside; the middle of an edge is on the boundary; a repeated corner is a corner.
    assert not_corners(points, poly) == [(16, "inside the hull"), (17, "on the hull's boundary but not a corner")]
    assert not_corners(np.array(CORNERS), Polytope.from_vertices(CORNERS)) == []


def scene_file(tmp_path, shape):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"objects": [{"name": "x", "shape": shape, "position": [0, 0, 0, 1.5]}]}))
    return path


def test_scene_check_refuses_a_dented_tesseract_naming_the_corner_and_parts(tmp_path, capsys):
    path = scene_file(tmp_path, {"vertices": dented()})
    assert main(["scene", "check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "objects[0].shape.vertices" in err and "[15] [0.2, 0.2, 0.2, 0.2] lies inside the hull" in err
    assert "1 of 16 points" in err and "parts:" in err and "Traceback" not in err


def test_a_point_on_an_edge_is_refused_too(tmp_path, capsys):
    path = scene_file(tmp_path, {"vertices": [*CORNERS, [0.5, 0.5, 0.5, 0.0]]})
    assert main(["scene", "check", str(path)]) == 2
    assert "[16] [0.5, 0.5, 0.5, 0.0] lies on the hull's boundary" in capsys.readouterr().err


def test_the_dented_shape_as_convex_parts_is_accepted(tmp_path, capsys):
    # The same concave solid, cut along w = 0: the w < 0 half is a box; the w > 0 half is convex
    # without the pushed-in corner's octant... keep it simple: two boxes side by side.
    low = [[x, y, z, w] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5) for w in (-.5, 0)]
    high = [[x, y, z, w] for x in (-.5, 0) for y in (-.5, .5) for z in (-.5, .5) for w in (0, .5)]
    path = scene_file(tmp_path, {"parts": [{"vertices": low}, {"vertices": high}]})
    assert main(["scene", "check", str(path)]) == 0
    assert "ok" in capsys.readouterr().out.splitlines()[-1]

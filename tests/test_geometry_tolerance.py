"""The shared tolerance and the one segment clipper: closed-form intervals, and a segment lying on a
boundary kept or dropped by the sign of the tolerance, as rounding leaves it a hair outside."""
import numpy as np
import pytest

from touch4d.geometry import tolerance
from touch4d.geometry.polytope import Polytope
from touch4d.geometry.segment import clip_segment

BOX = Polytope.from_vertices(np.array(np.meshgrid(*[[-1.0, 1.0]] * 4)).reshape(4, -1).T)   # [-1, 1]^4


def test_tolerance_scales_with_size():
    points = 3.0 * BOX.vertices + 100.0
    assert tolerance.size(points) == pytest.approx(6.0)                 # half-diagonal of a side-6 box
    assert tolerance.of(tolerance.size(points)) == pytest.approx(6.0 * tolerance.RELATIVE)
    assert tolerance.extent(np.zeros(3)) == 1.0 and tolerance.extent([-7.0, 2.0], [3.0]) == 7.0


def test_clip_segment_closed_form():
    # x runs from -3 to 3 along the segment: inside [-1, 1] for t in [1/3, 2/3]
    t0, t1 = clip_segment(np.array([-3.0, 0.2, 0, 0]), np.array([3.0, 0.2, 0, 0]), BOX.normals, BOX.offsets, 0.0)
    assert (t0, t1) == pytest.approx((1 / 3, 2 / 3), abs=1e-15)
    t0, t1 = clip_segment(np.array([2.0, 0, 0, 0]), np.array([3.0, 0, 0, 0]), BOX.normals, BOX.offsets, 0.0)
    assert t0 > t1                                                      # wholly outside
    # in 3D too (the clip units of visibility)
    n3 = np.vstack([np.eye(3), -np.eye(3)])
    t0, t1 = clip_segment(np.array([0.0, -2, 0]), np.array([0.0, 2, 0]), n3, np.ones(6), 0.0)
    assert (t0, t1) == pytest.approx((0.25, 0.75))


def test_a_segment_on_a_boundary_is_kept_within_the_tolerance():
    # an edge lying on the cell x = 1, rounding putting it 1e-16 outside (as a hull rebuilt from its own
    # half-spaces does): kept with the shared tolerance, lost without one, outside with it negative
    above = np.nextafter(1.0, 2.0)
    p0, p1 = np.array([above, -0.5, 0, 0]), np.array([above, 0.5, 0, 0])
    tol = tolerance.of(tolerance.size(BOX.vertices))
    t0, t1 = clip_segment(p0, p1, BOX.normals, BOX.offsets, tol)
    assert (t0, t1) == (0.0, 1.0)
    t0, t1 = clip_segment(p0, p1, BOX.normals, BOX.offsets, 0.0)
    assert t0 > t1
    t0, t1 = clip_segment(p0 - [above - 1, 0, 0, 0], p1 - [above - 1, 0, 0, 0], BOX.normals, BOX.offsets, -tol)
    assert t0 > t1


def test_cell_planes_are_qhulls_and_exact_for_a_turned_box():
    # a box turned by a plane rotation: its cell normals are the turned axes (closed form)
    c, s = np.cos(0.3), np.sin(0.3)
    r = np.eye(4)
    r[0, 0], r[0, 3], r[3, 0], r[3, 3] = c, -s, s, c
    poly = Polytope.from_vertices(BOX.vertices @ r.T)
    axes = np.vstack([r.T, -r.T])                                       # +-columns of r
    match = np.abs(poly.normals @ axes.T - 1).min(axis=1)
    assert match.max() < 1e-15 and np.allclose(poly.offsets, 1.0, atol=1e-15)

"""The clip-unit build in batches of bounded memory: a 120-cell beside an object of many small parts
once took 4.5 GB (every part padded to the 120-cell's clip units and vertices, in one batch)."""
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.shapes import get_shape
from touch4d.render.clip import Body, MeshBuilder, arrays
from touch4d.render.clip.arrays import batches


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5000), max_size=300), st.integers(1, 20000))
def test_batches_cover_every_item_once_within_the_limit(cost, limit):
    cost = np.asarray(cost, np.int64)
    parts = batches(cost, limit)
    assert sorted(np.concatenate(parts).tolist() if parts else []) == list(range(len(cost)))
    for rows in parts:
        assert len(rows) <= 1 or len(rows) * max(int(cost[rows].max()), 1) <= limit


def mixed_bodies():
    cell = get_shape("120-cell").parts[0]
    bodies = [Body(cell, rotation_from_list([["xw", 10], ["yw", 5]]), np.array([-0.5, 0, 0, 1.5]), 1.0,
                   np.array([0.9, 0.35, 0.6, 1.0]), 0)]
    return bodies + [Body(p, np.eye(4), np.array([0.5, 0, 0, 1.5]), 1.0, np.array([0.3, 0.65, 1.0, 1.0]), 1)
                     for p in get_shape("hollow-front").parts]


def area_by_colour(vertices):
    """Total screen area (x, y) of the triangles of each colour."""
    tri = vertices.reshape(-1, 3, vertices.shape[1]).astype(np.float64)
    (ux, uy), (vx, vy) = (tri[:, 1, :2] - tri[:, 0, :2]).T, (tri[:, 2, :2] - tri[:, 0, :2]).T
    a = 0.5 * np.abs(ux * vy - uy * vx)
    keys = [tuple(np.round(c, 3)) for c in tri[:, 0, 3:]]
    return {k: float(a[[key == k for key in keys]].sum()) for k in set(keys)}


def test_a_120_cell_beside_many_small_parts_builds_in_bounded_memory_and_batches_change_nothing(monkeypatch):
    bodies = mixed_bodies()
    tracemalloc.start()
    try:
        mesh = MeshBuilder().build(bodies)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 600e6, f"peak {peak / 1e6:.0f} MB"
    monkeypatch.setattr(arrays, "BATCH_FLOATS", 200000)         # many small batches: the same picture
    small = MeshBuilder().build(bodies)
    assert small.counts == mesh.counts
    for got, want in ((small.fills, mesh.fills), (small.centres, mesh.centres)):
        a, b = area_by_colour(got), area_by_colour(want)
        assert a.keys() == b.keys() and all(a[k] == pytest.approx(b[k], rel=1e-9) for k in a)

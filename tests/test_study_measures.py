"""A trial's exploration columns (touch4d.study.measures) against their definition written out as a
plain loop here: sample-and-hold motors over [onset, end] and the hand's steps between tracked poses,
for samples added one by one (a study node) or in batches (a served page), in any order."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.study.measures import TrialMeasures

THRESHOLD = 0.1


def by_definition(motors, poses, onset, end):
    """motors: (stamp, intensities); poses: (stamp, position or None)."""
    touching = integral = 0.0
    samples = sorted(motors, key=lambda s: s[0])
    for k, (t, v) in enumerate(samples):
        t_next = samples[k + 1][0] if k + 1 < len(samples) else end
        a, b = max(t, onset), min(t_next, end)
        if b > a:
            touching += (b - a) * any(x > THRESHOLD for x in v)
            integral += (b - a) * (sum(v) / len(v))
    path, previous = 0.0, None
    for t, position in sorted(poses, key=lambda s: s[0]):
        if t > end:
            break
        if t < onset:
            previous = position
            continue
        if position is not None and previous is not None:
            path += math.dist(position, previous)
        previous = position
    return touching, integral / (end - onset), path


stamp = st.floats(0, 10, allow_nan=False)
motor = st.tuples(stamp, st.lists(st.floats(0, 1), min_size=3, max_size=3))
pose = st.tuples(stamp, st.one_of(st.none(), st.tuples(*[st.floats(-1, 1)] * 3)))


@settings(max_examples=300, deadline=None)
@given(st.lists(motor, max_size=30), st.lists(pose, max_size=30), st.floats(0, 5), st.floats(0.1, 5),
       st.integers(1, 4))
def test_the_columns_equal_their_definition_one_by_one_or_in_batches(motors, poses, onset, span, batches):
    end = onset + span
    want = by_definition(motors, poses, onset, end)
    one = TrialMeasures(threshold=THRESHOLD)
    for t, v in motors:
        one.add_motors(t, np.array(v))
    for t, p in poses:
        one.add_pose(t, np.zeros(3) if p is None else np.array(p), p is not None)
    many = TrialMeasures(threshold=THRESHOLD)
    for part in np.array_split(np.arange(len(motors)), batches):
        if len(part):
            many.add_motor_rows(np.array([motors[k][0] for k in part]), np.array([motors[k][1] for k in part]))
    for part in np.array_split(np.arange(len(poses)), batches):
        if len(part):
            many.add_poses(np.array([poses[k][0] for k in part]),
                           np.array([poses[k][1] or (0.0, 0.0, 0.0) for k in part]),
                           np.array([poses[k][1] is not None for k in part]))
    for got in (one.measure(onset, end), many.measure(onset, end)):
        assert (got.time_touching_s, got.mean_intensity, got.path_length) == pytest.approx(want, abs=1e-9)


def test_reset_keeps_the_latest_sample_which_holds_into_the_next_window():
    m = TrialMeasures(threshold=THRESHOLD)
    m.add_motor_rows(np.array([0.0, 1.0]), np.array([[0.0], [0.8]]))   # felt from t = 1 on
    m.add_poses(np.array([0.0, 1.0]), np.array([[5.0, 0, 0], [1.0, 0, 0]]), np.array([True, True]))
    m.reset()
    m.add_pose(2.5, np.array([1.0, 0.5, 0.0]), True)
    got = m.measure(2.0, 3.0)
    assert got.time_touching_s == pytest.approx(1.0) and got.mean_intensity == pytest.approx(0.8)
    assert got.path_length == pytest.approx(0.5)        # from where it was at the onset (x = 1), not from x = 5

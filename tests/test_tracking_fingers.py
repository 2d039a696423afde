"""Finger motions (touch4d.tracking.fingers) and the scripted tracker publishing the bent hand's joints."""
import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, running_broker
from touch4d.errors import ConfigError
from touch4d.messages import HandJoints, HandPose
from touch4d.nodes.scripted_tracker import ScriptedTracker
from touch4d.tactile.glove import load_glove
from touch4d.tactile.skeleton import JOINTS
from touch4d.tracking.fingers import SHAPES, load_motion, load_motions


def test_the_shipped_motions_ease_between_their_keyframes():
    curl = load_motions()["curl"]
    assert curl.duration == 4.0
    assert curl.sample(0.0).of("index") == 0.0 and curl.sample(1.5).of("index") == 1.0
    # halfway between flat (0) and fist (1) in time: smoothstep(0.5) = 0.5
    assert curl.sample(0.75).of("middle") == pytest.approx(0.5)
    assert curl.sample(0.75).of("thumb") == pytest.approx(0.4)            # the fist's thumb is 0.8
    # a quarter of the way: smoothstep(0.25) = 0.15625
    assert curl.sample(0.375).of("ring") == pytest.approx(0.15625)
    assert curl.looped(4.0 + 1.5).of("little") == pytest.approx(1.0)
    assert load_motion("point").sample(7.0) == SHAPES["point"]            # a shape name holds still
    wave = load_motions()["wave"]
    assert wave.sample(1.0).of("index") == 1.0 and wave.sample(1.0).of("middle") == 0.0


@pytest.mark.parametrize("text, key", [
    ("motions: {a: {keyframes: [{t: 0, shape: fst}]}}", "motions.a.keyframes[0].shape"),
    ("motions: {a: {keyframes: [{t: 0, curl: {pinky: 1}}]}}", "motions.a.keyframes[0].curl.pinky"),
    ("motions: {a: {keyframes: [{t: 0}, {t: 0}]}}", "motions.a.keyframes[1].t"),
    ("motions: {a: {keyframes: [{t: 0, spread: 2}]}}", "motions.a.keyframes[0].spread"),
    ("motions: {a: {keyframs: []}}", "motions.a.keyframs"),
])
def test_mistakes_in_a_fingers_file_are_named(tmp_path, text, key):
    path = tmp_path / "f.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_motions(path)
    assert info.value.key == key


def test_an_unknown_motion_lists_what_exists():
    with pytest.raises(ConfigError, match="curl.*did you mean 'curl'"):
        load_motion("crul")


@pytest.mark.timeout(60)
def test_the_scripted_tracker_publishes_the_bent_hands_joints_before_its_pose():
    glove = load_glove()
    with running_broker() as bus:
        # the curl motion 1.5 s in: a fist; 10x slower fingers, so it stays a fist for the test
        tracker = ScriptedTracker(bus=bus, params={"fingers": "curl", "path": "orbit", "start_s": 0.15,
                                                   "finger_speed": 10.0, "rate": 200.0, "loop": False},
                                  heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            order = []
            probe.create_raw_subscription("hand/", lambda topic, payload: order.append(topic))
            joints = collect(probe, "hand/joints", HandJoints)
            poses = collect(probe, "hand/pose", HandPose)
            deadline = time.monotonic() + 10
            while len(poses) < 3 and time.monotonic() < deadline:
                tracker.spin_once(0.001)
                probe.spin_once(0.001)
            assert order[:4] == ["hand/joints", "hand/pose"] * 2
            j, p = joints[0], poses[0]
            assert j.valid and j.stamp == p.stamp and j.names == list(JOINTS)
            # the wrist is where the rigid hand's wrist is; the index tip folded back under the palm
            expected = glove.skeleton.joint_set(p.position, p.orientation, glove.units_per_metre)
            np.testing.assert_allclose(j.positions[0], expected.positions[0], atol=1e-9)
            tip, knuckle = JOINTS.index("index-finger-tip"), JOINTS.index("index-finger-phalanx-proximal")
            flat_reach = np.linalg.norm(expected.positions[tip] - expected.positions[knuckle])
            assert np.linalg.norm(j.positions[tip] - j.positions[knuckle]) < 0.6 * flat_reach
        finally:
            probe.shutdown()
            tracker.shutdown()

"""The tactile node follows the fingers: hand/joints drives while fresh and valid, hand/pose (the
rigid hand) takes over when the joints go stale or are lost, without a pause in tactile/motors."""
import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, running_broker
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.messages import HandJoints, HandPose, MotorCommand
from touch4d.nodes.tactile import TactileNode
from touch4d.tactile.engine import HandSource, TactileEngine
from touch4d.tactile.glove import load_glove
from touch4d.hands import HandShape

WHERE = np.array([0.0, -0.1, 0.0])
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def glove():
    return load_glove()


def box_scene():
    """A box z in [-0.06, 0.94]: the straight hand at WHERE is inside, a curled index leaves it."""
    obj = SceneObject(name="box", shape="tesseract", size=1.0, position=np.array([0.0, 0.0, 0.44, 2.0]),
                      orientation=np.eye(4), color=np.ones(4))
    return Scene(objects=[obj], projection="orthographic").to_message()


def pose(stamp, valid=True):
    return HandPose(position=WHERE.copy(), orientation=IDENTITY.copy(), valid=valid, stamp=stamp, source_stamp=stamp)


def curled(glove, stamp):
    shape = HandShape(curl={"index": 1.0})
    return glove.skeleton.joint_set(WHERE, IDENTITY, glove.units_per_metre, shape).message(stamp)


def index_on(glove, motors: MotorCommand) -> bool:
    return bool(np.any([v > 0 for n, v in zip(glove.motor_names, motors.intensity) if n.startswith("index-")]))


def test_the_source_follows_the_joints_and_falls_back_to_the_pose(glove):
    engine = TactileEngine(glove)
    engine.set_scene(box_scene())
    src = HandSource(engine, timeout_s=0.05)
    out = []
    # 100 Hz: a joint set, then the pose of the same instant (a tracker's order)
    for k in range(10):
        t = 100.0 + 0.01 * k
        out.append((t, src.on_joints(curled(glove, t))[0]))
        assert src.on_pose(pose(t)) is None          # superseded: computed once, from the joints
    assert src.using == "joints" and all(not index_on(glove, m) for _, (f, m) in out)
    # the joints stop: poses within the timeout are still superseded, the first one after drives
    made = [(t, src.on_pose(pose(t))) for t in 100.09 + 0.01 * np.arange(1, 10)]
    driven = [t for t, o in made if o is not None]
    assert driven[0] == pytest.approx(100.09 + 0.06) and src.using == "pose"
    assert all(index_on(glove, o[1]) for _, o in made if o is not None)   # the rigid, straight hand
    # joints again, then lost: the latest pose at once
    out, err = src.on_joints(curled(glove, 100.2))
    assert err is None and not index_on(glove, out[1]) and src.using == "joints"
    lost = HandJoints(handedness="left", names=[], positions=np.zeros((0, 3)), orientations=np.zeros((0, 4)),
                      radii=np.zeros(0), valid=False, stamp=100.21)
    out, err = src.on_joints(lost)
    assert err is None and index_on(glove, out[1]) and out[1].source_stamp == pytest.approx(100.18)
    assert src.using == "pose" and src.counts["switches"] == 4 and src.counts["joints_lost"] == 1
    # unusable joints: the error comes back, and the pose drives at once
    src.on_joints(curled(glove, 100.3))
    assert src.on_pose(pose(100.3)) is None
    bad = curled(glove, 100.31)
    bad.orientations[3] *= 2.0
    out, err = src.on_joints(bad)
    assert "thumb-phalanx-distal" in str(err) and index_on(glove, out[1]) and src.counts["bad_joints"] == 1
    # joints lost long after the last pose (a tracker of joints alone): nothing stale is sent
    src.on_joints(curled(glove, 101.0))
    out, err = src.on_joints(HandJoints(handedness="left", names=[], positions=np.zeros((0, 3)),
                                        orientations=np.zeros((0, 4)), radii=np.zeros(0), valid=False, stamp=101.01))
    assert out is None and err is None and src.using == "pose"


@pytest.mark.timeout(60)
def test_the_node_switches_to_the_rigid_hand_without_a_gap_in_the_motor_commands(glove):
    with running_broker() as bus:
        tactile = TactileNode(bus=bus, params={"joints_timeout_s": 0.05}, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            motors = collect(probe, "tactile/motors", MotorCommand)
            joints_pub = probe.create_publisher("hand/joints", HandJoints)
            pose_pub = probe.create_publisher("hand/pose", HandPose)
            tactile.engine.set_scene(box_scene())       # (the scene node's part is tested elsewhere)
            period, t0 = 0.01, time.monotonic()
            k = 0
            sent = []                                   # each pose's stamp as published

            def tick(with_joints):
                nonlocal k
                now = time.time()
                sent.append(now)
                if with_joints:
                    joints_pub.publish(curled(glove, now))
                pose_pub.publish(pose(now))
                k += 1
                deadline = t0 + k * period
                while time.monotonic() < deadline:
                    tactile.spin_once(0.001)
                    probe.spin_once(0)

            deadline = time.monotonic() + 20
            while len(motors) < 10 and time.monotonic() < deadline:   # until the subscriptions are connected
                tick(True)
            for _ in range(10):
                tick(True)
            assert tactile.hand.using == "joints" and not index_on(glove, motors[-1])
            switch, first_pose = len(motors), len(sent)
            for _ in range(30):
                tick(False)                               # the joints stop, the poses go on
            deadline = time.monotonic() + 20              # ... until the node has switched
            while not (tactile.hand.using == "pose" and len(motors) > switch + 5):
                assert time.monotonic() < deadline, "the node never switched to the rigid hand"
                tick(False)
            assert index_on(glove, motors[-1])            # the straight, rigid hand
            # the commands' own stamps (their poses' and joint sets'): across the switch they pause for
            # the timeout plus a pose period or two, below the motor node's watchdog (0.1 s); a loaded
            # machine that published the poses further apart stretches that by its own gaps
            stamps = np.array([m.source_stamp for m in motors[switch - 3:]])
            step = max(period, float(np.diff(sent[first_pose - 1:]).max()))
            assert np.diff(stamps).max() < 0.05 + 3 * step + 0.01, (np.diff(stamps).max(), step)
            stats = tactile.stats_flat()
            assert stats["hand_joints"] == 0 and stats["switches"] == 2 and stats["joints"] >= 5
            assert stats["poses_superseded"] >= 5
        finally:
            probe.shutdown()
            tactile.shutdown()

"""The tactile engine (no bus) and the tactile node on a bus: messages, stamps, scene changes, bad input."""
import time

import numpy as np
import pytest
import zmq

import tilted_tesseract
from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.errors import ConfigError
from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.messages import HandPose, MotorCommand, SceneState, TactileField, encode
from touch4d.nodes.tactile import TactileNode
from touch4d.tactile.engine import TactileEngine
from touch4d.tactile.glove import load_glove

HAND = np.array([-0.14, -0.18, 0.0])
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def glove():
    return load_glove()


def scene_msg(rotation=(), revision=1, color=(0.3, 0.6, 1.0, 1.0), projection="orthographic", size=1.2):
    obj = SceneObject(name="cube", shape="tesseract", size=size, position=np.array([0, 0, 0, 1.6]),
                      orientation=rotation_from_list(rotation), color=np.array(color))
    return Scene(objects=[obj], projection=projection, revision=revision).to_message()


def pose(position=HAND, orientation=IDENTITY, valid=True, stamp=1000.0):
    return HandPose(position=np.array(position, float), orientation=np.array(orientation, float), valid=valid,
                    stamp=stamp, source_stamp=stamp)


# ---- the engine -----------------------------------------------------------------------------------


def test_engine_messages_carry_the_stimulus_and_the_pose_stamp(glove):
    engine = TactileEngine(glove)
    engine.set_scene(scene_msg([["xw", -20]]))
    field, motors = engine.messages(pose(stamp=1234.5))
    positions, l, s, h, v = tilted_tesseract.stimulus(glove.samples, HAND, 3.0, 0.5, 1.0, glove.motor_sample)
    np.testing.assert_allclose(field.positions, positions, atol=1e-12)
    np.testing.assert_allclose(field.l, l, atol=1e-9)
    np.testing.assert_allclose(field.h, h, atol=1e-9)
    np.testing.assert_allclose(motors.intensity, v, atol=1e-9)
    assert np.ptp(v) > 0.1                 # a gradient across the hand, not a constant
    assert motors.names == glove.motor_names
    assert field.source_stamp == motors.source_stamp == 1234.5
    assert (field.alpha, field.beta, field.gamma) == (3.0, 0.5, 1.0)
    field.validate()
    motors.validate()


def test_engine_rebuilds_only_when_what_can_be_touched_changes(glove):
    engine = TactileEngine(glove)
    assert engine.set_scene(scene_msg(revision=1))
    assert not engine.set_scene(scene_msg(revision=2, color=(1, 0, 0, 1)))   # colour or selection only
    assert not engine.set_scene(scene_msg(revision=2))                       # the steady re-publish
    assert engine.set_scene(scene_msg([["xw", 10]], revision=3))
    assert engine.set_scene(scene_msg([["xw", 10]], revision=4, projection="perspective"))
    assert engine.builds == 3


def test_engine_projection_override(glove):
    forced = TactileEngine(glove, projection="orthographic")
    forced.set_scene(scene_msg(projection="perspective"))
    np.testing.assert_allclose(forced.stimulus(pose()).h, 0.5)   # flat front, rays along +w
    follows = TactileEngine(glove)
    follows.set_scene(scene_msg(projection="perspective"))
    assert np.ptp(follows.stimulus(pose()).h) > 0.01             # perspective: nearer at the centre


def test_engine_keeps_the_last_good_scene_when_one_fails(glove):
    engine = TactileEngine(glove)
    engine.set_scene(scene_msg())
    bad = scene_msg(revision=2)
    bad.objects[0]["shape"] = "no-such-shape"
    with pytest.raises(ValueError):
        engine.set_scene(bad)
    np.testing.assert_allclose(engine.stimulus(pose()).h, 0.5)


def test_engine_feels_nothing_without_a_scene_or_a_tracked_hand(glove):
    engine = TactileEngine(glove)
    field, motors = engine.messages(pose())
    assert (motors.intensity == 0).all() and np.isnan(field.l).all()
    engine.set_scene(scene_msg())
    field, motors = engine.messages(pose(valid=False))
    assert (motors.intensity == 0).all() and (field.h == 0).all()
    lost = HandPose(position=np.zeros(3), orientation=np.zeros(4), valid=False, stamp=5.0)
    field, motors = engine.messages(lost)
    assert field is None and (motors.intensity == 0).all() and motors.source_stamp == 5.0


def test_engine_alpha_beta_overrides_are_checked(glove):
    engine = TactileEngine(glove, alpha=1.0, beta=0.0)
    engine.set_scene(scene_msg())
    field, _ = engine.messages(pose())
    assert (field.alpha, field.beta) == (1.0, 0.0)
    np.testing.assert_allclose(field.h, 1.0)
    with pytest.raises(ConfigError, match="beta"):
        TactileEngine(glove, beta=2.0)


# ---- the node, in this process on a test broker ---------------------------------------------------


def spin_until(nodes, predicate, timeout=20.0):
    def step():
        for n in nodes:
            n.spin_once(0.01)
        return predicate()
    return wait_until(step, timeout=timeout, interval=0.0)


@pytest.mark.timeout(60)
def test_node_publishes_field_and_motors_for_every_pose_and_survives_bad_input(glove):
    with running_broker() as bus:
        tactile = TactileNode(bus=bus, params={"alpha": 2.0}, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        raw = zmq.Context.instance().socket(zmq.PUB)
        raw.linger = 0
        try:
            fields = collect(probe, "tactile/field", TactileField)
            motors = collect(probe, "tactile/motors", MotorCommand)
            scene_pub = probe.create_publisher("scene/state", SceneState)
            pose_pub = probe.create_publisher("hand/pose", HandPose)
            nodes = (tactile, probe)

            scene_pub.publish(scene_msg())
            spin_until(nodes, lambda: tactile.engine.caster is not None)
            for k in range(3):
                pose_pub.publish(pose(stamp=2000.0 + k))
                spin_until(nodes, lambda: len(motors) == k + 1 and len(fields) == k + 1)
            assert [m.source_stamp for m in motors] == [2000.0, 2001.0, 2002.0]
            assert [f.source_stamp for f in fields] == [2000.0, 2001.0, 2002.0]
            np.testing.assert_allclose(motors[-1].intensity, 0.5)
            assert fields[-1].alpha == 2.0 and fields[-1].positions.shape == (len(glove.samples), 3)

            # Garbage on both topics and a scene that cannot be built: logged, counted, ignored.
            raw.connect(bus.pub_endpoint)
            bad = scene_msg(revision=7)
            bad.objects[0]["shape"] = "no-such-shape"
            def junk():
                raw.send_multipart([b"hand/pose", b"\x93garbage"])
                raw.send_multipart([b"scene/state", b"junk"])
                for n in nodes:
                    n.spin_once(0.02)
                return tactile.stats["hand/pose"]["malformed"] and tactile.stats["scene/state"]["malformed"]

            def unbuildable():
                scene_pub.publish(bad)
                for n in nodes:
                    n.spin_once(0.02)
                return tactile.counts["bad_scenes"]

            wait_until(junk, timeout=20, interval=0.05)
            wait_until(unbuildable, timeout=20, interval=0.05)

            # A pose that decodes but cannot be used (built in-process, past the codec's checks).
            published = len(motors)
            tactile.on_pose(HandPose(position=np.array([0.0, 0.0, np.nan]), orientation=IDENTITY, valid=True))
            tactile.on_pose(HandPose(position=np.zeros(3), orientation=np.zeros(4), valid=True))
            assert tactile.counts["bad_poses"] == 2
            spin_until(nodes, lambda: True)
            assert len(motors) == published

            # Still serving, with the last good scene: a tilted cell now gives a gradient.
            scene_pub.publish(scene_msg([["xw", -20]], revision=8))
            spin_until(nodes, lambda: tactile.counts["scenes_built"] == 2)
            before = len(motors)
            pose_pub.publish(pose(position=[-0.34, -0.18, 0.0], stamp=3000.0))
            spin_until(nodes, lambda: len(motors) > before)
            assert motors[-1].source_stamp == 3000.0
            assert np.ptp(motors[-1].intensity) > 0.1
        finally:
            raw.close()
            probe.shutdown()
            tactile.shutdown()


def test_a_pose_replaced_while_the_scene_was_built_is_never_computed():
    with running_broker() as bus:
        tactile = TactileNode(bus=bus, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            motors = collect(probe, "tactile/motors", MotorCommand)
            scene_pub = probe.create_publisher("scene/state", SceneState)
            pose_pub = probe.create_publisher("hand/pose", HandPose)
            build = tactile.engine.set_scene

            def slow_build(msg):   # a newer pose arrives while the scene is being built
                rebuilt = build(msg)
                pose_pub.publish(pose(stamp=2001.0))
                assert tactile._sub.poll(10000)
                return rebuilt

            tactile.engine.set_scene = slow_build
            scene_pub.publish(scene_msg())
            pose_pub.publish(pose(stamp=2000.0))
            assert tactile._sub.poll(10000)
            time.sleep(0.3)   # scene and first pose queued together
            spin_until((tactile, probe), lambda: len(motors) >= 1)
            spin_until((tactile, probe), lambda: True)
            assert [m.source_stamp for m in motors] == [2001.0]
            assert tactile.counts["poses"] == 1 and tactile.stats["hand/pose"]["dropped"] == 1
        finally:
            probe.shutdown()
            tactile.shutdown()


def test_node_rejects_bad_parameters_with_their_names():
    with running_broker() as bus:
        for params, key in (({"projection": "fisheye"}, "projection"), ({"beta": 3.0}, "beta"),
                            ({"glove": "/no/such/glove.yaml"}, "glove")):
            with pytest.raises(ConfigError) as info:
                TactileNode(bus=bus, params=params, heartbeat=False)
            assert info.value.key == key
        with pytest.raises(ConfigError) as info:  # from a launch file: named as there
            TactileNode(bus=bus, params={"alpha": "steep"}, params_source="launch/demo.yaml", heartbeat=False)
        assert (info.value.file, info.value.key) == ("launch/demo.yaml", "nodes.tactile.params.alpha")


# ---- the node as its own process --------------------------------------------------------------------


@pytest.mark.timeout(90)
def test_node_process_turns_poses_into_motor_commands():
    with running_broker() as bus:
        with node_process("tactile", bus) as proc:
            probe = Node("probe", bus=bus, heartbeat=False)
            try:
                motors = collect(probe, "tactile/motors", MotorCommand)
                scene_pub = probe.create_publisher("scene/state", SceneState)
                pose_pub = probe.create_publisher("hand/pose", HandPose)
                proc.wait_for_line("samples, 30 motors", timeout=40)
                stamp = time.time()

                def exchange():
                    scene_pub.publish(scene_msg())
                    pose_pub.publish(pose(stamp=stamp))
                    probe.spin_once(0.2)
                    return any(m.source_stamp == stamp and np.allclose(m.intensity, 0.5) for m in motors)

                wait_until(exchange, timeout=40, interval=0.1)
            finally:
                probe.shutdown()

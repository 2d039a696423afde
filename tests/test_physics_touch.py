"""The hand pushes what it feels, and collisions reach the motors as short transients."""
import numpy as np
import pytest

from touch4d.geometry.scene import parse_scene
from touch4d.physics.config import parse_physics
from touch4d.physics.session import PhysicsSession
from touch4d.tactile.glove import load_glove
from touch4d.tactile.stimulus import compute_stimulus
from touch4d.tactile.transient import TAU, TransientBank, envelope, strength, transient_intensity
from touch4d.tracking.calibration import load_calibration

pytestmark = pytest.mark.timeout(600)     # the first test may compile the step (numba; cached afterwards)

Q = [0.0, 0.0, 0.0, 1.0]
SCENE = {"physics": {"gravity": [0, 0, 0, 0]}, "objects": [
    {"name": "cube", "shape": "tesseract", "size": 0.5, "position": [0, 0, 0, 0.8]},
    {"name": "far", "shape": "tesseract", "size": 0.3, "position": [0, 0.7, 0, 1.5]}]}


def pushing_session(rate=40.0):
    glove = load_glove(None)
    return glove, PhysicsSession(parse_scene(SCENE), parse_physics(SCENE), load_calibration(None), glove=glove,
                                 push_rate=rate)


def test_a_hand_moving_into_an_object_pushes_it_where_it_feels_it():
    glove, s = pushing_session()
    speed = 0.5
    for k in range(40):                                     # 0.4 s moving +x at 0.5 units/s, poses every 10 ms
        x = -0.45 + speed * 0.01 * k
        s.on_hand([x, 0, 0], Q)
        s.advance(10)
    cube, far = s.message().objects[0]["position"], s.message().objects[1]["position"]
    assert cube[0] > 0.05                                   # moved along the push
    assert np.abs(cube[1:] - [0, 0, 0.8]).max() < 0.02      # and barely anywhere else
    np.testing.assert_array_equal(far, [0, 0.7, 0, 1.5])    # what the hand does not feel does not move
    assert np.abs(s.state.v[0, 0]) <= speed + 1e-9          # never faster than the hand
    st = compute_stimulus(glove, s.control.scene.ray_caster(), [x, 0, 0], Q)
    felt = set(st.hit[st.h > 0])
    assert felt == {0} and st.V.max() > 0                   # the motors feel the object being pushed
    assert [e.body for e in s.hand_events][:1] == [0]       # the push began as a contact event on the cube


def test_a_still_hand_or_no_push_rate_moves_nothing():
    _, s = pushing_session()
    for _ in range(20):
        s.on_hand([-0.3, 0, 0], Q)                          # touching, not moving
        s.advance(10)
    np.testing.assert_array_equal(s.message().objects[0]["position"], [0, 0, 0, 0.8])
    _, s = pushing_session(rate=0.0)
    for k in range(20):
        s.on_hand([-0.45 + 0.005 * k, 0, 0], Q)
        s.advance(10)
    np.testing.assert_array_equal(s.message().objects[0]["position"], [0, 0, 0, 0.8])


def test_transient_envelope_and_which_motors_get_it():
    assert strength(0.75, 1.5) == 0.5 and strength(9.0) == 1.0 and strength(-1.0) == 0.0
    np.testing.assert_allclose(envelope([0.0, TAU, 2 * TAU, 0.2], 0.8), [0.8, 0.8 / np.e, 0.8 / np.e ** 2, 0.0])
    bank = TransientBank()
    bank.add(a=[0, 0, -1], b=[1, 1, 2], speeds=[0.3, 0.75, 3.0], now=10.0)  # floor-cube twice, the hand on 2
    hits = np.array([-1, 1, 0, 2, 3])
    got = bank.apply(np.array([0.0, 0.2, 0.1, 0.9, 0.5]), hits, now=10.0 + TAU)
    np.testing.assert_allclose(got, [0.0, 0.2 + 0.5 / np.e, 0.1 + 0.5 / np.e, 1.0, 0.5])
    assert bank.apply(np.zeros(5), hits, now=10.2).max() == 0 and not bank.active    # over after 100 ms
    np.testing.assert_allclose(transient_intensity([], 0.0, hits), 0.0)


def test_a_struck_object_reaches_the_motors_touching_it():
    """A cube falls onto a floor under the hand: the physics contact event gives the touching motors a burst."""
    from touch4d.physics.world import from_data, step

    data = {"physics": {"gravity": [0, -9.81, 0, 0]}, "objects": [
        {"name": "floor", "shape": "tesseract", "size": 1.0, "position": [0, -1.0, 0, 1.0], "physics": {"static": True}},
        {"name": "cube", "shape": "tesseract", "size": 0.4, "position": [0, -0.2, 0, 0.8]}]}
    world, state = from_data(data)
    struck = None
    for _ in range(400):
        state, contacts = step(world, state)
        hard = contacts.speed < -0.05
        if hard.any():
            struck = contacts
            break
    assert struck is not None and set(struck.b[hard]) == {1}
    glove = load_glove(None)
    scene = parse_scene(data)
    st = compute_stimulus(glove, scene.ray_caster(), [0.0, 0.0, 0.0], Q)
    hits = st.hit[glove.motor_sample]
    bank = TransientBank()
    bank.add(struck.a[hard], struck.b[hard], -struck.speed[hard], now=0.0)
    got = bank.apply(st.V, hits, now=0.01)
    assert (got[hits >= 0] > st.V[hits >= 0]).all() and np.array_equal(got[hits < 0], st.V[hits < 0])


def test_the_tactile_node_adds_the_burst_of_a_physics_contact_on_the_touching_motors():
    from touch4d.bus import Node
    from touch4d.bus.testing import collect, running_broker, wait_until
    from touch4d.geometry.scene import Scene, SceneObject
    from touch4d.messages import HandPose, MotorCommand, PhysicsContacts, SceneState
    from touch4d.nodes.tactile import TactileNode

    cube = SceneObject(name="cube", shape="tesseract", size=0.6, position=np.array([0.6, 0, 0, 1.6]))
    scene = Scene(objects=[cube], revision=1).to_message()
    hand = HandPose(position=np.array([0.25, 0.0, 0.0]), orientation=np.array(Q), valid=True)
    with running_broker() as bus:
        tactile = TactileNode(bus=bus, heartbeat=False)
        tactile.transients = TransientBank(tau=10.0, duration=60.0)        # a long burst: no race with the clock
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            motors = collect(probe, "tactile/motors", MotorCommand)
            probe.create_publisher("scene/state", SceneState).publish(scene)
            poses = probe.create_publisher("hand/pose", HandPose)
            contacts = probe.create_publisher("physics/contacts", PhysicsContacts)

            def spin(predicate):
                wait_until(lambda: (tactile.spin_once(0.01), probe.spin_once(0.01), predicate())[-1], timeout=30)

            spin(lambda: tactile.engine.caster is not None)
            poses.publish(hand)
            spin(lambda: len(motors) == 1)
            contacts.publish(PhysicsContacts(names=["cube"], a=np.array([-1]), b=np.array([0]),
                                             points=np.zeros((1, 4)), normals=np.array([[1.0, 0, 0, 0]]),
                                             impulses=np.array([0.1]), speeds=np.array([0.75]), step=1, time=0.001))
            spin(lambda: tactile.transients.active)
            poses.publish(hand)
            spin(lambda: len(motors) == 2)
        finally:
            probe.shutdown()
            tactile.shutdown()
    before, after = motors[0].intensity, motors[1].intensity
    touching = before > 0
    assert touching.any() and not touching.all()                         # the hand half on the cube
    np.testing.assert_allclose(after[touching], np.minimum(before[touching] + 0.5, 1.0), atol=0.01)  # a = 0.75 / 1.5
    np.testing.assert_array_equal(after[~touching], before[~touching])

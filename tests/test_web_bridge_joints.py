"""The WebXR bridge and the articulated hand: the glove hand's joints go out before its pose, the
other hand's apart, a lost hand at once, and pages get the hand with its fingers placed."""
import numpy as np
from scipy.spatial.transform import Rotation

from test_web_bridge import GLOVE, Rig
from touch4d.hands import HandShape
from touch4d.tactile.skeleton import outline_segments
from touch4d.web.protocol import unpack_frame


def room_joints(shape=None, x=0.0):
    """The glove's hand as a page's tracked joints (metres, the room): the screen's centre is at
    (0, 1.2, -0.45) and the screen turned as the calibration says; here simply the glove's own
    joints at 1/4 scale (4 units per metre) placed at the screen's centre."""
    js = GLOVE.skeleton.joint_set([x, 0.0, 0.0], [0, 0, 0, 1], 1.0, shape)
    pos = js.positions + np.array([0.0, 1.2, -0.45])
    return [[*p, *q, r] for p, q, r in zip(pos.tolist(), js.orientations.tolist(), js.radii.tolist())]


def sources(right=True, left=False):
    out = []
    if right:
        out.append({"handedness": "right", "grip": None, "trigger": 0.0, "buttons": [], "joints": room_joints()})
    if left:
        out.append({"handedness": "left", "grip": None, "trigger": 0.0, "buttons": [], "joints": room_joints(x=0.2)})
    return out


def test_the_glove_hands_joints_go_out_first_and_the_other_hand_apart():
    rig = Rig(hand_source="hand")
    rig.bridge.connected(1)
    rig.input(1, sources=sources(right=True, left=True))
    topics = [t for t, _ in rig.published]
    assert topics.index("hand/joints") < topics.index("hand/pose")
    (glove_hand,) = rig.topic("hand/joints")
    (other,) = rig.topic("hand/joints/other")
    assert glove_hand.handedness == "right" and other.handedness == "left"
    assert glove_hand.stamp == rig.topic("hand/pose")[0].stamp
    # the glove hand stops being tracked: its joints are published invalid at once, once
    rig.input(1, sources=sources(right=False, left=True))
    lost = rig.topic("hand/joints")[1:]
    assert len(lost) == 1 and not lost[0].valid
    rig.input(1, sources=sources(right=False, left=True))
    assert len(rig.topic("hand/joints")) == 2


def test_a_page_that_stops_tracking_loses_the_joints_too():
    rig = Rig(hand_source="hand")
    rig.bridge.connected(1)
    rig.input(1, sources=sources())
    rig.bridge.closed(1)
    assert not rig.topic("hand/joints")[-1].valid and not rig.topic("hand/pose")[-1].valid


def test_pages_get_the_articulated_hand_while_its_joints_drive():
    rig = Rig(tracker=False)
    upm = GLOVE.units_per_metre
    shape = HandShape(curl={"index": 1.0})
    q = Rotation.from_euler("y", 30, degrees=True).as_quat()
    joints = GLOVE.skeleton.joint_set([0.1, -0.2, 0.0], q, upm, shape).message(50.0)
    rig.bridge.on_hand_joints(joints)
    rig.bridge.on_hand_pose(_pose(50.0, q))
    header, arrays = unpack_frame(rig.bridge.frame())
    assert header["hand_source"] == "joints"
    samples = arrays["hand_samples"].reshape(-1, 3)
    placed = GLOVE.skeleton.place("samples", GLOVE.skeleton.transforms(joints.names, joints.positions,
                                                                        joints.orientations, "left", upm))
    np.testing.assert_allclose(samples, placed, atol=1e-6)
    # the outline the page draws from the joints and the setup's pairs is the skeleton's
    setup_header, setup = unpack_frame(rig.bridge.setup_frame())
    pairs = setup["outline_pairs"].reshape(-1, 2)
    j = arrays["hand_joints"].reshape(-1, 3)
    np.testing.assert_allclose(j[pairs], outline_segments(joints.positions), atol=1e-6)
    # a pose much newer than the joints: the rigid glove again
    rig.bridge.on_hand_pose(_pose(50.3, q))
    header, arrays = unpack_frame(rig.bridge.frame())
    assert header["hand_source"] == "pose" and "hand_samples" not in arrays


def _pose(stamp, q):
    from touch4d.messages import HandPose
    return HandPose(position=np.array([0.1, -0.2, 0.0]), orientation=np.asarray(q), valid=True, stamp=stamp)

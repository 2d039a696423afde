"""The keyboard-and-mouse hand, the OpenVR conversions and the tracker messages, without a bus."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.desktop import DesktopConfig, DesktopHand
from touch4d.tracking.outputs import from_controller, from_hand
from touch4d.tracking.paths import PathSample
from touch4d.tracking.vr import buttons_from_mask, pose_from_matrix

DT = 1 / 100


def hand_at_origin(**kwargs):
    return DesktopHand(DesktopConfig(home=(0.0, 0.0, 0.0), **kwargs))


def run(hand, seconds, keys=(), buttons=(), drag=(0.0, 0.0), start=0.0):
    sample = None
    steps = int(round(seconds / DT))
    for k in range(steps):
        now = start + k * DT
        hand.on_input(list(keys), [], np.array(drag) / steps, list(buttons), now)
        sample = hand.step(DT, now)
    return sample


@pytest.mark.parametrize("key, axis, sign", [("d", 0, 1), ("a", 0, -1), ("e", 1, 1), ("q", 1, -1),
                                             ("s", 2, 1), ("w", 2, -1)])
def test_move_keys_move_along_one_axis_at_the_set_speed(key, axis, sign):
    sample = run(hand_at_origin(move_speed=0.5), 1.0, keys=[key])
    expected = np.zeros(3)
    expected[axis] = 0.5 * sign
    assert np.allclose(sample.position, expected)
    assert sample.trigger == 0.0


def test_shift_slows_and_the_hand_stays_within_its_limit():
    assert run(hand_at_origin(move_speed=1.0), 1.0, keys=["d", "left_shift"]).position[0] == pytest.approx(0.25)
    assert run(hand_at_origin(move_speed=1.0), 5.0, keys=["d"]).position[0] == pytest.approx(2.0)


def test_arrows_turn_the_hand_about_the_screen_axes():
    sample = run(hand_at_origin(turn_speed_deg=90.0), 1.0, keys=["left"])
    rot = Rotation.from_quat(sample.orientation)
    assert np.allclose(rot.as_rotvec(), [0, np.pi / 2, 0])


def test_space_and_drags_hold_the_trigger():
    hand = hand_at_origin()
    assert run(hand, 0.1, keys=["space"]).trigger == 1.0
    # a right-button drag of 100 px to the right moves the hand 0.4 units along +x
    sample = run(hand_at_origin(drag_move=0.004), 0.5, buttons=[2], drag=(100.0, 0.0))
    assert sample.trigger == 1.0 and np.allclose(sample.position, [0.4, 0, 0])
    # a left-button drag of 50 px down turns it 0.5 rad about +x
    sample = run(hand_at_origin(drag_turn=0.01), 0.5, buttons=[1], drag=(0.0, 50.0))
    assert sample.trigger == 1.0 and np.allclose(Rotation.from_quat(sample.orientation).as_rotvec(), [0.5, 0, 0])


def test_keys_hold_controller_buttons_and_h_goes_home():
    hand = DesktopHand(DesktopConfig(home=(0.0, 0.0, 1.5)))
    sample = run(hand, 0.5, keys=["n", "a"])
    assert sample.buttons == ("menu",)
    assert sample.position[0] < 0
    hand.on_input([], ["h"], [0, 0], [], 1.0)
    assert np.allclose(hand.step(DT, 1.0).position, [0, 0, 1.5])


def test_stale_input_counts_as_released():
    hand = hand_at_origin(move_speed=1.0, input_timeout=0.5)
    hand.on_input(["d", "space"], [], [0, 0], [], 0.0)
    for k in range(100):               # no more input for a second: the window went away
        sample = hand.step(DT, k * DT)
    assert sample.position[0] == pytest.approx(0.51, abs=0.02) and sample.trigger == 0.0


def test_pose_from_matrix_and_buttons_from_mask():
    rot = Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    m = np.c_[rot.as_matrix(), [0.1, 1.2, -0.3]]
    position, quat = pose_from_matrix(m.tolist())
    assert np.allclose(position, [0.1, 1.2, -0.3])
    assert np.allclose(Rotation.from_quat(quat).as_matrix(), rot.as_matrix()) and quat[3] >= 0
    assert buttons_from_mask((1 << 1) | (1 << 32) | (1 << 5)) == ["menu", "trackpad"]
    assert buttons_from_mask(0) == []


def test_tracker_messages_agree_through_the_calibration():
    cal = load_calibration()
    sample = PathSample(np.array([0.2, -0.1, 0.3]), Rotation.from_euler("z", 40, degrees=True).as_quat(),
                        0.8, ("grip",))
    hand, ctrl = from_hand(sample, cal, stamp=123.0)
    hand.validate()
    ctrl.validate()
    assert hand.source_stamp == ctrl.source_stamp == 123.0 and ctrl.trigger == 0.8 and ctrl.buttons == ["grip"]
    hand2, ctrl2 = from_controller(ctrl.position, ctrl.orientation, 1.3, ["grip"], True, cal, stamp=5.0)
    assert np.allclose(hand2.position, hand.position) and ctrl2.trigger == 1.0
    assert np.allclose(Rotation.from_quat(hand2.orientation).as_matrix(), Rotation.from_quat(hand.orientation).as_matrix())
    lost, lost_ctrl = from_controller([0, 0, 0], [0, 0, 0, 1.0], 0.0, [], False, cal)
    assert not lost.valid and not lost_ctrl.valid

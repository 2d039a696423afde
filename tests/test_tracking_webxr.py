"""WebXR input -> the glove hand and the controller, and the screen placed in front of a headset:
expectations built from the frames' definitions (WebXR's joint and grip axes, the glove's hand
frame), not from the code under test."""
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.errors import ConfigError
from touch4d.tracking.calibration import (Calibration, load_calibration, load_placement, rotation_from_steps,
                                          save_screen_placement)
from touch4d.tracking.webxr import JOINTS, XRSource, controller_state, hand_from_joints, hand_joints, hand_pose

REPO = Path(__file__).resolve().parents[1]
CENTER = np.array([0.0, 1.2, -0.45])


def calibration(hand_steps=(("y", 90),), screen_steps=()):
    return Calibration(CENTER.copy(), rotation_from_steps([list(s) for s in screen_steps]), 0.5, np.zeros(3),
                       rotation_from_steps([list(s) for s in hand_steps]))


def tracked_hand(origin, hand_rotation: Rotation, span=0.09):
    """25 joints of a flat hand whose glove frame (x thumb, y fingers, z back of hand) is `hand_rotation`
    at `origin`: every joint oriented as WebXR says (-z along the fingers, +y out of the back)."""
    r = hand_rotation.as_matrix()
    joint_axes = np.c_[r[:, 0], r[:, 2], -r[:, 1]]        # joint x = glove x, joint y = glove z, joint z = -glove y
    q = Rotation.from_matrix(joint_axes).as_quat()
    joints = np.zeros((25, 8))
    joints[:, 3:7] = q
    joints[:, 7] = 0.01
    fingers = r[:, 1]
    for k, name in enumerate(JOINTS):
        joints[k, :3] = origin + fingers * (0.5 * span if name != "wrist" else -0.5 * span)
    joints[JOINTS.index("middle-finger-phalanx-proximal"), :3] = origin + 0.5 * span * fingers
    return joints


def test_hand_tracking_gives_the_palm_centre_and_the_glove_frame():
    turn = Rotation.from_euler("xyz", [20, -35, 10], degrees=True)
    origin = np.array([0.1, 1.25, -0.4])
    position, quat = hand_from_joints(tracked_hand(origin, turn))
    assert np.allclose(position, origin)
    assert np.allclose(Rotation.from_quat(quat).as_matrix(), turn.as_matrix(), atol=1e-9)


def test_hand_pose_from_tracked_joints_is_in_screen_units():
    origin = CENTER + [0.05, -0.025, 0.1]                       # 4 screen units per metre
    pose = hand_pose(XRSource("right", joints=tracked_hand(origin, Rotation.identity())), "hand", calibration(), 5.0)
    assert pose.valid and pose.source_stamp == 5.0
    assert np.allclose(pose.position, [0.2, -0.1, 0.4])
    assert np.allclose(Rotation.from_quat(pose.orientation).as_matrix(), np.eye(3), atol=1e-9)


def test_controller_grip_carries_the_hand_with_its_back_along_grip_x():
    # WebXR grip space: +x out of the back of a right hand, -z toward the thumb along the grip.
    grip_turn = Rotation.from_euler("y", 40, degrees=True)
    grip = np.r_[CENTER + [0.0, 0.1, 0.0], grip_turn.as_quat()]
    pose = hand_pose(XRSource("right", grip=grip), "controller", calibration(), 1.0)
    assert pose.valid and np.allclose(pose.position, [0.0, 0.4, 0.0])
    hand = Rotation.from_quat(pose.orientation).as_matrix()
    g = grip_turn.as_matrix()
    assert np.allclose(hand[:, 2], g[:, 0])       # back of the hand = grip +x
    assert np.allclose(hand[:, 0], -g[:, 2])      # thumb = grip -z


def test_untracked_or_missing_inputs_give_invalid_poses():
    cal = calibration()
    assert not hand_pose(None, "controller", cal, 1.0).valid
    assert not hand_pose(XRSource("right", grip=None), "controller", cal, 1.0).valid
    assert not hand_pose(XRSource("right", grip=np.r_[CENTER, 0, 0, 0, 1]), "hand", cal, 1.0).valid  # no joints
    state = controller_state(XRSource("right", trigger=1.0, buttons=("a",)), cal, 1.0)
    assert not state.valid and state.trigger == 0.0 and state.buttons == []


def test_controller_state_is_in_the_room_and_a_tracked_hand_uses_its_wrist():
    cal = calibration()
    grip = np.array([0.3, 1.1, -0.2, 0.0, 0.0, 0.0, 1.0])
    state = controller_state(XRSource("right", grip=grip, trigger=0.75, buttons=("b",)), cal, 2.0)
    assert state.valid and state.trigger == 0.75 and state.buttons == ["b"]
    assert np.allclose(state.position, grip[:3])   # room coordinates, metres: unchanged
    joints = tracked_hand(np.array([0.0, 1.3, -0.3]), Rotation.identity())
    state = controller_state(XRSource("left", trigger=1.0, joints=joints), cal, 2.0)
    assert state.valid and np.allclose(state.position, joints[0, :3]) and state.trigger == 1.0


def test_hand_joints_in_screen_coordinates():
    joints = tracked_hand(CENTER, Rotation.identity())
    msg = hand_joints(XRSource("left", joints=joints), calibration(), 3.0)
    msg.validate()
    assert msg.names == list(JOINTS) and msg.handedness == "left"
    assert np.allclose(msg.positions, (joints[:, :3] - CENTER) * 4.0)
    assert np.allclose(msg.radii, 0.04)


def test_screen_placed_in_front_of_a_turned_head():
    # Head at yaw 30 degrees (turned left, about +y), looking 20 degrees down: the screen goes
    # 0.45 m ahead along the horizontal gaze (-sin 30, 0, -cos 30), 0.35 m below the eyes, turned 30 degrees.
    head = Rotation.from_euler("y", 30, degrees=True) * Rotation.from_euler("x", -20, degrees=True)
    placed = calibration().placed_in_front([0.2, 1.6, 0.1], head.as_quat(), 0.45, 0.35)
    assert np.allclose(placed.center_m, [0.2 - 0.45 * 0.5, 1.25, 0.1 - 0.45 * np.sqrt(3) / 2])
    assert np.allclose(placed.screen_rotation.as_matrix(), Rotation.from_euler("y", 30, degrees=True).as_matrix())
    # the hand mapping is unchanged and the screen's centre is at the origin of screen coordinates
    assert np.allclose(placed.room_to_screen(placed.center_m), 0.0)


def test_placement_is_stored_in_the_file_keeping_everything_else(tmp_path):
    path = tmp_path / "calibration.yaml"
    shutil.copy(REPO / "config" / "calibration.yaml", path)
    before = path.read_text()
    head = Rotation.from_euler("y", -90, degrees=True)
    placed = load_calibration(path).placed_in_front([1.0, 1.7, 0.0], head.as_quat(), 0.5, 0.3)
    save_screen_placement(path, placed)
    back = load_calibration(path)
    assert np.allclose(back.center_m, [1.5, 1.4, 0.0], atol=1e-4)
    assert np.allclose(back.screen_rotation.as_matrix(), head.as_matrix(), atol=1e-5)
    assert back.edge_m == 0.5
    after = path.read_text()
    changed = [line for line in after.splitlines() if line not in before.splitlines()]
    assert len(changed) == 2 and all(line.strip().startswith(("center_m:", "rotation_deg:")) for line in changed)
    assert "# in front of a standing user" in after   # the comments stay
    assert load_calibration(path, "hand_in_controller").hand_offset_m.tolist() == [0.0, -0.03, 0.10]


def test_placement_and_hand_in_grip_sections():
    placement = load_placement(REPO / "config" / "calibration.yaml")
    assert placement.distance_m > 0 and placement.below_eye_m >= 0
    grip = load_calibration(REPO / "config" / "calibration.yaml", "hand_in_grip")
    assert np.allclose(grip.hand_rotation.as_matrix() @ [0, 0, 1], [1, 0, 0])


def test_a_file_without_a_screen_block_cannot_store_a_placement(tmp_path):
    path = tmp_path / "calibration.yaml"
    path.write_text("screen: {center_m: [0, 1, 0], edge_m: 0.5}\n")
    with pytest.raises(ConfigError, match="screen.center_m"):
        save_screen_placement(path, load_calibration(path))

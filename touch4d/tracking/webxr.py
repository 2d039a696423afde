"""WebXR input -> touch4d values: controllers' grip poses and buttons, tracked hands' joints.

The WebXR page sends what the headset tracks in its `local-floor` space (metres, +y up, the user
facing -z at the start, as SteamVR's standing space), unchanged; everything that turns it into
the glove hand's pose happens here, through the calibration (room -> screen, one place).

The glove hand's pose comes from one of two sources (`HAND_SOURCES`):
- "controller": the grip space of the controller held in the glove hand, with the calibration's
  `hand_in_grip` offset (as the paper's Vive controller, §3);
- "hand": WebXR hand tracking. The hand frame (origin at the palm centre, +y along the fingers, +z
  out of the back of the hand) is the wrist joint's frame turned -90 degrees about its x axis
  (WebXR joints point -z along the bone and +y out of the back of the hand), its origin halfway
  between the wrist and the middle finger's knuckle (`middle-finger-phalanx-proximal`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from touch4d.hands import WEBXR_JOINTS
from touch4d.messages import ControllerState, HandJoints, HandPose

from touch4d.geometry import quaternion
from .calibration import Calibration

HAND_SOURCES = ("controller", "hand")
HANDS = ("right", "left")

JOINTS = WEBXR_JOINTS    # the 25 joints of the WebXR Hand Input module, in its order
WRIST = JOINTS.index("wrist")
KNUCKLE = JOINTS.index("middle-finger-phalanx-proximal")

# The buttons of the WebXR `xr-standard` gamepad mapping, by index (0, the trigger, is an axis here).
XR_STANDARD_BUTTONS = (None, "squeeze", "touchpad", "thumbstick", "a", "b")
# The thumbstick pushed forward / back past half its travel, held as buttons (the slice view's c).
THUMBSTICK_BUTTONS = ("thumbstick-up", "thumbstick-down")

# Hand frame in the wrist joint's frame: a -90 degree turn about x (q = (-sin 45, 0, 0, cos 45)).
_HAND_IN_WRIST = np.array([-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class XRSource:
    """One tracked input of the page: a controller (grip pose) or a hand (joints), in the room."""

    handedness: str                       # "right", "left" (or "none")
    grip: np.ndarray | None = None        # (7,) position m + quaternion (x, y, z, w), room; None: not tracked
    trigger: float = 0.0                  # 0..1 (a tracked hand's pinch)
    buttons: tuple[str, ...] = ()         # names held, from XR_STANDARD_BUTTONS
    joints: np.ndarray | None = None      # (25, 8): position m, quaternion, radius m, room; None: no hand


def hand_from_joints(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tracked hand joints (25, 8) in the room -> the glove hand's origin (m) and orientation, room."""
    wrist = joints[WRIST]
    origin = 0.5 * (wrist[:3] + joints[KNUCKLE, :3])
    return origin, quaternion.canonical(quaternion.multiply(quaternion.canonical(wrist[3:7]), _HAND_IN_WRIST))


def hand_pose(source: XRSource | None, hand_source: str, calibration: Calibration, stamp: float) -> HandPose:
    """The glove hand in screen coordinates from its controller or its tracked joints; invalid when
    that input is not tracked (the tactile node then treats the hand as absent)."""
    position, quat, valid = np.zeros(3), _IDENTITY, False
    if source is not None:
        if hand_source == "controller" and source.grip is not None:
            position, quat = calibration.hand_from_controller(source.grip[:3], source.grip[3:7])
            valid = True
        elif hand_source == "hand" and source.joints is not None:
            origin, q_room = hand_from_joints(source.joints)
            position, quat = calibration.room_to_screen(origin), calibration.orientation_to_screen(q_room)
            valid = True
    return HandPose(position=position, orientation=quat, valid=valid, stamp=stamp, source_stamp=stamp)


def controller_state(source: XRSource | None, calibration: Calibration, stamp: float) -> ControllerState:
    """The controller (or, for a tracked hand, its wrist and pinch) in the room: what turns the object."""
    position, quat, trigger, buttons, valid = np.zeros(3), _IDENTITY, 0.0, [], False
    if source is not None:
        pose = source.grip if source.grip is not None else (
            source.joints[WRIST, :7] if source.joints is not None else None)
        if pose is not None:
            position, quat, valid = pose[:3].copy(), quaternion.canonical(pose[3:7]), True
        trigger, buttons = min(max(float(source.trigger), 0.0), 1.0), list(source.buttons)
    return ControllerState(position=position, orientation=quat, trigger=trigger if valid else 0.0,
                           buttons=buttons if valid else [], valid=valid, stamp=stamp, source_stamp=stamp)


def hand_joints(source: XRSource, calibration: Calibration, stamp: float) -> HandJoints:
    """A tracked hand's joints in screen coordinates (positions, orientations, radii in screen units)."""
    joints = source.joints
    positions = calibration.room_to_screen(joints[:, :3])
    orientations = np.array([calibration.orientation_to_screen(q) for q in joints[:, 3:7]])
    return HandJoints(handedness=source.handedness, names=list(JOINTS), positions=positions,
                      orientations=orientations, radii=joints[:, 7] * calibration.units_per_metre,
                      valid=True, stamp=stamp, source_stamp=stamp)

"""The two messages every tracker publishes: the hand in screen coordinates, the controller in the room."""
from __future__ import annotations

import time

import numpy as np

from touch4d.messages import ControllerState, HandPose

from .calibration import Calibration
from .paths import PathSample


def from_hand(sample: PathSample, calibration: Calibration, stamp: float | None = None
              ) -> tuple[HandPose, ControllerState]:
    """A hand pose given in screen coordinates (scripted, desktop) and the controller that holds it."""
    stamp = time.time() if stamp is None else stamp
    position_m, quat_room = calibration.controller_from_hand(sample.position, sample.orientation)
    hand = HandPose(position=np.asarray(sample.position, dtype=float), orientation=sample.orientation,
                    valid=sample.valid, stamp=stamp, source_stamp=stamp)
    controller = ControllerState(position=position_m, orientation=quat_room, trigger=float(sample.trigger),
                                 buttons=list(sample.buttons), valid=sample.valid, stamp=stamp, source_stamp=stamp)
    return hand, controller


def from_controller(position_m, quat_room, trigger: float, buttons, valid: bool, calibration: Calibration,
                    stamp: float | None = None) -> tuple[HandPose, ControllerState]:
    """A tracked controller in the room (OpenVR) and the hand it places on the screen."""
    stamp = time.time() if stamp is None else stamp
    position_m = np.asarray(position_m, dtype=float)
    quat_room = np.asarray(quat_room, dtype=float)
    if valid:
        position, quat = calibration.hand_from_controller(position_m, quat_room)
    else:
        position, quat = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    hand = HandPose(position=position, orientation=quat, valid=bool(valid), stamp=stamp, source_stamp=stamp)
    controller = ControllerState(position=position_m, orientation=quat_room,
                                 trigger=float(min(max(trigger, 0.0), 1.0)), buttons=list(buttons),
                                 valid=bool(valid), stamp=stamp, source_stamp=stamp)
    return hand, controller

"""OpenVR tracker: a real SteamVR controller (HTC Vive, Index...) through the `openvr` package.

Publishes the controller's pose, trigger and buttons on `controller/state` (room = SteamVR's
standing space) and the glove hand it holds on `hand/pose` (screen coordinates, through the
calibration) at `rate` Hz. Without the package or without a running SteamVR it exits at once
with code 1 and says what is missing.
"""
from __future__ import annotations

import logging

from touch4d.bus import Node, Param
from touch4d.errors import Unavailable
from touch4d.messages import ControllerState, HandPose
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import MAX_TRACKER_RATE
from touch4d.tracking.outputs import from_controller
from touch4d.tracking.vr import MISSING_PACKAGE, NO_STEAMVR, buttons_from_mask, pose_from_matrix

TRIGGER_AXIS = 1  # rAxis[1].x is the trigger on Vive and Index controllers


class OpenVRTracker(Node):
    """A SteamVR controller held in the gloved hand."""

    default_name = "tracker"
    PARAMS = {
        "rate": Param(90.0, "poses per second", unit="Hz", above=0, max=MAX_TRACKER_RATE),
        "hand": Param("right", "the hand that holds the controller", choices=("right", "left")),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration", path="calibration file"),
    }

    def setup(self) -> None:
        self.openvr, self.system = connect()
        self.add_cleanup(self.openvr.shutdown)
        self.rate, hand = self.params["rate"], self.params["hand"]
        vr = self.openvr
        self.role = vr.TrackedControllerRole_RightHand if hand == "right" else vr.TrackedControllerRole_LeftHand
        self.calibration = load_calibration(self.params["calibration"])
        self.hand_pub = self.create_publisher("hand/pose", HandPose)
        self.controller_pub = self.create_publisher("controller/state", ControllerState)
        self.create_timer(1.0 / self.rate, self.tick)
        self.was_found = None
        self.log.info("reading the %s-hand controller at %g Hz", hand, self.rate)
    def tick(self) -> None:
        vr, system = self.openvr, self.system
        index = system.getTrackedDeviceIndexForControllerRole(self.role)
        found = index != vr.k_unTrackedDeviceIndexInvalid
        if found != self.was_found:
            self.was_found = found
            self.log.log(logging.INFO if found else logging.WARNING, "controller %s", "found" if found else "not found: is it on?")
        position, quat, trigger, buttons, valid = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], 0.0, [], False
        if found:
            poses = system.getDeviceToAbsoluteTrackingPose(vr.TrackingUniverseStanding, 0, vr.k_unMaxTrackedDeviceCount)
            pose = poses[index]
            if pose.bPoseIsValid:
                position, quat = pose_from_matrix([list(row) for row in pose.mDeviceToAbsoluteTracking])
                valid = True
            ok, state = system.getControllerState(index)
            if ok:
                trigger = float(state.rAxis[TRIGGER_AXIS].x)
                buttons = buttons_from_mask(state.ulButtonPressed)
        hand, controller = from_controller(position, quat, trigger, buttons, valid, self.calibration)
        self.hand_pub.publish(hand)
        self.controller_pub.publish(controller)


def connect():
    """(openvr module, IVRSystem); Unavailable saying what is missing otherwise."""
    try:
        import openvr
    except ImportError:
        raise Unavailable(MISSING_PACKAGE) from None
    try:
        # Background: use a running SteamVR, never start one (so this fails at once without it).
        system = openvr.init(openvr.VRApplication_Background)
    except Exception as exc:  # noqa: BLE001 - openvr raises its own error classes per init failure
        raise Unavailable(NO_STEAMVR.format(error=str(exc) or type(exc).__name__)) from None
    return openvr, system


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

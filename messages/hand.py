"""Tracker messages: the hand in screen coordinates, the controller in the room."""
import math
from typing import Literal

import numpy as np

from .base import Array, Float, Message, doc

IDENTITY = (0.0, 0.0, 0.0, 1.0)  # quaternion x, y, z, w


def check_unit_quaternion(q: np.ndarray, name: str = "orientation", tol: float = 1e-3) -> None:
    """Raise ValueError unless `q` (4,) is a unit quaternion, or every row of a stack (N, 4) is (the
    stack's norms in one array operation; the error names the first row that is not: name[i])."""
    if q.ndim == 1:
        norm = math.hypot(*q.tolist())
        if not abs(norm - 1.0) <= tol:   # NaN too
            raise ValueError(f"{name}: expected a unit quaternion (x, y, z, w), got norm {norm:.6g}")
        return
    n2 = np.einsum("ij,ij->i", q, q)      # squared norms: |n - 1| <= tol is (1 - tol)^2 <= n^2 <= (1 + tol)^2
    if len(n2) and not (n2.min() >= (1.0 - tol) ** 2 and n2.max() <= (1.0 + tol) ** 2):   # NaN fails both
        norms = np.sqrt(n2)
        i = int((~(np.abs(norms - 1.0) <= tol)).argmax())
        raise ValueError(f"{name}[{i}]: expected a unit quaternion (x, y, z, w), got norm {norms[i]:.6g}")


class HandPose(Message):
    """Where the glove hand is, already in the 3D screen's coordinates (topic hand/pose)."""

    position: Array(3) = doc("hand origin in screen units; the screen spans [-1, 1]^3")
    orientation: Array(4) = doc("unit quaternion (x, y, z, w) rotating the hand's frame into the screen's frame",
                                default=IDENTITY)
    valid: bool = doc("false while tracking is lost: consumers treat the hand as absent")

    def check(self):
        if self.valid:
            check_unit_quaternion(self.orientation)


class HandPoses(Message):
    """The glove hand's poses as a served page tracked them, one batch of its frames (topic hand/poses):
    a served study's log, where one message per frame at 72 Hz would cost the server a write each."""

    stamps: Array(None) = doc("each pose's time, the page's clock mapped to the server's, seconds")
    positions: Array(None, 3) = doc("hand origins in screen units (rows of an invalid pose: 0)")
    orientations: Array(None, 4) = doc("unit quaternions (x, y, z, w), hand frame -> screen frame (invalid: 0, 0, 0, 1)")
    valid: Array(None, dtype="bool") = doc("false where tracking was lost: the hand absent in that frame")

    def check(self):
        n = len(self.stamps)
        for name in ("positions", "orientations", "valid"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name}: expected {n} rows, one per stamp, got {len(getattr(self, name))}")
        if self.valid.any():
            check_unit_quaternion(self.orientations[self.valid], "orientations")


class ControllerState(Message):
    """The motion controller held in the glove hand, in room coordinates (topic controller/state)."""

    position: Array(3) = doc("controller position in the room frame, metres")
    orientation: Array(4) = doc("unit quaternion (x, y, z, w), controller frame -> room frame", default=IDENTITY)
    trigger: Float = doc("trigger travel, 0 (released) to 1 (fully pressed)")
    buttons: list[str] = doc("names of the buttons held, e.g. 'menu', 'grip', 'trackpad'")
    valid: bool = doc("false while tracking is lost")

    def check(self):
        if not 0.0 <= self.trigger <= 1.0:
            raise ValueError(f"trigger: expected 0..1, got {self.trigger}")
        if self.valid:
            check_unit_quaternion(self.orientation)


HANDEDNESS = ("right", "left")


class HandJoints(Message):
    """Every tracked joint of a hand, in the 3D screen's coordinates (topic hand/joints), so that a
    session's articulated hand is recorded (and can later carry samples on the fingers)."""

    handedness: Literal[HANDEDNESS] = doc("which hand")
    names: list[str] = doc("joint names, in the order of the arrays (WebXR's: wrist, thumb-metacarpal ... "
                           "pinky-finger-tip)")
    positions: Array(None, 3) = doc("joint centres in screen units")
    orientations: Array(None, 4) = doc(
        "unit quaternions (x, y, z, w), joint frame -> screen frame; WebXR joint axes: -z along the bone toward "
        "the finger tip, +y out of the back of the hand")
    radii: Array(None) = doc("joint radii (centre to skin) in screen units")
    valid: bool = doc("false while the hand is not tracked: the arrays are then empty or stale")

    def check(self):
        n = len(self.names)
        if not (len(self.positions) == len(self.orientations) == len(self.radii) == n):
            raise ValueError(f"names, positions, orientations and radii: expected equal lengths, got {n}, "
                             f"{len(self.positions)}, {len(self.orientations)}, {len(self.radii)}")
        if self.valid:
            check_unit_quaternion(self.orientations, "orientations")

"""Tracker messages: the hand in screen coordinates, the controller in the room."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Array, Bool, Float, Message, StrList, spec


IDENTITY = (0.0, 0.0, 0.0, 1.0)  # quaternion x, y, z, w


def check_unit_quaternion(q: np.ndarray, name: str = "orientation", tol: float = 1e-3) -> None:
    norm = math.hypot(*q.tolist())
    if abs(norm - 1.0) > tol:
        raise ValueError(f"{name}: expected a unit quaternion (x, y, z, w), got norm {norm:.6g}")


@dataclass(kw_only=True)
class HandPose(Message):
    """Where the glove hand is, already in the 3D screen's coordinates (topic hand/pose)."""

    position: np.ndarray = spec(Array((3,)), "hand origin in screen units; the screen spans [-1, 1]^3")
    orientation: np.ndarray = spec(
        Array((4,), default=IDENTITY), "unit quaternion (x, y, z, w) rotating the hand's frame into the screen's frame"
    )
    valid: bool = spec(Bool(), "false while tracking is lost: consumers treat the hand as absent")

    def check(self):
        if self.valid:
            check_unit_quaternion(self.orientation)


@dataclass(kw_only=True)
class ControllerState(Message):
    """The motion controller held in the glove hand, in room coordinates (topic controller/state)."""

    position: np.ndarray = spec(Array((3,)), "controller position in the room frame, metres")
    orientation: np.ndarray = spec(Array((4,), default=IDENTITY), "unit quaternion (x, y, z, w), controller frame -> room frame")
    trigger: float = spec(Float(), "trigger travel, 0 (released) to 1 (fully pressed)")
    buttons: list = spec(StrList(), "names of the buttons held, e.g. 'menu', 'grip', 'trackpad'")
    valid: bool = spec(Bool(), "false while tracking is lost")

    def check(self):
        if not 0.0 <= self.trigger <= 1.0:
            raise ValueError(f"trigger: expected 0..1, got {self.trigger}")
        if self.valid:
            check_unit_quaternion(self.orientation)

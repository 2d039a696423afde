"""Physics messages: the contacts of the 4D rigid-body world (topic physics/contacts)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import Array, Float, Int, Map, Message, Str, StrList, spec


@dataclass(kw_only=True)
class PhysicsContacts(Message):
    """New or hard contacts since the previous message, one row per contact point (topic physics/contacts).

    Published by the physics node when bodies strike each other or the hand pushes one; the tactile node
    adds a short vibration transient on the motors touching the struck objects.
    """

    names: list = spec(StrList(), "object names, in scene order (a and b index them; -1: the hand)")
    a: np.ndarray = spec(Array((None,), dtype="i8"), "first body of each point (object index, -1 the hand)")
    b: np.ndarray = spec(Array((None,), dtype="i8"), "second body of each point (object index)")
    points: np.ndarray = spec(Array((None, 4)), "contact points, world (screen units)")
    normals: np.ndarray = spec(Array((None, 4)), "unit normals from a to b")
    impulses: np.ndarray = spec(Array((None,)), "normal impulse of each point over the step (mass x speed)")
    speeds: np.ndarray = spec(Array((None,)), "closing speed of the point before the step, screen units / s (>= 0)")
    step: int = spec(Int(), "the physics step the contacts happened in")
    time: float = spec(Float(), "simulated time of that step, seconds")

    def check(self):
        n = len(self.a)
        if not (len(self.b) == len(self.points) == len(self.normals) == len(self.impulses) == len(self.speeds) == n):
            raise ValueError("a, b, points, normals, impulses and speeds need one row per contact point")


JOURNAL_KINDS = ("controller", "hand", "command", "run")


@dataclass(kw_only=True)
class PhysicsInput(Message):
    """One entry of the physics node's journal (topic physics/journal): an input it applied, or steps it ran,
    at a step count. A recorded log's journal replays to the same states (`touch4d physics replay`)."""

    step: int = spec(Int(), "the step count the entry was applied at")
    kind: str = spec(Str(JOURNAL_KINDS), "controller | hand | command | run")
    args: dict = spec(Map(), "controller: position, orientation, trigger, buttons, valid; hand: position, orientation, "
                             "valid; command: command, argument; run: steps")

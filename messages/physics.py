"""Physics messages: the contacts of the 4D rigid-body world (topic physics/contacts) and the physics node's
journal of inputs (topic physics/journal)."""
from typing import Literal

from .base import Array, Float, Map, Message, doc

JOURNAL_KINDS = ("controller", "hand", "command", "run", "start")


class PhysicsContacts(Message):
    """New or hard contacts since the previous message, one row per contact point (topic physics/contacts).

    Published by the physics node when bodies strike each other or the hand starts pushing one; the tactile
    node adds a short vibration transient on the motors touching the struck objects.
    """

    names: list[str] = doc("object names, in scene order (a and b index them; -1: the hand)")
    a: Array(None, dtype="i8") = doc("first body of each point (object index, -1 the hand)")
    b: Array(None, dtype="i8") = doc("second body of each point (object index)")
    points: Array(None, 4) = doc("contact points, world (screen units)")
    normals: Array(None, 4) = doc("unit normals from a to b")
    impulses: Array(None) = doc("normal impulse of each point over the step (mass x speed)")
    speeds: Array(None) = doc("closing speed of the point before the step, screen units / s (>= 0)")
    step: int = doc("the physics step the contacts happened in")
    time: Float = doc("simulated time of that step, seconds")

    def check(self):
        n = len(self.a)
        if not (len(self.b) == len(self.points) == len(self.normals) == len(self.impulses) == len(self.speeds) == n):
            raise ValueError("a, b, points, normals, impulses and speeds need one row per contact point")


class PhysicsInput(Message):
    """One entry of the physics node's journal (topic physics/journal): an input it applied, or steps it ran,
    at a step count. A recorded log's journal replays to the same states (`touch4d physics replay`)."""

    step: int = doc("the step count the entry was applied at")
    kind: Literal[JOURNAL_KINDS] = doc("controller | hand | command | run | start (the node's set-up, repeated "
                                       "for a recorder that joins late)")
    args: Map = doc("controller: position, orientation, trigger, buttons, valid; hand: position, orientation, "
                    "valid; command: command, argument; run: steps; start: scene, calibration, glove, push_rate, "
                    "gains, trigger_threshold, buttons, rotate")

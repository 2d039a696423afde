"""What a study's condition allows: are objects drawn, may the motors run? One answer for every
consumer (motor node, desktop renderer, WebXR page), taken from the latest `study/trial`.

- `visual`: objects drawn, motors held off (duty 0);
- `touch`: motors run, no object drawn in any view (the screen's frame and the hand still are);
- `visual+touch`: both.
A condition that sets a view (`slice-visual`, `both-visual+touch`, ...) gates as its modality does.
Outside a trial's stimulus phase (between trials, breaks, pauses, the end) nothing is drawn and the
motors are off. Before any `study/trial` has arrived everything is allowed (no study runs). The last
message holds for good: a study node that dies leaves its gate as it was (fail safe: a visual trial
stays without motors), and one that restarts publishes its state again.
"""
from __future__ import annotations

from dataclasses import dataclass

from touch4d.messages import StudyTrial

from .conditions import BY_NAME



@dataclass(frozen=True)
class Allowed:
    """What may be shown and felt right now."""

    objects: bool
    motors: bool


OPEN = Allowed(objects=True, motors=True)
CLOSED = Allowed(objects=False, motors=False)


def allowed(condition: str, phase: str = "stimulus") -> Allowed:
    """The gate of a condition in a phase; an unknown condition closes it (fail safe)."""
    known = BY_NAME.get(condition)
    if phase != "stimulus" or known is None:
        return CLOSED
    return Allowed(objects=known.objects, motors=known.motors)


GATE_START = ("open", "closed")   # a node's `study_gate` parameter: its gate before any study/trial


class StudyGate:
    """The latest `study/trial`'s gate. `update(msg)` returns True when what is allowed changed.

    `start`: "open" (no study runs: everything allowed until a study/trial says otherwise) or
    "closed" (a study's launch: a node that (re)starts in the middle of a visual trial drives no
    motor, and one in a touch trial draws no object, until the study's next message)."""

    def __init__(self, start: str = "open"):
        if start not in GATE_START:
            raise ValueError(f"study gate start: expected one of {', '.join(GATE_START)}, got {start!r}")
        self.state = OPEN if start == "open" else CLOSED
        self.trial: StudyTrial | None = None

    def update(self, msg: StudyTrial) -> bool:
        before = self.state
        self.trial = msg
        self.state = allowed(msg.condition, msg.phase)
        return self.state != before

    @property
    def objects(self) -> bool:
        return self.state.objects

    @property
    def motors(self) -> bool:
        return self.state.motors

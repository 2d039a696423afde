"""A study's conditions in one place: their names (the wire's, `touch4d.messages.study`), what each
lets through during a trial's stimulus (objects drawn, motors running) and how a participant is told
about it. Study files, the gate, the offline simulation, the trial state machine and the analysis
read them from here."""
from __future__ import annotations

from dataclasses import dataclass

from touch4d.messages.study import STUDY_CONDITIONS


@dataclass(frozen=True)
class Condition:
    """A condition: what the participant sees and feels during a trial's stimulus."""

    name: str
    objects: bool        # the objects are drawn
    motors: bool         # the glove's motors run
    words: str           # how a break's prompt names it


CONDITIONS: tuple[str, ...] = STUDY_CONDITIONS    # ("visual", "touch", "visual+touch"): the usual order
_VISUAL, _TOUCH, _BOTH = CONDITIONS
BY_NAME = {c.name: c for c in (
    Condition(_VISUAL, objects=True, motors=False, words="seeing only (the glove is off)"),
    Condition(_TOUCH, objects=False, motors=True, words="touch only (nothing is shown)"),
    Condition(_BOTH, objects=True, motors=True, words="seeing and touching"))}

"""A study's conditions in one place: their names (the wire's, `touch4d.messages.study`), what each
lets through during a trial's stimulus (objects drawn, motors running), the view it is seen in and
how a participant is told about it. Study files, the gate, the offline simulation, the observers,
the trial state machine and the analysis read them from here.

A condition is a modality (`visual`, `touch`, `visual+touch`), seen in the projection, or a modality
with a view: `slice-<modality>` shows (and, with touch, lets the hand press) each object's
cross-section at the scene's slice_w, `both-<modality>` that section inside the projection."""
from __future__ import annotations

from dataclasses import dataclass

from touch4d.messages.study import STUDY_CONDITIONS, STUDY_MODALITIES, STUDY_VIEWS


@dataclass(frozen=True)
class Condition:
    """A condition: what the participant sees and feels during a trial's stimulus, and in which view."""

    name: str
    modality: str        # visual, touch or visual+touch
    view: str            # projection, slice or both
    objects: bool        # the objects are drawn
    motors: bool         # the glove's motors run
    words: str           # how a break's prompt names it


CONDITIONS: tuple[str, ...] = STUDY_MODALITIES     # ("visual", "touch", "visual+touch"): the usual order
ALL_CONDITIONS: tuple[str, ...] = STUDY_CONDITIONS  # those, then the same in the slice and both views
# Said to every participant, whatever their output: a glove's motors or a held controller's one.
_WORDS = {"visual": "seeing only (nothing vibrates)", "touch": "touch only (nothing is shown)",
          "visual+touch": "seeing and touching"}


def _condition(name: str) -> Condition:
    view, sep, modality = name.partition("-")
    if not sep:
        view, modality = "projection", name
    words = _WORDS[modality] + ("" if view == "projection" else f", {view} view")
    return Condition(name, modality, view, objects=modality != "touch", motors=modality != "visual", words=words)


BY_NAME: dict[str, Condition] = {name: _condition(name) for name in ALL_CONDITIONS}
assert all(c.view in ("projection", *STUDY_VIEWS) for c in BY_NAME.values())


def split_condition(condition: str) -> tuple[str, str]:
    """(what reaches the participant: visual | touch | visual+touch, the view: projection | slice |
    both) of a condition name; ValueError for a name that is not a condition."""
    known = BY_NAME.get(condition)
    if known is None:
        raise ValueError(f"condition: expected one of {', '.join(ALL_CONDITIONS)}, got {condition!r}")
    return known.modality, known.view

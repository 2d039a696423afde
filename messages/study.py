"""Study messages: the trial being run (topic study/trial), the participant's answers (study/response)
and commands to the study node (study/command).

Renderers, the WebXR page and the motor node gate on `study/trial` (touch4d.study.gate): only a trial
in its `stimulus` phase draws objects (unless its condition is `touch`) or drives motors (unless it is
`visual`). Reaction times are measured on the bus clock: a response's `stamp` minus the trial's
`onset` (the stamp of the first `study/trial` of its stimulus phase).
"""
from typing import Literal

from .base import Float, Message, doc

# idle: between trials (the next trial's scene loads); stimulus: the trial runs and takes answers;
# break: a rest the participant ends; paused: the experimenter paused; done: the session is complete.
STUDY_PHASES = ("idle", "stimulus", "break", "paused", "done")
STUDY_CONDITIONS = ("visual", "touch", "visual+touch")
STUDY_COMMANDS = ("pause", "resume", "toggle")
RESPONSE_SOURCES = ("keyboard", "controller", "page", "observer", "cli")


class StudyTrial(Message):
    """The study's state (topic study/trial): published at every change and repeated a few times a
    second, so a node that (re)starts gates at once."""

    study: str = doc("the study's name")
    participant: str = doc("the participant id")
    phase: Literal[STUDY_PHASES] = doc("idle, stimulus, break, paused or done")
    index: int = doc("trial index over the session (practice included); -1: none (done)")
    total: int = doc("trials in the session")
    block: int = doc("block (one per condition), from 0")
    trial: int = doc("trial within its block, from 0")
    practice: bool = doc("a practice trial (not analysed)")
    task: str = doc("task id")
    kind: str = doc("task kind: front-element, look-alikes or tilt")
    condition: Literal[STUDY_CONDITIONS] = doc("visual (motors held off), touch (no object drawn), visual+touch")
    stimulus: str = doc("stimulus name, e.g. face, tilt+8")
    prompt: str = doc("the question shown")
    options: list[str] = doc("the response options, in the order keys 1..9 and buttons pick them")
    onset: Float = doc("stamp of the stimulus onset (bus clock, s); 0 outside the stimulus phase")
    time_limit_s: Float = doc("the trial ends unanswered this long after onset, s")
    message: str = doc("a line for the participant (break, pause, end)")

    def check(self):
        if self.phase == "stimulus" and (self.index < 0 or len(self.options) < 2):
            raise ValueError("options: a trial in its stimulus phase needs an index >= 0 and two options or more")
        if len(self.options) > 9:
            raise ValueError(f"options: at most 9 (keys 1..9), got {len(self.options)}")


class StudyResponse(Message):
    """An answer (topic study/response). Its `stamp` is when it was given on the bus clock (a page maps
    its own clock to it); the study node keeps the first valid answer per trial."""

    index: int = doc("the trial answered (StudyTrial.index)")
    response: str = doc("the option chosen, one of the trial's options")
    source: Literal[RESPONSE_SOURCES] = doc("what gave it: keyboard, controller, page, observer, cli")
    received: Float = doc("when it reached touch4d on the bus clock (a page's: its arrival at the WebXR node); "
                          "0: not known", default=0.0, optional=True)


class StudyCommand(Message):
    """Tell the study node to pause or resume (topic study/command), e.g.
    `touch4d topic pub study/command '{command: pause}'`."""

    command: Literal[STUDY_COMMANDS] = doc("pause, resume or toggle")
    reason: str = doc("why, for the log")

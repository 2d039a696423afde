"""A participant's session as a state machine without a bus: which trial runs, in which phase, when
its scene is (re)loaded, when its stimulus starts and ends, and the row each trial leaves.

`TrialMachine(study, plan, done, participant=..., clock=...)` takes inputs as method calls and leaves
what the caller must do in `outbox`, a list of events drained in order after each call:

- `LoadScene(text)`: load this scene-file text into the scene node (`scene/command` `load`);
- `Announce(stamp)`: the state changed: publish `trial_message(stamp)` (a stimulus's stamp is its onset);
- `TrialDone(trial, row, response)`: write `row` (trials.csv) before anything else happens;
- `Paused(why, interrupted)`, `Resumed(why)`: for the log (an interrupted trial is shown again);
- `Finished()`: the session is complete (phase `done`): stop the motors (`safety/stop`).

Per trial: IDLE until the scene node shows the trial's scene (`scene_shown`) and `iti_s` has passed,
then STIMULUS (its onset is the clock's reading then) until the first valid answer (`respond`, or a
key `1..9`) or `time_limit_s`. A block's first trial, and one the plan offers a break before, start
with a BREAK that `go_on` (Enter, any answer) or `break_s` ends. `pause` interrupts a trial, which
is shown again from its start after `resume`, or a break, which `resume` shows again. After the last
trial: DONE.

One clock, passed in: `clock()` returns seconds on the bus clock (`time.time` in a node, so that
answers' stamps compare with the onset); a test passes a fake and moves it by hand.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import yaml

from touch4d.geometry.scene import parse_scene, scene_digest
from touch4d.messages import SceneState, StudyResponse, StudyTrial
from touch4d.messages.study import STUDY_PHASES
from touch4d.schema import SAFE_DUMPER, parse_yaml

from .conditions import BY_NAME
from .design import Study
from .gate import allowed
from .measures import TrialMeasures
from .plan import Trial
from .stimuli import scene_mapping
from .table import trial_row

# The phases, with the wire's names: IDLE (between trials, the next scene loads), STIMULUS, BREAK,
# PAUSED, DONE.
Phase = enum.StrEnum("Phase", [(name.upper(), name) for name in STUDY_PHASES])

ANSWER_KEYS = {**{str(k): k for k in range(1, 10)}, **{f"kp_{k}": k for k in range(1, 10)}}   # key -> option 1..9
PAUSE_KEYS = ("pause", "f9")            # p and space steer the desktop hand
GO_ON_KEYS = ("enter", "kp_enter")
RELOAD_PERIOD_S = 0.5     # a scene node that lost the trial's scene (restarted) is sent it again this often


@dataclass(frozen=True)
class LoadScene:
    text: str


@dataclass(frozen=True)
class Announce:
    stamp: float = 0.0


@dataclass(frozen=True)
class TrialDone:
    trial: Trial
    row: dict
    response: str | None      # None: timed out


@dataclass(frozen=True)
class Paused:
    why: str
    interrupted: bool         # a trial's stimulus was running: it is shown again


@dataclass(frozen=True)
class Resumed:
    why: str


@dataclass(frozen=True)
class Finished:
    pass


def scene_kind(msg: SceneState) -> tuple:
    """What a scene is made of (not where its objects are turned): tells the trial's scene from another."""
    return tuple((o["name"], o["shape"], float(o["size"]), tuple(np.asarray(o["color"]).tolist()))
                 for o in msg.objects)


def trial_scene_text(study: Study, trial: Trial) -> str:
    """The scene-file text of a trial's stimulus, with nothing a participant may read that gives the
    answer away: neutral object names (the desktop's status line shows them, e.g. a look-alike's
    "cone") and description."""
    mapping = scene_mapping(study, trial)
    mapping["description"] = f"{study.name}: a trial"
    for k, obj in enumerate(mapping["objects"]):
        obj["name"] = f"object-{k + 1}"
    return yaml.dump(mapping, Dumper=SAFE_DUMPER, sort_keys=False)


class TrialMachine:
    """One participant's session: phases, scene loads, onsets, answers, rows (see the module docstring).

    `plan`: the session's trials in order; `done`: indices that already have a row (a resumed
    session starts at the first trial without one). `threshold`: a motor intensity above it is felt
    (the glove's touch threshold, for the exploration columns)."""

    def __init__(self, study: Study, plan: list[Trial], done=(), *, participant: str, session: str = "1",
                 clock: Callable[[], float], iti_s: float = 0.6, break_s: float = 0.0, threshold: float = 0.0):
        self.study, self.plan, self.participant, self.session = study, list(plan), participant, session
        self.clock, self.iti_s, self.break_s = clock, float(iti_s), float(break_s)
        done = set(done)
        self.remaining = [t for t in self.plan if t.index not in done]
        self.measures = TrialMeasures(threshold=threshold)
        self.counts = {"responses": 0, "responses_ignored": 0, "timed_out": 0, "scene_loads": 0, "pauses": 0}
        self.outbox: list = []
        self.phase = Phase.IDLE
        self.message = ""
        self.since = self.onset = 0.0
        self.current: Trial | None = None        # the trial shown or about to be
        self._expected: tuple[bytes, tuple, str] | None = None   # digest, kind and text of its scene
        self._scene_ok = False                   # the scene node shows exactly the trial's scene
        self._scene_kind_ok = False              # ... or the same objects, turned
        self._loaded_at = -np.inf
        self._paused_break = ""                  # the message of a break a pause interrupted

    # ---- the session's course ---------------------------------------------------------------------------
    def start(self) -> None:
        """Begin (or resume) the session: a break before a block's first trial, or the end at once."""
        self._advance(first=True)

    def tick(self) -> None:
        """Check the clock: reload a lost scene, end a timed break, start a stimulus, time a trial out."""
        now = self.clock()
        if self.phase in (Phase.DONE, Phase.PAUSED) or self.current is None:
            return
        # The scene node (re)started without the trial's scene, missed the command, or (before the onset)
        # the scene was turned: send it again. A stimulus already shown keeps being turned as it is.
        wrong = not self._scene_kind_ok if self.phase == Phase.STIMULUS else not self._scene_ok
        if wrong and now - self._loaded_at >= RELOAD_PERIOD_S:
            self._load_scene()
        if self.phase == Phase.BREAK:
            if self.break_s > 0 and now - self.since >= self.break_s:
                self._set_phase(Phase.IDLE)
        elif self.phase == Phase.IDLE:
            if self._scene_ok and now - self.since >= self.iti_s:
                self._start_stimulus(now)
        elif self.phase == Phase.STIMULUS:
            if now - self.onset >= self.current.time_limit_s:
                self._end_trial(None, None)

    def next_check(self) -> float:
        """When (on the machine's clock) `tick` next has something to do unless an event comes first;
        inf: only an event moves the session on. A runner waits for it instead of polling `tick`."""
        if self.phase in (Phase.DONE, Phase.PAUSED) or self.current is None:
            return math.inf
        wrong = not self._scene_kind_ok if self.phase == Phase.STIMULUS else not self._scene_ok
        due = self._loaded_at + RELOAD_PERIOD_S if wrong else math.inf
        if self.phase == Phase.BREAK:
            if self.break_s > 0:
                due = min(due, self.since + self.break_s)
        elif self.phase == Phase.IDLE:
            if self._scene_ok:
                due = min(due, self.since + self.iti_s)
        elif self.phase == Phase.STIMULUS:
            due = min(due, self.onset + self.current.time_limit_s)
        return due

    def _advance(self, first: bool = False) -> None:
        """Go to the next unanswered trial: a break first at a block's start or where the plan offers one."""
        previous = self.current
        self.current = self.remaining[0] if self.remaining else None
        self.measures.reset()
        if self.current is None:
            self._set_phase(Phase.DONE, "Done. Thank you!")
            self.outbox.append(Finished())
            return
        self._prepare_scene()
        known = BY_NAME.get(self.current.condition)
        words = known.words if known else self.current.condition
        if first and self.current.trial == 0:      # a block's start, the session's or after a restart
            self._set_phase(Phase.BREAK, f"Ready? First: {words}. Press Enter or any answer button to start.")
        elif previous is not None and previous.block != self.current.block:
            self._set_phase(Phase.BREAK, f"Break. Next: {words}. Press Enter or any answer button to go on.")
        elif self.current.break_before and not first:
            self._set_phase(Phase.BREAK, "Break. Press Enter or any answer button to go on.")
        else:
            self._set_phase(Phase.IDLE)

    def _prepare_scene(self) -> None:
        text = trial_scene_text(self.study, self.current)
        msg = parse_scene(parse_yaml(text, "study"), "study").to_message()   # as the scene node will read it
        self._expected = (scene_digest(msg), scene_kind(msg), text)
        self._scene_ok = self._scene_kind_ok = False
        self._load_scene()

    def _load_scene(self) -> None:
        self.outbox.append(LoadScene(self._expected[2]))
        self._loaded_at = self.clock()
        self.counts["scene_loads"] += 1

    def _set_phase(self, phase: Phase, message: str = "") -> None:
        self.phase, self.message, self.since = phase, message, self.clock()
        if phase != Phase.STIMULUS:
            self.onset = 0.0
        self.outbox.append(Announce())

    def _start_stimulus(self, now: float) -> None:
        self.phase, self.message, self.since, self.onset = Phase.STIMULUS, "", now, now
        self.outbox.append(Announce(stamp=now))     # its stamp is the onset every consumer sees

    def _end_trial(self, response: str | None, stamp: float | None, received: float | None = None) -> None:
        trial, onset = self.current, self.onset
        end = stamp if stamp is not None else onset + trial.time_limit_s
        m = self.measures.measure(onset, end)
        row = trial_row(trial, participant=self.participant, session=self.session, response=response, onset=onset,
                        response_stamp=stamp, time_touching_s=m.time_touching_s, mean_intensity=m.mean_intensity,
                        path_length=m.path_length, response_received=received)
        self.outbox.append(TrialDone(trial, row, response))   # written before the next trial can start
        self.remaining.pop(0)
        if response is None:
            self.counts["timed_out"] += 1
        self._advance()

    # ---- inputs -----------------------------------------------------------------------------------------
    def respond(self, index: int, response: str, stamp: float, received: float | None = None) -> bool:
        """An answer to trial `index` at `stamp` (bus clock). During its stimulus a valid option ends the
        trial; during a break before it, any answer ends the break (not recorded). `received`: when it
        reached touch4d, if known (a page's answer: table.ARRIVAL_COLUMNS). Returns whether it was taken."""
        cur = self.current
        if cur is not None and self.phase == Phase.BREAK and index == cur.index:
            self._set_phase(Phase.IDLE)
            return True
        if self.phase != Phase.STIMULUS or cur is None or index != cur.index or response not in cur.options \
                or stamp < self.onset:
            self.counts["responses_ignored"] += 1
            return False
        self.counts["responses"] += 1
        self._end_trial(response, stamp, received)
        return True

    def key(self, key: str, stamp: float) -> StudyResponse | None:
        """A key pressed in the participant's window: Pause/F9 toggles the pause, Enter ends a break, 1..9
        answer the stimulus. Returns the answer a key gave (to be published), else None."""
        if key in PAUSE_KEYS:
            self.pause(self.phase != Phase.PAUSED, f"key {key}")
        elif key in GO_ON_KEYS:
            self.go_on()
        elif key in ANSWER_KEYS and self.phase == Phase.STIMULUS and ANSWER_KEYS[key] <= len(self.current.options):
            answer = StudyResponse(index=self.current.index, response=self.current.options[ANSWER_KEYS[key] - 1],
                                   source="keyboard", stamp=stamp)   # when the window saw the key
            self.respond(answer.index, answer.response, answer.stamp)
            return answer
        return None

    def go_on(self) -> None:
        """End a break (Enter); anything else is left as it is."""
        if self.phase == Phase.BREAK:
            self._set_phase(Phase.IDLE)

    def command(self, name: str, why: str = "") -> None:
        """`pause`, `resume` or `toggle` (a `study/command`)."""
        pause = {"pause": True, "resume": False, "toggle": self.phase != Phase.PAUSED}[name]
        self.pause(pause, why or f"study/command {name}")

    def pause(self, pause: bool, why: str) -> None:
        """Pause (a trial under way is shown again from its start) or resume; nothing once done."""
        if self.phase == Phase.DONE:
            return
        if pause and self.phase != Phase.PAUSED:
            self.counts["pauses"] += 1
            self.outbox.append(Paused(why, interrupted=self.phase == Phase.STIMULUS))
            self._paused_break = self.message if self.phase == Phase.BREAK else ""
            self._set_phase(Phase.PAUSED, "Paused.")
        elif not pause and self.phase == Phase.PAUSED:
            self.outbox.append(Resumed(why))
            self.measures.reset()
            if self._paused_break:
                self._set_phase(Phase.BREAK, self._paused_break)
            else:
                self._set_phase(Phase.IDLE)

    def stop(self) -> None:
        """The runner stops (a clean shutdown): close the gate; the trial shown is shown again on resume."""
        if self.phase not in (Phase.DONE, Phase.PAUSED):
            self._set_phase(Phase.PAUSED, "Stopped.")

    def scene_shown(self, msg: SceneState) -> None:
        """What the scene node shows now (`scene/state`)."""
        if self._expected is None:
            return
        self._scene_ok = scene_digest(msg) == self._expected[0]
        self._scene_kind_ok = scene_kind(msg) == self._expected[1]

    def motors(self, stamp: float, intensity) -> None:
        """A motor command (`tactile/motors`). What the glove delivered counts: nothing outside a trial's
        stimulus or where its condition holds the motors off (a visual trial). Outside a trial only the
        latest sample is kept: it holds into the next."""
        stimulus = self.phase == Phase.STIMULUS
        if not stimulus:
            self.measures.reset()
        felt = stimulus and allowed(self.current.condition).motors
        intensity = np.asarray(intensity, dtype=float)
        self.measures.add_motors(stamp, intensity if felt else np.zeros(len(intensity)))

    def motor_rows(self, stamps, intensity) -> None:
        """Many motor commands at once, as `motors` takes them one by one (a served page's batch)."""
        stimulus = self.phase == Phase.STIMULUS
        if not stimulus:
            self.measures.reset()
        intensity = np.asarray(intensity, dtype=float)
        felt = stimulus and allowed(self.current.condition).motors
        self.measures.add_motor_rows(stamps, intensity if felt else np.zeros_like(intensity))

    def poses(self, stamps, positions, valid) -> None:
        """Many hand poses at once, as `pose` takes them one by one."""
        if self.phase != Phase.STIMULUS:
            self.measures.reset()
        self.measures.add_poses(stamps, positions, valid)

    def pose(self, stamp: float, position, valid: bool) -> None:
        """A hand pose (`hand/pose`), for the hand's path."""
        if self.phase != Phase.STIMULUS:
            self.measures.reset()
        self.measures.add_pose(stamp, position, valid)

    # ---- output -----------------------------------------------------------------------------------------
    def trial_message(self, stamp: float = 0.0) -> StudyTrial:
        """The state as a `study/trial` (repeated by the runner, so a node that (re)starts gates at once)."""
        t = self.current
        common = dict(study=self.study.name, participant=self.participant, phase=str(self.phase),
                      total=len(self.plan), message=self.message, stamp=stamp)
        if t is None:
            return StudyTrial(index=-1, **common)
        return StudyTrial(index=t.index, block=t.block, trial=t.trial, practice=t.practice, task=t.task,
                          kind=t.kind, condition=t.condition, stimulus=t.stimulus, prompt=t.prompt,
                          options=list(t.options), onset=self.onset, time_limit_s=t.time_limit_s, **common)

    @property
    def scene_text(self) -> str | None:
        """The scene-file text of the trial shown or about to be (what `LoadScene` last asked for)."""
        return self._expected[2] if self._expected is not None else None

    def drain(self) -> list:
        """The events since the last drain, in order (and an empty outbox)."""
        events, self.outbox = self.outbox, []
        return events

"""Study node: runs a participant's trials on the bus and writes them down (touch4d.study).

Per trial it loads the stimulus into the scene node (`scene/command` `load` with the scene-file
text of touch4d.study.stimuli), waits until `scene/state` shows it and the inter-trial interval has
passed, then starts the stimulus: a `study/trial` in phase `stimulus` whose stamp is the onset. The
renderers, the WebXR page and the motor node gate on it (touch4d.study.gate). The first answer on
`study/response` for that trial (or keys 1..9 in the renderer window, `ui/input`) ends it, timed
from the onset on the bus clock; `time_limit_s` ends it unanswered. Each trial's row goes to
trials.csv, fsync'd, before the next one starts, with the exploration between onset and answer:
time touching and mean intensity of the motors as the glove delivered them (0 in a visual trial,
as the offline simulation counts them) and the hand's path.

Pause: the Pause key or F9, `study/command` {pause, resume, toggle} (`touch4d topic pub study/command
'{command: pause}'`); a trial interrupted by a pause is shown again from its start. Breaks (between
blocks and every `break_every` trials) end with Enter, any answer, `resume`, or after `break_s`.
A restarted node reads trials.csv and resumes at the first trial without a row: nothing lost, none
repeated. At the end: phase `done` (motors gated off, nothing drawn) and a `safety/stop`.
"""
from __future__ import annotations

import time

import numpy as np
import yaml

from touch4d.boards.config import load_glove_can
from touch4d.boards.dbc import dbc_text
from touch4d.bus import Node, Param
from touch4d.geometry.scene import parse_scene, scene_digest
from touch4d.messages import (HandPose, InputEvents, MotorCommand, SceneCommand, SceneState, Stop, StudyCommand,
                              StudyResponse, StudyTrial)
from touch4d.schema import parse_yaml
from touch4d.study.design import load_study, split_condition
from touch4d.study.gate import allowed
from touch4d.study.plan import condition_order, plan_session, quick_plan
from touch4d.study.session import TrialMeasures, TrialsFile, session_dir, start_manifest, trial_row
from touch4d.study.table import TRIALS
from touch4d.tactile.glove import load_glove
from touch4d.study.stimuli import scene_mapping

KEYS = {**{str(k): k for k in range(1, 10)}, **{f"kp_{k}": k for k in range(1, 10)}}
CONDITION_WORDS = {"visual": "seeing only (the glove is off)", "touch": "touch only (nothing is shown)",
                   "visual+touch": "seeing and touching"}
PAUSE_KEYS = ("pause", "f9")            # p and space steer the desktop hand
GO_ON_KEYS = ("enter", "kp_enter")
RELOAD_PERIOD_S = 0.5     # a scene node that lost the trial's scene (restarted) is sent it again this often


def scene_kind(msg: SceneState) -> tuple:
    """What a scene is made of (not where its objects are turned): tells the trial's scene from another."""
    return tuple((o["name"], o["shape"], float(o["size"]), tuple(np.asarray(o["color"]).tolist()))
                 for o in msg.objects)


class StudyNode(Node):
    """Runs a participant's trials: scene, gate, prompt, answers, trials.csv."""

    default_name = "study"
    PARAMS = {
        "study": Param("config/studies/paper.yaml", "the study file", path="study file"),
        "participant": Param("", "participant id (P01, P02, ... pick the counterbalancing rows in turn)"),
        "session": Param("1", "session label written in every row"),
        "out": Param("study-data", "output directory; the session lives in OUT/PARTICIPANT/"),
        "quick": Param(False, "one repetition per task x condition cell, no practice (touch4d.study.plan.quick_plan)"),
        "glove": Param("config/glove.yaml", "the glove file (its touch_threshold; hashed in the manifest)",
                       path="glove file"),
        "calibration": Param("config/calibration.yaml", "the calibration file (hashed in the manifest)",
                             path="calibration file"),
        "iti_s": Param(0.6, "blank time between trials (the next scene loads)", unit="s", min=0, max=60),
        "break_s": Param(0.0, "a break ends by itself after this long (0: when the participant goes on)", unit="s",
                         min=0),
        "rate": Param(5.0, "study/trial repeats, so a (re)started node gates at once", unit="Hz", above=0, max=100),
        "tick_hz": Param(100.0, "how often the trial's clock is checked", unit="Hz", above=0, max=1000),
    }

    def setup(self) -> None:
        p = self.params
        if not p["participant"]:
            raise self.param_error("participant", "a participant id, e.g. P01")
        self.study = load_study(p["study"])
        quick = quick_plan if p["quick"] else plan_session
        self.plan = quick(self.study, p["participant"])
        self.directory = session_dir(p["out"], p["participant"])
        self.trials = TrialsFile(self.directory / TRIALS)
        self.add_cleanup(self.trials.close)
        self.remaining = [t for t in self.plan if t.index not in self.trials.done]
        can = load_glove_can(p["glove"])   # the DBC the motor node speaks, for the manifest
        start_manifest(self.directory, study=self.study, study_path=p["study"], participant=p["participant"],
                       session=p["session"], condition_order=condition_order(self.study, p["participant"]),
                       trials=len(self.plan), glove_path=p["glove"], calibration_path=p["calibration"],
                       dbc_text=dbc_text(can), resumed_at=self.remaining[0].index if self.remaining else -1,
                       quick=p["quick"])
        self.measures = TrialMeasures(threshold=load_glove(p["glove"]).touch_threshold)
        self.counts = {"responses": 0, "responses_ignored": 0, "timed_out": 0, "scene_loads": 0, "pauses": 0}
        self.add_stats(lambda: {**self.counts, "done": len(self.trials.rows), "trials": len(self.plan)})

        self.trial_pub = self.create_publisher("study/trial", StudyTrial)
        self.response_pub = self.create_publisher("study/response", StudyResponse)
        self.scene_pub = self.create_publisher("scene/command", SceneCommand)
        self.stop_pub = self.create_publisher("safety/stop", Stop)
        self.create_subscription("study/response", StudyResponse, self.on_response, optional=True)
        self.create_subscription("study/command", StudyCommand, self.on_command, optional=True)
        self.create_subscription("ui/input", InputEvents, self.on_input, optional=True)
        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors)
        self.create_subscription("hand/pose", HandPose, self.on_pose)

        self.phase = "idle"
        self.since = time.monotonic()
        self.onset = 0.0
        self.message = ""
        self.current = None          # the trial shown or about to be
        self.expected: tuple[bytes, tuple, str] | None = None   # digest, kind and text of its scene
        self.scene_ok = False        # scene/state shows exactly the trial's scene
        self.scene_kind_ok = False   # ... or the same objects, turned
        self.loaded_at = -np.inf
        self.create_timer(1.0 / p["tick_hz"], self.tick)
        self.create_timer(1.0 / p["rate"], self.publish_trial)
        done = len(self.plan) - len(self.remaining)
        self.log.info("study %s, participant %s: %d trials (%s), %d already done; writing %s", self.study.name,
                      p["participant"], len(self.plan), ", ".join(condition_order(self.study, p["participant"])),
                      done, self.directory)
        self._advance(first=True)

    # ---- the session's course ---------------------------------------------------------------------------
    def _advance(self, first: bool = False) -> None:
        """Go to the next unanswered trial: a break first at a block's start or where the plan offers one."""
        previous = self.current
        self.current = self.remaining[0] if self.remaining else None
        self.measures.reset()
        if self.current is None:
            self._finish_session()
            return
        self._prepare_scene()
        modality, view = split_condition(self.current.condition)
        words = CONDITION_WORDS[modality] + ("" if view == "projection" else f", {view} view")
        new_block = previous is not None and previous.block != self.current.block
        if first and self.current.trial == 0:      # a block's start, the session's or after a restart
            self._set_phase("break", f"Ready? First: {words}. Press Enter or any answer button to start.")
        elif new_block:
            self._set_phase("break", f"Break. Next: {words}. Press Enter or any answer button to go on.")
        elif self.current.break_before and not first:
            self._set_phase("break", "Break. Press Enter or any answer button to go on.")
        else:
            self._set_phase("idle", "")

    def _prepare_scene(self) -> None:
        mapping = scene_mapping(self.study, self.current)
        # Nothing a participant may read gives the answer away: the objects' names (the desktop's status
        # line shows them, e.g. a look-alike's "cone") and the description are neutral.
        mapping["description"] = f"{self.study.name}: a trial"
        for k, obj in enumerate(mapping["objects"]):
            obj["name"] = f"object-{k + 1}"
        text = yaml.safe_dump(mapping, sort_keys=False)
        msg = parse_scene(parse_yaml(text, "study"), "study").to_message()   # as the scene node will read it
        self.expected = (scene_digest(msg), scene_kind(msg), text)
        self.scene_ok = self.scene_kind_ok = False
        self._load_scene()

    def _load_scene(self) -> None:
        self.scene_pub.publish(SceneCommand(command="load", argument=self.expected[2]))
        self.loaded_at = time.monotonic()
        self.counts["scene_loads"] += 1

    def _set_phase(self, phase: str, message: str = "") -> None:
        self.phase, self.message, self.since = phase, message, time.monotonic()
        if phase != "stimulus":
            self.onset = 0.0
        self.publish_trial()

    def _finish_session(self) -> None:
        self._set_phase("done", "Done. Thank you!")
        self.stop_pub.publish(Stop(reason="study session complete", origin=self.name))
        self.log.info("session complete: %d trials in %s", len(self.trials.rows), self.directory / TRIALS)

    def tick(self) -> None:
        now = time.monotonic()
        if self.phase in ("done", "paused") or self.current is None:
            return
        # The scene node (re)started without the trial's scene, missed the command, or (before the onset)
        # the scene was turned: send it again. A stimulus already shown keeps being turned as it is.
        wrong = not self.scene_kind_ok if self.phase == "stimulus" else not self.scene_ok
        if wrong and now - self.loaded_at >= RELOAD_PERIOD_S:
            self._load_scene()
        if self.phase == "break":
            if self.params["break_s"] > 0 and now - self.since >= self.params["break_s"]:
                self._set_phase("idle")
        elif self.phase == "idle":
            if self.scene_ok and now - self.since >= self.params["iti_s"]:
                self._start_stimulus()
        elif self.phase == "stimulus":
            if time.time() - self.onset >= self.current.time_limit_s:
                self._end_trial(None, None)

    def _start_stimulus(self) -> None:
        self.phase, self.message, self.since = "stimulus", "", time.monotonic()
        self.onset = time.time()
        self.publish_trial(stamp=self.onset)     # its stamp is the onset every consumer sees

    def _end_trial(self, response: str | None, stamp: float | None) -> None:
        trial, onset = self.current, self.onset
        end = stamp if stamp is not None else onset + trial.time_limit_s
        row = trial_row(trial, participant=self.params["participant"], session=self.params["session"],
                        response=response, onset=onset, response_stamp=stamp,
                        measures=self.measures.measure(onset, end))
        self.trials.write(row)                    # fsync'd before anything else happens
        self.remaining.pop(0)
        if response is None:
            self.counts["timed_out"] += 1
        self.log.info("trial %d/%d %s %s %s: %s (%s)%s", trial.index + 1, len(self.plan), trial.condition,
                      trial.task, trial.stimulus, response or "timed out", trial.answer,
                      f" in {stamp - onset:.2f} s" if stamp is not None else "")
        self._advance()

    # ---- inputs ---------------------------------------------------------------------------------------
    def on_response(self, msg: StudyResponse) -> None:
        cur = self.current
        if cur is not None and self.phase == "break" and msg.index == cur.index:
            self._set_phase("idle")               # any answer ends a break (it is not recorded)
            return
        if (self.phase != "stimulus" or cur is None or msg.index != cur.index or msg.response not in cur.options
                or msg.stamp < self.onset):
            self.counts["responses_ignored"] += 1
            return
        self.counts["responses"] += 1
        self._end_trial(msg.response, msg.stamp)

    def on_input(self, msg: InputEvents) -> None:
        for key in msg.pressed:
            if key in PAUSE_KEYS:
                self._pause(self.phase != "paused", f"key {key}")
            elif key in GO_ON_KEYS and self.phase == "break":
                self._set_phase("idle")
            elif key in KEYS and self.phase == "stimulus" and KEYS[key] <= len(self.current.options):
                answer = StudyResponse(index=self.current.index, response=self.current.options[KEYS[key] - 1],
                                       source="keyboard", stamp=msg.stamp)   # when the window saw the key
                self.response_pub.publish(answer)
                self.on_response(answer)

    def on_command(self, msg: StudyCommand) -> None:
        pause = {"pause": True, "resume": False, "toggle": self.phase != "paused"}[msg.command]
        self._pause(pause, msg.reason or f"study/command {msg.command}")

    def _pause(self, pause: bool, why: str) -> None:
        if self.phase == "done":
            return
        if pause and self.phase != "paused":
            self.counts["pauses"] += 1
            self.log.info("paused (%s)%s", why, "; the trial will be shown again" if self.phase == "stimulus" else "")
            self._set_phase("paused", "Paused.")
        elif not pause and self.phase == "paused":
            self.log.info("resumed (%s)", why)
            self.measures.reset()
            self._set_phase("idle")

    def on_scene(self, msg: SceneState) -> None:
        if self.expected is None:
            return
        self.scene_ok = scene_digest(msg) == self.expected[0]
        self.scene_kind_ok = scene_kind(msg) == self.expected[1]

    def on_motors(self, msg: MotorCommand) -> None:
        # What the glove delivered: nothing outside a trial's stimulus or where its condition holds the
        # motors off (a visual trial). Outside a trial only the latest sample is kept: it holds into the next.
        stimulus = self.phase == "stimulus"
        if not stimulus:
            self.measures.reset()
        felt = stimulus and allowed(self.current.condition).motors
        self.measures.add_motors(msg.stamp, msg.intensity if felt else np.zeros(len(msg.intensity)))

    def on_pose(self, msg: HandPose) -> None:
        if self.phase != "stimulus":
            self.measures.reset()
        self.measures.add_pose(msg.stamp, msg.position, msg.valid)

    # ---- output ---------------------------------------------------------------------------------------
    def publish_trial(self, stamp: float = 0.0) -> None:
        t = self.current
        common = dict(study=self.study.name, participant=self.params["participant"], phase=self.phase,
                      total=len(self.plan), message=self.message, stamp=stamp)
        if t is None:
            msg = StudyTrial(index=-1, **common)
        else:
            msg = StudyTrial(index=t.index, block=t.block, trial=t.trial, practice=t.practice, task=t.task,
                             kind=t.kind, condition=t.condition, stimulus=t.stimulus, prompt=t.prompt,
                             options=list(t.options), onset=self.onset, time_limit_s=t.time_limit_s, **common)
        self.trial_pub.publish(msg)

    def on_shutdown(self) -> None:
        """A clean stop closes the gate (motors off, nothing drawn); the trial shown is shown again on resume."""
        if self.phase not in ("done", "paused"):
            self._set_phase("paused", "Stopped.")
        self.log.info("stopped with %d of %d trials done: %s", len(self.trials.rows), len(self.plan), self.counts)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

"""Study node: runs a participant's trials on the bus and writes them down. The trial state machine is
touch4d.study.machine.TrialMachine; this node wires it to topics, trials.csv and the manifest.

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

import json
import math
import time

from touch4d.boards.config import load_glove_can
from touch4d.boards.dbc import dbc_text
from touch4d.bus import Node, Param
from touch4d.messages import (HandPose, InputEvents, MotorCommand, SceneCommand, SceneState, Stop, StudyCommand,
                              StudyResponse, StudyTrial)
from touch4d.study.design import load_study
from touch4d.study.machine import Announce, Finished, LoadScene, Paused, Resumed, TrialDone, TrialMachine
from touch4d.study.lock import WRITER, SessionLock
from touch4d.study.manifest import start_manifest
from touch4d.study.plan import condition_order, order_note, order_table, plan_session, quick_plan
from touch4d.study.store import TrialsFile, session_dir
from touch4d.study.table import TRIALS
from touch4d.tactile.glove import load_glove


class StudyNode(Node):
    """Runs a participant's trials: scene, gate, prompt, answers, trials.csv."""

    default_name = "study"
    PARAMS = {
        "study": Param("config/studies/paper.yaml", "the study file", path="study file"),
        "participant": Param("", "participant id (P01, P02, ... pick the counterbalancing rows in turn)"),
        "order": Param(None, "counterbalancing row, from 1 (default: from the participant id)", type=int, min=1),
        "session": Param("1", "session label written in every row"),
        "simulation": Param("", "a simulation's settings as JSON, kept in the manifest (touch4d study run --simulate "
                                "sets it; empty: a participant's session)"),
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
    }

    def setup(self) -> None:
        p = self.params
        if not p["participant"]:
            raise self.param_error("participant", "a participant id, e.g. P01")
        try:
            simulation = json.loads(p["simulation"]) if p["simulation"] else None
        except ValueError as exc:
            raise self.param_error("simulation", "the simulation's settings as JSON, or empty", got=str(exc)) from None
        self.study = load_study(p["study"])
        rows = len(order_table(self.study))
        if p["order"] is not None and p["order"] > rows:
            raise self.param_error("order", f"a counterbalancing row 1..{rows} of study {self.study.name}")
        quick = quick_plan if p["quick"] else plan_session
        self.plan = quick(self.study, p["participant"], p["order"])
        self.directory = session_dir(p["out"], p["participant"])
        # one writer of trials.csv: held as long as this process lives, even when its `study run` is gone
        self.add_cleanup(SessionLock(self.directory, WRITER).acquire().release)
        self.trials = TrialsFile(self.directory / TRIALS)
        self.add_cleanup(self.trials.close)
        # one clock for the whole session: the bus clock, on which answers and poses are stamped
        self.machine = TrialMachine(self.study, self.plan, self.trials.done, participant=p["participant"],
                                    session=p["session"], clock=time.time, iti_s=p["iti_s"], break_s=p["break_s"],
                                    threshold=load_glove(p["glove"]).touch_threshold)
        remaining = self.machine.remaining
        can = load_glove_can(p["glove"])   # the DBC the motor node speaks, for the manifest
        order = condition_order(self.study, p["participant"], p["order"])
        note = order_note(self.study, p["participant"], p["order"])
        if note:
            self.log.warning("%s", note)
        start_manifest(self.directory, study=self.study, study_path=p["study"], participant=p["participant"],
                       session=p["session"], condition_order=order, trials=len(self.plan), glove_path=p["glove"],
                       calibration_path=p["calibration"], dbc_text=dbc_text(can),
                       resumed_at=remaining[0].index if remaining else -1, quick=p["quick"],
                       simulation=simulation)
        self.add_stats(lambda: {**self.machine.counts, "done": len(self.trials.rows), "trials": len(self.plan)})

        self.trial_pub = self.create_publisher("study/trial", StudyTrial)
        self.response_pub = self.create_publisher("study/response", StudyResponse)
        self._keyed: set[tuple[int, float]] = set()   # (index, stamp) of the key answers published here
        self.scene_pub = self.create_publisher("scene/command", SceneCommand)
        self.stop_pub = self.create_publisher("safety/stop", Stop)
        self.create_subscription("study/response", StudyResponse, self.on_response, optional=True)
        self.create_subscription("study/command", StudyCommand, self.on_command, optional=True)
        self.create_subscription("ui/input", InputEvents, self.on_input, optional=True)
        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors)
        self.create_subscription("hand/pose", HandPose, self.on_pose)
        self._check = None   # the one-shot timer at the machine's next deadline (TrialMachine.next_check)
        self._check_due = math.nan
        self.create_timer(1.0 / p["rate"], self.publish_trial)
        self.log.info("study %s, participant %s: %d trials (%s), %d already done; writing %s", self.study.name,
                      p["participant"], len(self.plan), ", ".join(order), len(self.plan) - len(remaining),
                      self.directory)
        self.machine.start()
        self._act()

    # ---- the machine's events -------------------------------------------------------------------------
    def _act(self) -> None:
        """Do what the machine asked, in order (a trial's row is fsync'd before anything after it)."""
        for event in self.machine.drain():
            if isinstance(event, LoadScene):
                self.scene_pub.publish(SceneCommand(command="load", argument=event.text))
            elif isinstance(event, Announce):
                self.publish_trial(stamp=event.stamp)
            elif isinstance(event, TrialDone):
                self._write(event)
            elif isinstance(event, Paused):
                self.log.info("paused (%s)%s", event.why, "; the trial will be shown again" if event.interrupted
                              else "")
            elif isinstance(event, Resumed):
                self.log.info("resumed (%s)", event.why)
            elif isinstance(event, Finished):
                self.stop_pub.publish(Stop(reason="study session complete", origin=self.name))
                self.log.info("session complete: %d trials in %s", len(self.trials.rows), self.directory / TRIALS)
        self._schedule()

    def _schedule(self) -> None:
        """Check the trial's clock when the machine next has something to do (an onset, a timeout, the
        end of a break, a scene to send again), not at a polling rate: a participant's process wakes
        for its trials' deadlines only."""
        due = self.machine.next_check()
        if self._check is not None and due == self._check_due and not self._check.cancelled:
            return   # the same deadline (a scene state repeated): its timer stands
        if self._check is not None:
            self._check.cancel()
            self._check = None
        self._check_due = due
        if math.isfinite(due):
            self._check = self.call_later(max(0.0, due - time.time()), self.tick)

    def _write(self, done: TrialDone) -> None:
        self.trials.write(done.row)                    # fsync'd before anything else happens
        t, row = done.trial, done.row
        self.log.info("trial %d/%d %s %s %s: %s (%s)%s", t.index + 1, len(self.plan), t.condition, t.task,
                      t.stimulus, done.response or "timed out", t.answer,
                      f" in {row['rt_s']:.2f} s" if done.response is not None else "")

    @property
    def phase(self) -> str:
        return str(self.machine.phase)

    @property
    def counts(self) -> dict:
        return self.machine.counts

    @property
    def remaining(self) -> list:
        return self.machine.remaining

    # ---- inputs ---------------------------------------------------------------------------------------
    def tick(self) -> None:
        self.machine.tick()
        self._act()

    def on_response(self, msg: StudyResponse) -> None:
        if (msg.index, msg.stamp) in self._keyed:    # a key's answer, taken already, back from the bus
            self._keyed.discard((msg.index, msg.stamp))
            return
        self.machine.respond(msg.index, msg.response, msg.stamp, msg.received)
        self._act()

    def on_input(self, msg: InputEvents) -> None:
        for key in msg.pressed:
            answer = self.machine.key(key, msg.stamp)
            if answer is not None:
                self._keyed.add((answer.index, answer.stamp))
                self.response_pub.publish(answer)
            self._act()

    def on_command(self, msg: StudyCommand) -> None:
        self.machine.command(msg.command, msg.reason)
        self._act()

    def on_scene(self, msg: SceneState) -> None:
        self.machine.scene_shown(msg)
        self._schedule()   # the trial's scene shown: its onset may be due

    def on_motors(self, msg: MotorCommand) -> None:
        self.machine.motors(msg.stamp, msg.intensity)

    def on_pose(self, msg: HandPose) -> None:
        self.machine.pose(msg.stamp, msg.position, msg.valid)

    # ---- output ---------------------------------------------------------------------------------------
    def publish_trial(self, stamp: float = 0.0) -> None:
        self.trial_pub.publish(self.machine.trial_message(stamp))

    def on_shutdown(self) -> None:
        """A clean stop closes the gate (motors off, nothing drawn); the trial shown is shown again on resume."""
        self.machine.stop()
        self._act()
        self.log.info("stopped with %d of %d trials done: %s", len(self.trials.rows), len(self.plan), self.counts)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

"""Study observer node: a simulated participant on the bus (touch4d.study.observer.ModelObserver).

It takes the tracker role: in each trial's stimulus phase (`study/trial`) its scripted hand visits the
observer's `explore` positions on `hand/pose`, staying at each until the tactile node's command for
that very pose (`tactile/motors`, matched by its `source_stamp`) has arrived, and `dwell_s` more when
the condition lets the motors run. Then it decides with `ModelObserver.respond` (from the motor
patterns it felt when the motors run, from the scene it sees, `scene/state`, when objects are drawn)
and answers on `study/response` when the offline simulation's answer time has passed since the onset
(touch4d.study.simulate.answer_time: look, dwell per touch, decide, a log-normal factor), never
sooner than its hand is done; an answer time beyond the trial's limit is no answer (the trial times
out, as offline). `pace` scales every time (1: the offline simulation's; a quick check of the stack
may take less, and its answer times then mean nothing). Breaks it ends at once, as a participant
pressing a button. Between trials its hand is away (an invalid pose).
"""
from __future__ import annotations

import time

import numpy as np

from touch4d.bus import Node, Param
from touch4d.geometry.scene import Scene
from touch4d.messages import HandPose, MotorCommand, SceneState, StudyResponse, StudyTrial
from touch4d.study.design import load_study
from touch4d.study.gate import allowed
from touch4d.study.observer import FACING, ModelObserver
from touch4d.study.plan import participant_hash, plan_session, quick_plan
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.study.simulate import Timing, answer_time
from touch4d.tactile.glove import load_glove

RESEND_S = 0.5       # a pose whose command has not come back by then is published again


class StudyObserverNode(Node):
    """A model observer that explores with a scripted hand and answers the study's trials."""

    default_name = "observer"
    PARAMS = {
        "study": Param("config/studies/paper.yaml", "the study file", path="study file"),
        "participant": Param("", "the participant id the study node runs (the plan is the same)"),
        "quick": Param(False, "the study node's quick plan (touch4d.study.plan.quick_plan)"),
        "order": Param(None, "the study node's counterbalancing row, from 1 (default: from the participant id)",
                       type=int, min=1),
        "glove": Param("config/glove.yaml", "the glove file (the tactile node's)", path="glove file"),
        "seed": Param(None, "observer seed (default: from the participant id)", type=int),
        "noise": Param(HUMAN_NOISE, "sensory noise on a finger's motors, fraction of full drive (default: the "
                       "fingertip's amplitude discrimination; the palm's: x0.64, the thenar's)", min=0),
        "lapse": Param(0.03, "chance of a random answer", min=0, max=1),
        "look_s": Param(Timing.look_s, "time to look when objects are drawn", unit="s", min=0),
        "dwell_s": Param(Timing.dwell_s, "time at each position after its motor command arrived, when the motors run",
                         unit="s", min=0),
        "decide_s": Param(Timing.decide_s, "time to decide", unit="s", min=0),
        "rt_spread": Param(Timing.rt_spread, "sd of the log of the answer-time factor", min=0),
        "pace": Param(1.0, "every time above scaled by this (1: the offline simulation's)", above=0, max=10),
        "train_scenes": Param(12, "jittered scenes per stimulus the observer learns from", min=1),
        "train_positions": Param(20, "hand positions per training scene", min=1),
        "view_scenes": Param(30, "jittered views per stimulus the observer learns from", min=1),
    }

    def setup(self) -> None:
        p = self.params
        if not p["participant"]:
            raise self.param_error("participant", "the participant id the study node runs, e.g. P01")
        self.study = load_study(p["study"])
        quick = quick_plan if p["quick"] else plan_session
        self.plan = {t.index: t for t in quick(self.study, p["participant"], p["order"])}
        seed = p["seed"] if p["seed"] is not None else participant_hash(p["participant"]) % 2**32
        self.observer = ModelObserver(load_glove(p["glove"]), self.study, noise=p["noise"], lapse=p["lapse"],
                                      seed=seed, train_scenes=p["train_scenes"],
                                      train_positions=p["train_positions"], view_scenes=p["view_scenes"])
        started = time.monotonic()
        self.observer.train()
        self.log.info("model observer (seed %d) trained on %d tasks in %.1f s", seed, len(self.study.tasks),
                      time.monotonic() - started)
        self.seed = seed
        self.timing = Timing(look_s=p["look_s"] * p["pace"], dwell_s=p["dwell_s"] * p["pace"],
                             decide_s=p["decide_s"] * p["pace"], rt_spread=p["rt_spread"])
        self.pose_pub = self.create_publisher("hand/pose", HandPose)
        self.response_pub = self.create_publisher("study/response", StudyResponse)
        self.create_subscription("study/trial", StudyTrial, self.on_trial, latest_only=True)
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors)
        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        self.create_timer(0.01, self.tick)
        self.scene: SceneState | None = None
        self.trial = None            # the planned trial being explored
        self.message: StudyTrial | None = None
        self.answered: set[int] = set()
        self.positions = np.zeros((0, 3))
        self.patterns: list[np.ndarray] = []
        self.pending = 0.0           # stamp of the pose whose command is awaited
        self.sent_at = 0.0
        self.felt_at: float | None = None
        self.answer: tuple[str, float] | None = None    # decided: the answer and when to give it (bus clock)
        self.counts = {"trials": 0, "breaks": 0, "resent": 0, "too_slow": 0}
        self.add_stats(lambda: dict(self.counts))
        self._onset = 0.0
        self._away()

    def _away(self) -> None:
        self.pose_pub.publish(HandPose(position=np.zeros(3), valid=False))

    def on_scene(self, msg: SceneState) -> None:
        self.scene = msg

    def on_trial(self, msg: StudyTrial) -> None:
        self.message = msg
        if msg.phase == "break":
            self.counts["breaks"] += 1
            self.response_pub.publish(StudyResponse(index=msg.index, response="", source="observer"))
            return
        if msg.phase != "stimulus":
            if self.trial is not None:       # paused, or the trial ended: the hand leaves
                self.trial = None
                self._away()
            return
        if self.trial is not None and self.trial.index == msg.index:
            return
        if msg.index in self.answered and msg.onset == self._onset:
            return
        planned = self.plan.get(msg.index)
        if planned is None or (planned.task, planned.stimulus, planned.condition) != (msg.task, msg.stimulus,
                                                                                     msg.condition):
            self.warn_once(("plan", msg.index), f"study/trial {msg.index} is not trial {msg.index} of this "
                                                f"observer's plan: are study, participant and quick the same?")
            return
        self._onset = msg.onset
        self.trial = planned
        self.rng = np.random.default_rng([self.seed, planned.seed])
        self.positions = self.observer.explore(planned, self.rng)
        self.patterns = []
        self.answer = None
        self.dwell_s = self.timing.dwell_s if allowed(msg.condition, msg.phase).motors else 0.0
        self._visit()

    def _visit(self) -> None:
        k = len(self.patterns)
        pose = HandPose(position=np.asarray(self.positions[k], dtype=float), orientation=FACING.copy(), valid=True)
        self.pose_pub.publish(pose)
        self.pending, self.sent_at, self.felt_at = pose.stamp, time.time(), None

    def on_motors(self, msg: MotorCommand) -> None:
        if self.trial is not None and self.felt_at is None and msg.source_stamp == self.pending:
            self.patterns.append(np.asarray(msg.intensity, dtype=float).copy())
            self.felt_at = time.time()

    def tick(self) -> None:
        if self.trial is None:
            return
        if self.answer is not None:
            if time.time() >= self.answer[1]:     # one clock, the bus clock: the onset is on it
                self._give(self.answer[0])
            return
        now = time.time()
        if self.felt_at is None:
            if now - self.sent_at >= RESEND_S:
                self.counts["resent"] += 1
                self._visit()
            return
        if now - self.felt_at < self.dwell_s:
            return
        if len(self.patterns) < len(self.positions):
            self._visit()
            return
        self._decide()

    def _decide(self) -> None:
        """Answer from what got through; give it at the onset plus the offline answer time."""
        trial, gate = self.trial, allowed(self.message.condition, self.message.phase)
        patterns = np.array(self.patterns) if gate.motors else None        # motors held off: nothing felt
        scene = Scene.from_message(self.scene) if gate.objects and self.scene is not None else None
        answer = self.observer.respond(trial, patterns, scene, self.rng)
        rt = answer_time(self.timing, trial, len(self.positions), self.rng)
        if rt > trial.time_limit_s:
            self.counts["too_slow"] += 1       # no answer: the study node times the trial out
            self.answered.add(trial.index)
            self.trial = None
            self._away()
            return
        self.answer = (answer, self._onset + rt)

    def _give(self, answer: str) -> None:
        trial = self.trial
        self.response_pub.publish(StudyResponse(index=trial.index, response=answer, source="observer"))
        self.answered.add(trial.index)
        self.counts["trials"] += 1
        self.trial = None
        self.answer = None
        self._away()


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

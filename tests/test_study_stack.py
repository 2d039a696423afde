"""A study through the full stack (launch/study.yaml: scene, tactile, motors with emulated boards, the
study node, a recorder, and a model observer as the participant), run the way `touch4d study run
--simulate --quick` runs it. Its study node is SIGKILLed in the middle of a trial: the session goes
on, the interrupted trial is shown again, and trials.csv ends with every task x condition cell once,
in the plan's order. The motor node's duties stay 0 through every visual trial, and the log holds
every answer."""
from __future__ import annotations

import csv
import json
import os
import signal
import threading

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.log.reader import LogReader
from touch4d.messages import Heartbeat, MotorStatus, StudyResponse, StudyTrial, decode
from touch4d.study.design import load_study
from touch4d.study.gate import allowed
from touch4d.study.observer import Exploration
from touch4d.study.plan import condition_order, quick_plan
from touch4d.study.session import SessionOptions, run_session
from touch4d.study.simulate import Timing
from touch4d.study.table import COLUMNS

pytestmark = pytest.mark.timeout(180)

STUDY = "config/studies/paper.yaml"
PARTICIPANT = "P04"           # row 3 of the counterbalancing: an order other than the file's
KILL_AT = 4                   # the trial whose stimulus is running when the study node is killed
PACE = 0.1                    # the observer takes a tenth of the offline simulation's times (a quicker test)


class Watcher:
    """Collects study/trial, study/response, motors/status and heartbeats from the running stack, and
    SIGKILLs the study node as soon as trial KILL_AT's stimulus is on."""

    def __init__(self):
        self.bus_ready = threading.Event()
        self.trials: list[StudyTrial] = []
        self.responses: list[StudyResponse] = []
        self.status: list[MotorStatus] = []
        self.pids: dict[str, int] = {}
        self.killed: int | None = None
        self.stop = False
        self.error: BaseException | None = None

    def on_ready(self, bus):
        self.bus = bus
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()
        self.bus_ready.wait(30)

    def run(self):
        try:
            node = Node("test-watcher", bus=self.bus, heartbeat=False)
            node.create_subscription("study/trial", StudyTrial, self.on_trial)
            node.create_subscription("study/response", StudyResponse, self.responses.append)
            node.create_subscription("motors/status", MotorStatus, self.status.append)
            node.create_subscription("node/heartbeat", Heartbeat, lambda h: self.pids.__setitem__(h.node, h.pid))
            self.bus_ready.set()
            while not self.stop:
                node.spin_once(0.02)
            node.shutdown()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc
            self.bus_ready.set()

    def on_trial(self, msg: StudyTrial):
        self.trials.append(msg)
        # trial KILL_AT's stimulus is on (the observer's hand is on its way): kill the study node now
        if msg.phase == "stimulus" and msg.index == KILL_AT and self.killed is None and "study" in self.pids:
            self.killed = self.pids["study"]
            os.kill(self.killed, signal.SIGKILL)


def test_a_quick_study_runs_every_cell_through_the_full_stack_and_survives_its_study_node_killed(tmp_path):
    watcher = Watcher()
    code = {}
    runner = threading.Thread(target=lambda: code.setdefault("rc", run_session(
        STUDY, PARTICIPANT, tmp_path, [f"tracker.pace:={PACE}"],
        options=SessionOptions(simulate=True, quick=True, seed=7, timeout_s=150), echo=lambda line: None,
        on_ready=watcher.on_ready)))
    runner.start()
    runner.join(170)
    watcher.stop = True
    assert not runner.is_alive() and watcher.error is None
    assert code["rc"] == 0
    assert watcher.killed is not None, "the study node was never killed"

    study = load_study(STUDY)
    plan = quick_plan(study, PARTICIPANT)
    directory = tmp_path / PARTICIPANT
    with open(directory / "trials.csv", newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == COLUMNS
        rows = list(reader)
    # every trial once, nothing repeated, in the plan's order: every task x condition cell
    assert [int(r["index"]) for r in rows] == list(range(len(plan))) == [t.index for t in plan]
    assert [(r["task"], r["condition"], r["stimulus"], r["answer"]) for r in rows] == \
        [(t.task, t.condition, t.stimulus, t.answer) for t in plan]
    assert {(r["task"], r["condition"]) for r in rows} == {(t.id, c) for t in study.tasks for c in study.conditions}
    conditions_in_order = list(dict.fromkeys(r["condition"] for r in rows))
    assert conditions_in_order == condition_order(study, PARTICIPANT) != list(study.conditions)
    for r in rows:
        assert r["timed_out"] == "0" and r["response"] in study.task(r["task"]).options
        assert float(r["rt_s"]) > 0
        assert float(r["rt_s"]) == pytest.approx(float(r["response_stamp"]) - float(r["onset_stamp"]), abs=1e-6)
        assert r["correct"] == ("1" if r["response"] == r["answer"] else "0")
        # the exploration: the observer's hand visits 6 places (5 steps after the first, from away)
        assert 0.0 <= float(r["time_touching_s"]) <= float(r["rt_s"]) + 1e-6
        assert float(r["path_length"]) > 0.0 and float(r["mean_intensity"]) >= 0.0
    assert max(float(r["time_touching_s"]) for r in rows) > 0.0
    # answer times as the offline simulation's (simulate.answer_time, scaled by PACE): never sooner than
    # 4 sd of the log-normal factor below the trial's look + dwell per touch + decide, about it in the median
    timing, touches = Timing(), Exploration().touches
    base = {c: PACE * (timing.look_s * g.objects + timing.dwell_s * touches * g.motors + timing.decide_s)
            for c in study.conditions for g in [allowed(c)]}
    ratios = [float(r["rt_s"]) / base[r["condition"]] for r in rows]
    assert min(ratios) >= np.exp(-4 * timing.rt_spread) and np.median(ratios) >= 0.7
    # as the offline simulation counts them: nothing is felt where the motors are held off
    assert all(float(r["time_touching_s"]) == 0.0 == float(r["mean_intensity"])
               for r in rows if r["condition"] == "visual")

    # the killed trial, and only it, was shown twice (two onsets); its row is the second showing's
    shown = {}
    for m in watcher.trials:
        if m.phase == "stimulus":
            shown.setdefault(m.index, set()).add(m.onset)
    assert [i for i, o in shown.items() if len(o) > 1] == [KILL_AT] and set(shown) == set(range(len(plan)))
    onsets = sorted(shown[KILL_AT])
    assert float(rows[KILL_AT]["onset_stamp"]) == pytest.approx(onsets[1], abs=1e-6)
    manifest = json.loads((directory / "manifest.json").read_text())
    assert [s["resumed_at"] for s in manifest["starts"]] == [0, KILL_AT]
    assert manifest["condition_order"] == condition_order(study, PARTICIPANT)

    # the gate: no duty above 0 while a visual trial's stimulus ran; some where touch was allowed
    spans = {}
    for m in watcher.trials:
        if m.phase == "stimulus":
            spans[(m.index, m.onset)] = (m.condition, m.onset)
    ends = {float(r["onset_stamp"]): float(r["response_stamp"]) for r in rows}
    felt = {"visual": 0.0, "touch": 0.0, "visual+touch": 0.0}
    for (index, onset), (condition, _) in spans.items():
        end = ends.get(onset, onset + 1.0)
        duties = [s.duty.max() for s in watcher.status if onset < s.stamp < end]
        if duties:
            felt[condition] = max(felt[condition], max(duties))
    assert felt["visual"] == 0.0
    assert max(felt["touch"], felt["visual+touch"]) > 0.0

    # the log: one segment, holding every row's answer with its stamp
    logs = sorted(p.name for p in directory.glob("*.mcap"))
    assert logs == ["session-001.mcap"]
    answers = set()
    for record in LogReader(directory / logs[0]).messages({"study/response"}):
        m = decode(record.data, StudyResponse)
        answers.add((m.index, m.response, round(m.stamp, 6)))
    for r in rows:
        assert (int(r["index"]), r["response"], round(float(r["response_stamp"]), 6)) in answers

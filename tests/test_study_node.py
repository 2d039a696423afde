"""The study node in this process with the scene node, on a test bus: keys in the renderer window
answer (1..9), Enter ends a break, a pause interrupts a trial that is then shown again from its
start, a trial unanswered by its time limit is written as timed out, answers to another trial are
ignored, the end closes the gate and stops the motors, and a second study node on the same session
folder is refused while the first runs."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import yaml

from touch4d.bus import Node
from touch4d.bus.testing import collect, running_broker, wait_until
from touch4d.messages import InputEvents, SceneState, Stop, StudyCommand, StudyResponse, StudyTrial
from touch4d.nodes.scene import SceneNode
from touch4d.nodes.study import StudyNode
from touch4d.study.design import load_study
from touch4d.study.plan import plan_session
from touch4d.study.store import SessionError

pytestmark = pytest.mark.timeout(120)

STUDY = {
    "name": "small", "conditions": ["visual", "touch"], "repetitions": 1, "practice": 0, "time_limit_s": 1.0,
    "max_run": 2, "seed": 5,
    "tasks": [{"id": "front", "kind": "front-element", "prompt": "What is in front?", "options": ["face", "vertex"],
               "stimuli": [{"answer": "face", "scene": "config/scenes/hypercube-face.yaml"},
                           {"answer": "vertex", "scene": "config/scenes/hypercube-vertex.yaml"}]}],
}


def test_keys_pause_breaks_timeouts_and_the_end(tmp_path):
    study_file = tmp_path / "small.yaml"
    study_file.write_text(yaml.safe_dump(STUDY))
    plan = plan_session(load_study(study_file), "P01")
    with running_broker() as bus:
        probe = Node("probe", bus=bus, heartbeat=False)
        trials = collect(probe, "study/trial", StudyTrial)
        stops = collect(probe, "safety/stop", Stop)
        scenes = collect(probe, "scene/state", SceneState)
        keys = probe.create_publisher("ui/input", InputEvents)
        answers = probe.create_publisher("study/response", StudyResponse)
        commands = probe.create_publisher("study/command", StudyCommand)
        scene = SceneNode(params={"spin": {}, "buttons": {}}, bus=bus, heartbeat=False)
        study = StudyNode(params={"study": str(study_file), "participant": "P01", "out": str(tmp_path),
                                  "iti_s": 0.05}, bus=bus, heartbeat=False)
        nodes = (probe, scene, study)

        def spin_until(predicate, timeout=20.0):
            def step():
                for n in nodes:
                    n.spin_once(0.005)
                return predicate()
            return wait_until(step, timeout=timeout, interval=0.0)

        def phase(name, index):
            return spin_until(lambda: next((m for m in reversed(trials) if m.phase == name and m.index == index),
                                           None))

        def press(key):
            keys.publish(InputEvents(pressed=[key], mouse=np.zeros(2), mouse_delta=np.zeros(2)))

        try:
            assert phase("break", 0).message.startswith("Ready?")
            press("enter")
            first = phase("stimulus", 0)
            assert first.onset == first.stamp and first.options == plan[0].options   # the onset is its own stamp
            # the trial's scene is shown, its objects named so that no name gives the answer away
            assert [o["name"] for o in scenes[-1].objects] == ["object-1"]
            assert scenes[-1].objects[0]["shape"] == "tesseract"
            press("2")                                                               # the second option
            phase("idle", 1)
            shown = phase("stimulus", 1)
            commands.publish(StudyCommand(command="pause"))
            phase("paused", 1)
            commands.publish(StudyCommand(command="resume"))
            again = spin_until(lambda: next((m for m in reversed(trials) if m.phase == "stimulus" and m.index == 1
                                             and m.onset > shown.onset), None))
            answers.publish(StudyResponse(index=1, response=plan[1].options[0], source="cli"))
            assert phase("break", 2).message.startswith("Break. Next: touch only")   # a new block
            answers.publish(StudyResponse(index=2, response="", source="controller"))  # any answer goes on
            phase("stimulus", 2)
            phase("stimulus", 3)                                                   # 2 timed out after 1 s
            answers.publish(StudyResponse(index=2, response=plan[3].options[0], source="cli"))   # another trial's
            answers.publish(StudyResponse(index=3, response="smell", source="cli"))             # not an option
            answers.publish(StudyResponse(index=3, response=plan[3].options[1], source="cli"))
            done = phase("done", -1)
            spin_until(lambda: stops)
            assert done.message and study.counts["responses_ignored"] == 2 and study.counts["pauses"] == 1
            # one writer per session folder: a second study node on it is refused while the first runs
            with pytest.raises(SessionError, match=f"{tmp_path / 'P01'}: another process writes this session's trials.csv"):
                StudyNode(params={"study": str(study_file), "participant": "P01", "out": str(tmp_path)}, bus=bus,
                          heartbeat=False)
            study.shutdown()
            # run again on the same session: every trial is done, so it ends at once; a clean stop of a
            # session under way closes the gate
            again_node = StudyNode(params={"study": str(study_file), "participant": "P01", "out": str(tmp_path)},
                                   bus=bus, heartbeat=False)
            nodes = (probe, scene, again_node)
            assert again_node.phase == "done" and again_node.remaining == []
            again_node.shutdown()
            other = StudyNode(params={"study": str(study_file), "participant": "P02", "out": str(tmp_path)},
                              bus=bus, heartbeat=False)
            nodes = (probe, scene, other)
            phase("break", 0)
            other.shutdown()
            nodes = (probe, scene)
            assert phase("paused", 0).participant == "P02"
        finally:
            for n in (study, scene, probe):
                n.shutdown()
    with open(tmp_path / "P01" / "trials.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["index"]) for r in rows] == [0, 1, 2, 3]
    assert [r["response"] for r in rows] == [plan[0].options[1], plan[1].options[0], "", plan[3].options[1]]
    assert [r["timed_out"] for r in rows] == ["0", "0", "1", "0"]
    assert float(rows[1]["onset_stamp"]) == pytest.approx(again.onset)      # the showing after the pause
    assert rows[2]["rt_s"] == "" and rows[2]["correct"] == "0"
    assert all(float(r["rt_s"]) > 0 for r in rows if r["timed_out"] == "0")
    assert [(r["condition"], r["stimulus"]) for r in rows] == [(t.condition, t.stimulus) for t in plan]

"""The trial state machine without a bus, on a clock moved by hand: breaks, the scene gate before an
onset, answers timed from the onset, timeouts, pauses that show a trial again, resuming at the first
trial without a row, reloading a lost scene, and the exploration measured from motor samples."""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
import yaml

from touch4d.geometry.scene import parse_scene
from touch4d.schema import parse_yaml
from touch4d.study.design import load_study
from touch4d.study.machine import (RELOAD_PERIOD_S, Announce, Finished, LoadScene, Paused, Phase, Resumed, TrialDone,
                                   TrialMachine)
from touch4d.study.plan import plan_session

STUDY = {
    "name": "small", "conditions": ["visual", "touch"], "repetitions": 1, "practice": 0, "time_limit_s": 2.0,
    "max_run": 2, "seed": 5,
    "tasks": [{"id": "front", "kind": "front-element", "prompt": "What is in front?", "options": ["face", "vertex"],
               "stimuli": [{"answer": "face", "scene": "config/scenes/hypercube-face.yaml"},
                           {"answer": "vertex", "scene": "config/scenes/hypercube-vertex.yaml"}]}],
}
ITI = 0.5
START = 1000.0


class Clock:
    """The one clock, moved by the test."""

    def __init__(self):
        self.now = START

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def study(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(STUDY))
    return load_study(path)


def make(study, done=(), **kw):
    clock = Clock()
    machine = TrialMachine(study, plan_session(study, "P01"), done, participant="P01", clock=clock, iti_s=ITI,
                           threshold=0.05, **kw)
    return machine, clock


def shown(machine) -> None:
    """The scene node shows the scene the machine asked for."""
    machine.scene_shown(parse_scene(parse_yaml(machine.scene_text, "test"), "test").to_message())


def to_stimulus(machine, clock) -> float:
    """From a break or between trials to the next onset; returns it."""
    if machine.phase == Phase.BREAK:
        machine.go_on()
    machine.drain()
    shown(machine)
    clock.now += ITI
    machine.tick()
    onsets = [e for e in machine.drain() if isinstance(e, Announce) and e.stamp]
    assert machine.phase == Phase.STIMULUS and len(onsets) == 1
    return onsets[0].stamp


def test_a_session_runs_breaks_answers_and_timeouts_on_the_clock_it_is_given(study, monkeypatch):
    def no_other_clock():
        raise AssertionError("the machine read a clock other than its own")

    monkeypatch.setattr(time, "time", no_other_clock)
    monkeypatch.setattr(time, "monotonic", no_other_clock)
    machine, clock = make(study)
    plan = machine.plan
    machine.start()
    events = machine.drain()
    assert machine.phase == Phase.BREAK and machine.message.startswith("Ready? First: seeing only")
    # said to a glove's wearer and a controller's holder alike: no glove named
    assert "nothing vibrates" in machine.message and "glove" not in machine.message
    scene = yaml.safe_load([e for e in events if isinstance(e, LoadScene)][0].text)
    assert [o["name"] for o in scene["objects"]] == ["object-1"]       # no name gives the answer away
    assert scene["objects"][0]["shape"] == "tesseract"
    machine.go_on()
    assert machine.drain() == [Announce()]
    shown(machine)
    clock.now += ITI - 0.01
    machine.tick()
    assert machine.phase == Phase.IDLE                                 # the inter-trial interval runs
    clock.now += 0.01
    machine.tick()
    assert machine.phase == Phase.STIMULUS and machine.onset == clock.now
    assert machine.drain() == [Announce(stamp=clock.now)]              # the onset is the message's stamp
    onset = machine.onset
    # answers to another trial, not an option, or from before the onset are ignored
    assert not machine.respond(plan[1].index, plan[0].options[0], onset + 0.1)
    assert not machine.respond(0, "smell", onset + 0.1)
    assert not machine.respond(0, plan[0].options[0], onset - 0.1)
    assert machine.counts["responses_ignored"] == 3
    answer = machine.key("2", onset + 1.25)
    assert answer.response == plan[0].options[1] and answer.source == "keyboard"
    done = [e for e in machine.drain() if isinstance(e, TrialDone)]
    assert len(done) == 1 and done[0].response == plan[0].options[1]
    row = done[0].row
    assert row["rt_s"] == pytest.approx(1.25) and row["onset_stamp"] == onset and row["index"] == 0
    assert row["correct"] == (plan[0].options[1] == plan[0].answer)
    assert machine.phase == Phase.IDLE and machine.current == plan[1]
    # trial 1 is not answered: it times out at its limit, measured from its onset
    onset = to_stimulus(machine, clock)
    clock.now = onset + plan[1].time_limit_s - 0.01
    machine.tick()
    assert machine.phase == Phase.STIMULUS
    clock.now = onset + plan[1].time_limit_s
    machine.tick()
    done = [e for e in machine.drain() if isinstance(e, TrialDone)]
    assert done[0].response is None and done[0].row["timed_out"] and np.isnan(done[0].row["rt_s"])
    assert machine.counts["timed_out"] == 1
    # a new block opens with a break that names its condition; any answer to its trial ends it
    assert machine.phase == Phase.BREAK and machine.message.startswith("Break. Next: touch only")
    assert machine.respond(plan[2].index, "", clock.now)
    assert machine.phase == Phase.IDLE
    for trial in plan[2:]:
        onset = to_stimulus(machine, clock)
        assert machine.respond(trial.index, trial.answer, onset + 0.5)
    events = machine.drain()
    assert machine.phase == Phase.DONE and Finished() in events
    assert machine.trial_message().index == -1 and machine.trial_message().phase == "done"


def test_a_pause_shows_the_interrupted_trial_again_from_its_start(study):
    machine, clock = make(study)
    machine.start()
    first = to_stimulus(machine, clock)
    clock.now += 0.3
    machine.command("pause")
    assert machine.phase == Phase.PAUSED and machine.drain()[0] == Paused("study/command pause", interrupted=True)
    clock.now += 100.0                                  # paused: the time limit does not run
    machine.tick()
    assert machine.phase == Phase.PAUSED and not machine.drain()
    assert not machine.respond(0, machine.plan[0].answer, clock.now)     # nor do answers count
    machine.key("f9", clock.now)                          # the pause key toggles
    assert isinstance(machine.drain()[0], Resumed) and machine.phase == Phase.IDLE
    again = to_stimulus(machine, clock)
    assert machine.current.index == 0 and again > first
    machine.respond(0, machine.plan[0].answer, again + 2.0 - 1e-9)
    row = [e for e in machine.drain() if isinstance(e, TrialDone)][0].row
    assert row["onset_stamp"] == again and row["rt_s"] == pytest.approx(2.0 - 1e-9)
    assert machine.counts["pauses"] == 1


def test_a_pause_in_a_break_resumes_into_that_break(study):
    machine, clock = make(study)
    machine.start()
    assert machine.phase == Phase.BREAK
    ready = machine.message                              # the block's first condition, said before its trials
    machine.drain()
    machine.command("pause")
    assert machine.drain()[0] == Paused("study/command pause", interrupted=False)
    machine.command("resume")
    assert machine.phase == Phase.BREAK and machine.message == ready
    shown(machine)
    clock.now += 10 * ITI
    machine.tick()
    assert machine.phase == Phase.BREAK                  # no stimulus until the participant goes on
    to_stimulus(machine, clock)


def test_a_resumed_session_starts_at_the_first_trial_without_a_row_and_a_complete_one_ends_at_once(study):
    machine, clock = make(study, done={0, 1})
    machine.start()
    assert machine.current.index == 2 and machine.phase == Phase.BREAK      # block 1's first trial
    machine, clock = make(study, done={0})
    machine.start()
    assert machine.current.index == 1 and machine.phase == Phase.IDLE      # mid-block: no break
    machine, clock = make(study, done={0, 1, 2, 3})
    machine.start()
    assert machine.phase == Phase.DONE and Finished() in machine.drain()
    machine.pause(True, "late")
    assert machine.phase == Phase.DONE


def test_a_lost_scene_is_sent_again_and_a_timed_break_ends_by_itself(study):
    machine, clock = make(study, break_s=3.0)
    machine.start()
    first = [e for e in machine.drain() if isinstance(e, LoadScene)]
    assert len(first) == 1
    clock.now += RELOAD_PERIOD_S
    machine.tick()
    again = [e for e in machine.drain() if isinstance(e, LoadScene)]
    assert again == first and machine.counts["scene_loads"] == 2
    clock.now += 3.0
    machine.tick()
    assert machine.phase == Phase.IDLE                 # the break ended after break_s
    clock.now += 10.0
    machine.tick()
    assert machine.phase == Phase.IDLE                 # never an onset before the scene node shows it


def test_exploration_counts_what_the_glove_delivered_in_the_trial_window(study):
    machine, clock = make(study)
    machine.start()
    plan = machine.plan
    motors = 30
    # block 0 is visual: motors held off, nothing felt whatever the tactile node computed
    onset = to_stimulus(machine, clock)
    machine.motors(onset + 0.1, np.full(motors, 0.8))
    machine.pose(onset + 0.1, [0.0, 0.0, 0.0], True)
    machine.pose(onset + 0.2, [0.3, 0.4, 0.0], True)
    machine.respond(0, plan[0].answer, onset + 1.0)
    row = [e for e in machine.drain() if isinstance(e, TrialDone)][0].row
    assert row["time_touching_s"] == 0.0 and row["mean_intensity"] == 0.0 and row["path_length"] == pytest.approx(0.5)
    onset = to_stimulus(machine, clock)
    machine.respond(1, plan[1].answer, onset + 0.2)
    machine.respond(2, "", clock.now)                     # ends the break before block 1 (touch)
    onset = to_stimulus(machine, clock)
    assert plan[2].condition == "touch"
    machine.motors(onset + 0.0, np.full(motors, 0.5))    # felt for 0.25 s, then below the threshold
    machine.motors(onset + 0.25, np.full(motors, 0.01))
    machine.respond(2, plan[2].answer, onset + 1.0)
    row = [e for e in machine.drain() if isinstance(e, TrialDone)][0].row
    assert row["time_touching_s"] == pytest.approx(0.25)
    assert row["mean_intensity"] == pytest.approx((0.25 * 0.5 + 0.75 * 0.01) / 1.0)
    assert json.loads(row["transform"]) == [list(p) for p in plan[2].transform]


def test_next_check_is_the_next_deadline_on_the_machines_clock(study):
    """What a runner waits for instead of polling: the end of the inter-trial interval once the scene is
    shown, the time limit from the onset, a scene sent again while missing; nothing while paused."""
    import math
    machine, clock = make(study)
    assert machine.next_check() == math.inf              # not started
    machine.start()
    machine.drain()
    assert machine.next_check() == START + RELOAD_PERIOD_S     # its scene not shown yet: sent again then
    if machine.phase == Phase.BREAK:
        shown(machine)
        assert machine.next_check() == math.inf          # a break without break_s waits for the participant
        machine.go_on()
        machine.drain()
    shown(machine)
    assert machine.phase == Phase.IDLE and machine.next_check() == pytest.approx(clock.now + ITI)
    clock.now += ITI - 0.01
    machine.tick()
    assert machine.phase == Phase.IDLE                   # a check before the deadline does nothing
    clock.now += 0.01
    machine.tick()
    assert machine.phase == Phase.STIMULUS and machine.next_check() == pytest.approx(clock.now + STUDY["time_limit_s"])
    machine.pause(True, "test")
    assert machine.next_check() == math.inf

"""A study in the WebXR node's logic and the scene node's, without a bus: the frame tells pages the
question and whether objects are drawn, controller buttons and page buttons answer (stamped on this
machine's clock), the re-centre button answers instead of re-centring during a trial, and a trial's
scene arrives as scene-file text."""
import json
from pathlib import Path

import pytest
import yaml

from touch4d.errors import ConfigError
from touch4d.geometry.scene import load_scene
from touch4d.messages import StudyTrial
from touch4d.render.hud import study_lines
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import Placement, load_calibration
from touch4d.tracking.scene_control import SceneControl
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.protocol import PageError, parse_page_message, unpack_frame

REPO = Path(__file__).resolve().parents[1]


def trial(phase="stimulus", condition="touch", index=3, options=("face", "edge", "vertex")):
    return StudyTrial(study="s", participant="P01", phase=phase, index=index, total=9, condition=condition,
                      task="front", kind="front-element", stimulus="face", prompt="What is in front?",
                      options=list(options), time_limit_s=10.0, message="Break." if phase == "break" else "")


class Rig:
    def __init__(self):
        self.published, self.saved = [], []
        self.t = 1000.0
        self.bridge = WebBridge(BridgeConfig(tracker=True), load_glove(),
                                load_calibration(REPO / "config/calibration.yaml", "hand_in_grip"),
                                Placement(0.5, 0.3), publish=lambda topic, msg: self.published.append((topic, msg)),
                                broadcast=lambda data, latest: None, send=lambda conn, data: None,
                                save_calibration=self.saved.append, now=lambda: self.t)
        self.bridge.connected(1)

    def input(self, buttons=(), page_time=None, left=()):
        sources = [{"handedness": "right", "grip": [0.0, 1.2, -0.45, 0, 0, 0, 1], "trigger": 0.0,
                    "buttons": list(buttons), "joints": None},
                   {"handedness": "left", "grip": None, "trigger": 0.0, "buttons": list(left), "joints": None}]
        self.bridge.page_message(1, json.dumps({"type": "input", "time": 1000.0 * (page_time or self.t),
                                                "tracking": True, "head": [0, 1.6, 0, 0, 0, 0, 1],
                                                "sources": sources}), self.t)

    def answers(self):
        return [msg for topic, msg in self.published if topic == "study/response"]


def test_the_frame_carries_the_question_and_hides_objects_in_touch_trials():
    rig = Rig()
    rig.bridge.on_scene(load_scene(REPO / "config/scenes/hypercube.yaml").to_message())
    header, _ = unpack_frame(rig.bridge.frame())
    assert header["draw_objects"] is True and header["study"] is None          # no study: as always
    rig.bridge.on_trial(trial(condition="touch"))
    header, _ = unpack_frame(rig.bridge.frame())
    assert header["draw_objects"] is False
    assert header["study"]["prompt"] == "What is in front?" and header["study"]["options"] == ["face", "edge", "vertex"]
    assert header["study"]["buttons"] == ["a", "b", "thumbstick"]
    # the page shows the desktop's lines, with the controller's buttons for the keys
    assert header["study"]["lines"] == ["Trial 4 of 9", "What is in front?", "A: face   B: edge   stick: vertex"]
    assert study_lines(trial()) == ["Trial 4 of 9", "What is in front?", "1: face   2: edge   3: vertex"]
    assert study_lines(trial(phase="break")) == ["Break."] and study_lines(trial(phase="idle")) == []
    assert rig.bridge.frame() is None                                        # a repeat of the same trial: nothing new
    rig.bridge.on_trial(trial(condition="visual", index=4))
    assert unpack_frame(rig.bridge.frame())[0]["draw_objects"] is True
    rig.bridge.on_trial(trial(phase="idle", condition="visual", index=5))
    assert unpack_frame(rig.bridge.frame())[0]["draw_objects"] is False      # between trials: nothing


def test_controller_buttons_answer_once_per_press_with_the_page_clock_and_do_not_recentre():
    rig = Rig()
    rig.input()                                  # the page's clock meets this machine's: no offset
    rig.bridge.on_trial(trial())
    rig.t += 0.5
    rig.input(buttons=["b"], page_time=rig.t - 0.004)   # pressed 4 ms before it arrived
    rig.t += 0.01
    rig.input(buttons=["b"])                     # still held: no second answer
    rig.input(buttons=[], left=["a"])            # the other controller's A: option 1, and no re-centre
    answers = rig.answers()
    assert [(a.index, a.response, a.source) for a in answers] == [(3, "edge", "controller"), (3, "face", "controller")]
    assert answers[0].stamp == pytest.approx(1000.5 - 0.004, abs=1e-6)
    assert rig.saved == [] and rig.bridge.counts["recentred"] == 0
    rig.bridge.on_trial(trial(phase="idle", index=4))
    rig.input(buttons=["a"])                     # between trials A re-centres as always
    assert rig.bridge.counts["recentred"] == 1 and len(rig.answers()) == 2
    rig.input()
    rig.bridge.on_trial(trial(phase="break", index=4))
    rig.input(buttons=["thumbstick"])            # any answer button ends a break
    assert (rig.answers()[-1].index, rig.answers()[-1].response) == (4, "")


def test_a_page_button_answers_and_bad_responses_are_dropped():
    rig = Rig()
    rig.bridge.on_trial(trial())
    rig.bridge.page_message(1, json.dumps({"type": "response", "index": 3, "option": "vertex", "time": 1e6 * 1.0}),
                            rig.t)
    assert [(a.index, a.response, a.source) for a in rig.answers()] == [(3, "vertex", "page")]
    for bad in ({"index": -1, "option": "x"}, {"index": 1.5, "option": "x"}, {"index": 1, "option": 7},
                {"index": 1, "option": "x" * 65}, {"index": 1}):
        with pytest.raises(PageError):
            parse_page_message(json.dumps({"type": "response", "time": 1.0, **bad}))
    rig.bridge.page_message(1, json.dumps({"type": "response", "index": True, "option": "x", "time": 1.0}), rig.t)
    assert rig.bridge.counts["page_malformed"] == 1 and len(rig.answers()) == 1


def test_the_scene_node_loads_a_scene_given_as_text_and_keeps_its_scene_on_a_bad_one():
    control = SceneControl(load_scene(REPO / "config/scenes/hypercube.yaml"),
                           load_calibration(REPO / "config/calibration.yaml"))
    text = (REPO / "config/scenes/hypercube-vertex.yaml").read_text()
    revision = control.scene.revision
    assert control.command("load", text)
    loaded = control.message()
    expected = load_scene(REPO / "config/scenes/hypercube-vertex.yaml").to_message()
    assert loaded.revision == revision + 1
    assert [o["orientation"].tolist() for o in loaded.objects] == [o["orientation"].tolist() for o in expected.objects]
    assert control.command("reset")                                   # reset returns to the loaded scene
    assert control.message().objects[0]["orientation"].tolist() == expected.objects[0]["orientation"].tolist()
    bad = yaml.safe_dump({"objects": [{"shape": "tesseract", "size": -1}]})
    with pytest.raises(ConfigError, match="scene/command load.*size"):
        control.command("load", bad)
    assert control.message().objects[0]["orientation"].tolist() == expected.objects[0]["orientation"].tolist()


def test_a_study_scene_node_turns_nothing_with_the_trigger():
    from touch4d.tracking.scene_control import ControlConfig

    calibration = load_calibration(REPO / "config/calibration.yaml")
    scene = load_scene(REPO / "config/scenes/hypercube.yaml")
    for rotate, turns in (("object", True), ("none", False)):
        control = SceneControl(scene, calibration, ControlConfig(rotate=rotate))
        before = control.message().objects[0]["orientation"].copy()
        for x in (0.0, 0.05, 0.1):                       # the trigger held, the controller moved 10 cm
            control.on_controller([x, 1.2, -0.45], [0, 0, 0, 1], 1.0, [])
        moved = control.message().objects[0]["orientation"]
        assert (not (moved == before).all()) is turns

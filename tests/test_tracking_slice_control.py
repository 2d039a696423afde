"""The view and the slice as the scene node changes them: scene/command view and slice, the controller's
buttons (the desktop's m, k, j keys), and the scene/state they publish."""

from pathlib import Path

import numpy as np
import pytest

from touch4d.geometry.scene import Scene, load_scene
from touch4d.messages import SceneState, decode, encode
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import CONFIG_DIR
from touch4d.tracking.desktop import BUTTON_KEYS
from touch4d.tracking.scene_control import SLICE_STEP, ControlConfig, SceneCommandError, SceneControl


def control(**config):
    scene = load_scene(CONFIG_DIR / "scenes" / "hypercube.yaml")
    return SceneControl(scene, load_calibration(), ControlConfig(**config))


def test_view_command_sets_and_cycles_the_view():
    ctl = control()
    assert ctl.scene.view == "projection"
    assert ctl.command("view", "slice") and ctl.scene.view == "slice"
    assert not ctl.command("view", "slice")                   # no change, no new revision
    assert ctl.command("view") and ctl.scene.view == "both"
    assert ctl.command("view", "next") and ctl.scene.view == "projection"
    with pytest.raises(SceneCommandError, match="projection, slice, both or next"):
        ctl.command("view", "side")


def test_slice_command_moves_the_cut():
    ctl = control()
    assert ctl.scene.slice_w == pytest.approx(1.5)            # the middle of the tesseract's w 0.9 .. 2.1
    revision = ctl.scene.revision
    assert ctl.command("slice", "1.2") and ctl.scene.slice_w == 1.2 and ctl.scene.revision == revision + 1
    assert ctl.command("slice", "up") and ctl.scene.slice_w == pytest.approx(1.2 + SLICE_STEP)
    assert ctl.command("slice", "down 0.5") and ctl.scene.slice_w == pytest.approx(0.7 + SLICE_STEP)
    for bad in ("", "deep", "nan", "up x", "1 2"):
        with pytest.raises(SceneCommandError, match="where to cut"):
            ctl.command("slice", bad)


def test_buttons_and_keys_switch_the_view_and_step_the_slice():
    ctl = control()
    c = ctl.scene.slice_w
    for key, view, w in (("m", "slice", c), ("k", "slice", c + SLICE_STEP), ("j", "slice", c), ("m", "both", c)):
        ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, [BUTTON_KEYS[key]])
        ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, [])     # released: the next press counts
        assert ctl.scene.view == view and ctl.scene.slice_w == pytest.approx(w), key


def test_the_view_travels_in_scene_state_and_old_messages_read_as_projection():
    ctl = control()
    ctl.command("view", "both")
    ctl.command("slice", "1.75")
    msg = decode(encode(ctl.message()), SceneState)
    assert (msg.view, msg.slice_w, msg.slice_touch) == ("both", 1.75, "section")
    scene = Scene.from_message(msg)
    assert (scene.view, scene.slice_w) == ("both", 1.75)
    plain = SceneState(objects=msg.objects, projection="orthographic", eye_distance=3.0)
    assert (plain.view, plain.slice_w) == ("projection", 0.0)


def test_the_thumbstick_pushed_forward_and_back_moves_the_slice():
    from test_web_protocol import input_message, source

    from touch4d.web.protocol import parse_page_message

    msg = parse_page_message(input_message(sources=[source(buttons=["thumbstick-up"])]))
    held = list(msg["sources"][0].buttons)
    ctl = control()
    c = ctl.scene.slice_w
    ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, held)
    assert ctl.scene.slice_w == pytest.approx(c + SLICE_STEP)
    ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, ["thumbstick-down"])
    assert ctl.scene.slice_w == pytest.approx(c)


def test_in_a_study_the_participant_moves_the_slice_and_no_answer_changes_the_scene():
    """A slice condition's solid is explored by moving c (what the model observers do); answering
    never turns, selects or re-views the planned stimulus (a served participant's scene is controlled
    by this launch's scene parameters too: touch4d.web.served)."""
    launch = "launch/study.yaml"
    from touch4d.bus.launchfile import load_launch
    from touch4d.web.bridge import ANSWER_BUTTONS

    params = load_launch(Path(__file__).resolve().parents[1] / launch)["scene"].params
    ctl = control(buttons=params["buttons"], rotate=params["rotate"])
    ctl.command("view", "slice")
    view, c, revision = ctl.scene.view, ctl.scene.slice_w, ctl.scene.revision
    for button in (*ANSWER_BUTTONS, "menu", "grip", "trackpad"):
        ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, [button])
        ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, [])
    assert (ctl.scene.view, ctl.scene.slice_w, ctl.scene.revision) == (view, c, revision)
    ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, ["thumbstick-up"])
    assert ctl.scene.slice_w == pytest.approx(c + SLICE_STEP)
    ctl.on_controller(np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, ["thumbstick-down"])
    assert ctl.scene.slice_w == pytest.approx(c)

"""A study in a real browser (Debian's chromium, a Quest 3 emulated by iwer) against launch/study.yaml
with the WebXR node as the tracker: the page shows each trial's question in the headset, its
controller's buttons answer (and the page's own), and the study node writes those answers, timed from
the onset."""
from __future__ import annotations

import csv
import io

import numpy as np
from PIL import Image

import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, launch_process, wait_until
from touch4d.messages import StudyResponse, StudyTrial
from touch4d.study.design import load_study
from touch4d.study.plan import quick_plan
from touch4d.study.stimuli import trial_scene
from touch4d.web.testing import chromium, enter_vr, headset_page

pytestmark = pytest.mark.timeout(150)

STUDY = "config/studies/paper.yaml"
BUTTONS = ("a-button", "b-button")     # iwer's names of the answer buttons A and B: options 1 and 2
PARTICIPANT = "P03"                    # the third order of the conditions: touch first
BACKGROUND = np.array([0.04, 0.04, 0.06]) * 255


def press(page, watcher, button, until, timeout=20.0):
    """Hold a controller button until `until()` holds (the node saw it), then let it go."""
    page.evaluate(f"xr.controllers.right.updateButtonValue('{button}', 1)")
    try:
        return wait_until(until, timeout=timeout, spin=watcher)
    finally:
        page.evaluate(f"xr.controllers.right.updateButtonValue('{button}', 0)")


def test_two_trials_answered_with_the_controller_in_an_immersive_session(tmp_path):
    port = free_port()
    args = ["launch/study.yaml", "tracker:=webxr", f"tracker.port:={port}", "renderer:=none", "monitor:=none",
            "recorder:=none", f"study.participant:={PARTICIPANT}", f"study.out:={tmp_path}", "study.quick:=true",
            "study.iti_s:=0.2"]
    study = load_study(STUDY)
    plan = quick_plan(study, PARTICIPANT)
    assert [t.condition for t in plan[:3]] == ["touch"] * 3        # this participant starts touching
    with launch_process(args) as run, chromium() as browser:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        watcher = Node("browser-study-test", bus=bus, heartbeat=False)
        try:
            trials = collect(watcher, "study/trial", StudyTrial, latest_only=True)
            responses = collect(watcher, "study/response", StudyResponse)
            page = headset_page(browser, f"http://127.0.0.1:{port}/", 320, 180)
            enter_vr(page)
            page.evaluate("xr.position.set(0, 1.5, 0.8)")     # looking away: cheap software frames
            page.evaluate("xr.quaternion.set(0, 1, 0, 0)")
            # the session starts with a break ("Ready?"): shown in the headset, any answer button goes on
            page.wait_for_function("touch4d.study && touch4d.study.phase === 'break' && touch4d.panel.length > 0",
                                   timeout=30000)
            press(page, watcher, "a-button", lambda: trials and trials[-1].phase != "break")
            for k, trial in enumerate(plan[:2]):
                page.wait_for_function(f"touch4d.study && touch4d.study.phase === 'stimulus' && "
                                       f"touch4d.study.index === {trial.index}", timeout=30000)
                shown = page.evaluate("[touch4d.panel, touch4d.drawObjects, touch4d.study.options]")
                assert trial.prompt in shown[0] and shown[2] == trial.options
                assert shown[1] == (trial.condition != "touch")    # the page hides objects in touch trials
                if k == 1:
                    # look at the screen (iwer's default pose, from which test_web_browser sees the blue
                    # hypercube): the frame, the hand's cube and the question are drawn, no pixel of the object
                    page.evaluate("xr.position.set(0, 1.6, 0); xr.quaternion.set(0, 0, 0, 1)")
                    frames = page.evaluate("touch4d.xrFrames")
                    page.wait_for_function(f"touch4d.xrFrames > {frames + 5}", timeout=30000)
                    image = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"), dtype=float)
                    page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")
                    color = trial_scene(study, trial).objects[0].color[:3] * 255
                    assert (np.abs(image - BACKGROUND).sum(axis=2) > 30).mean() > 0.01
                    assert (np.abs(image - color).sum(axis=2) < 90).sum() == 0
                choice = (k + 1) % 2                               # B, then A
                answer = press(page, watcher, BUTTONS[choice], lambda: next(
                    (r for r in responses if r.index == trial.index and r.source == "controller" and r.response), None))
                assert answer.response == trial.options[choice]
            # the third with the page's own button (a tap in the headset's browser, a click on a desktop)
            third = plan[2]
            page.wait_for_function(f"touch4d.study && touch4d.study.phase === 'stimulus' && "
                                   f"touch4d.study.index === {third.index}", timeout=30000)
            # (iwer's immersive overlay covers the page: the click is dispatched to the button itself)
            page.locator(f"#study button[data-option='{third.options[-1]}']").dispatch_event("click")
            tapped = wait_until(lambda: next((r for r in responses if r.index == third.index and r.source == "page"),
                                             None), timeout=20, spin=watcher)
            assert tapped.response == third.options[-1]
            rows = wait_until(lambda: _rows(tmp_path / PARTICIPANT / "trials.csv", 3), timeout=20)
        finally:
            watcher.shutdown()
    assert rows[2]["response"] == plan[2].options[-1] and float(rows[2]["rt_s"]) > 0
    for row in rows:   # the arrival on this machine beside the page's stamp: an honest clock, not flagged
        received = float(row["response_received"])
        assert 0 <= received - float(row["response_stamp"]) < 1.0 and row["clock_suspect"] == "0"
    for k, (row, trial) in enumerate(zip(rows, plan[:2])):
        assert int(row["index"]) == trial.index and row["response"] == trial.options[(k + 1) % 2]
        assert row["timed_out"] == "0" and 0 < float(row["rt_s"]) < 30
        assert row["correct"] == ("1" if row["response"] == trial.answer else "0")


def _rows(path, n):
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError:
        return None
    return rows if len(rows) >= n else None

"""The page's own touch (touch4d/web/static/touch.js, run by node.js here) against the Python model
it must equal: eq. 1-3 and the motors' mix (touch4d.tactile.stimulus), the controller's one
actuator's intensity (touch4d.web.haptics.haptic_level), and the controller -> screen transform
(touch4d.tracking.calibration.hand_from_controller), on random cases for the 30-motor glove and the
held controller. The same page and the tactile node in a browser: test_web_touch_browser."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gpu_tactile_cases import quaternion_of
from pagejs import run_page_module
from touch4d.configfile import CONFIG_DIR
from touch4d.tactile import load_glove
from touch4d.tactile.stimulus import stimulus_of_distances
from touch4d.tracking.calibration import Calibration, rotation_from_steps
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.haptics import haptic_level
from touch4d.web.protocol import unpack_frame

GLOVES = {"glove": CONFIG_DIR / "glove.yaml", "controller": CONFIG_DIR / "gloves" / "quest-controller.yaml"}

RUN = """
import { stimulus, level, handFromGrip } from './touch.mjs';
import { readFileSync } from 'node:fs';
const input = JSON.parse(readFileSync(0, 'utf8'));
const model = { ...input.model, weights: Float32Array.from(input.model.weights) };
const out = input.cases.map((l) => {
  const r = stimulus(l.map((v) => (v === null ? NaN : v)), model);
  return { V: Array.from(r.V), h: Array.from(r.h), level: level(r.V) };
});
const hands = input.grips.map((g) => handFromGrip(g, input.calibration));
process.stdout.write(JSON.stringify({ out, hands }));
"""


def run_page_model(tmp_path, payload: dict) -> dict:
    return run_page_module(tmp_path, "touch", RUN, payload)


# a screen turned and off-centre, a hand off the grip and turned on it: every term of the transform counts
CALIBRATION = Calibration(center_m=np.array([0.1, 1.1, -0.5]), screen_rotation=rotation_from_steps([["y", 30], ["x", -10]]),
                          edge_m=0.6, hand_offset_m=np.array([0.01, -0.03, 0.08]),
                          hand_rotation=rotation_from_steps([["y", 90], ["z", 15]]))


def setup_of(glove):
    """The setup frame a page gets from the WebXR node for this glove (what touch.js reads)."""
    bridge = WebBridge(BridgeConfig(tracker=True, touch="page"), glove, CALIBRATION,
                       None, publish=lambda *a: None, broadcast=lambda *a: None, send=lambda *a: None)
    return unpack_frame(bridge.setup_frame())


def random_distances(rng, n):
    """Depths l per sample: some untouched (NaN), some at the nearest depth, the rest behind it."""
    kind = rng.integers(0, 4)
    if kind == 0:
        return np.full(n, np.nan)
    l = rng.uniform(0.5, 0.5 + rng.uniform(0.01, 1.0), n)
    if kind == 1:
        l[rng.random(n) < 0.6] = np.nan
    if kind == 2:
        l[: n // 3] = l.min()
    return l


@pytest.mark.parametrize("glove_name", sorted(GLOVES))
def test_the_pages_model_equals_the_python_model(tmp_path, glove_name):
    glove = load_glove(GLOVES[glove_name])
    header, arrays = setup_of(glove)
    n = len(glove.samples)
    rng = np.random.default_rng(7)
    cases = [random_distances(rng, n) for _ in range(60)]
    calibration = {k: header[k] for k in ("screen_center", "screen_rotation", "screen_edge", "hand_offset",
                                          "hand_rotation")}
    grips = [[*rng.uniform(-0.5, 0.5, 2), rng.uniform(0.8, 1.6), *quaternion_of(rng.uniform(-math.pi, math.pi, 3))]
             for _ in range(20)]
    model = {"alpha": header["alpha"], "beta": header["beta"], "gamma": header["gamma"],
             "weights": arrays["motor_weights"].ravel().tolist(), "motors": len(header["motor_names"])}
    got = run_page_model(tmp_path, {"model": model, "calibration": calibration, "grips": grips,
                                    "cases": [[None if math.isnan(v) else float(v) for v in l] for l in cases]})
    touching = 0
    for l, page in zip(cases, got["out"]):
        touched = np.isfinite(l)
        st = stimulus_of_distances(glove, np.zeros((n, 3)), touched, l, np.where(touched, 0, -1))
        np.testing.assert_allclose(page["h"], st.h, atol=1e-6)
        np.testing.assert_allclose(page["V"], st.V, atol=1e-5)     # the weights travel as float32
        assert abs(page["level"] - haptic_level(st.V, True)) < 1e-5
        touching += st.V.max() > 0.05
    assert touching >= 20
    cal = CALIBRATION
    for grip, hand in zip(grips, got["hands"]):
        position, orientation = cal.hand_from_controller(grip[:3], grip[3:])
        np.testing.assert_allclose(hand["position"], position, atol=1e-9)
        q = np.asarray(hand["orientation"])
        assert min(np.abs(q - orientation).max(), np.abs(q + orientation).max()) < 1e-9


def test_the_setup_frame_carries_the_model_and_the_hand_on_the_grip():
    glove = load_glove(GLOVES["controller"])
    header, arrays = setup_of(glove)
    assert header["touch"] == "page" and "tactile.frag" in header["shaders"]
    assert (header["alpha"], header["beta"], header["gamma"]) == (glove.alpha, glove.beta, glove.gamma)
    assert arrays["motor_weights"].shape == (1, len(glove.samples))
    np.testing.assert_allclose(arrays["motor_weights"], glove.motor_weights, rtol=1e-6)
    one_hot = setup_of(load_glove(GLOVES["glove"]))[1]["motor_weights"]
    assert np.array_equal(one_hot.sum(axis=1), np.ones(len(one_hot))) and set(np.unique(one_hot)) == {0.0, 1.0}


# ---- the node's side of touch: page (touch4d.web.bridge), without a browser ------------------------

def page_rig(glove_name="controller", **config):
    """A bridge with touch: page and a page (conn 1) that drives the hand; its published messages."""
    published = []
    clock = [1000.0]
    glove = load_glove(GLOVES[glove_name])
    bridge = WebBridge(BridgeConfig(tracker=True, touch="page", **config), glove, CALIBRATION, None,
                       publish=lambda topic, msg: published.append((topic, msg)), broadcast=lambda *a: None,
                       send=lambda *a: None, now=lambda: clock[0])
    bridge.connected(1)
    return bridge, published, clock, glove


def send_input(bridge, clock, page_ms, played=None, grip=(0.1, 1.1, -0.5, 0, 0, 0, 1), tracking=True):
    msg = {"type": "input", "time": page_ms, "tracking": tracking, "head": None,
           "sources": [{"handedness": "right", "grip": list(grip) if grip else None, "trigger": 0.0, "buttons": [],
                        "joints": None}]}
    if played is not None:
        msg["played"] = played
    bridge.page_message(1, json.dumps(msg), clock[0])


def motors_of(published):
    return [m for topic, m in published if topic == "tactile/motors"]


def test_what_the_page_played_goes_out_on_tactile_motors_stamped_with_its_pose():
    bridge, published, clock, glove = page_rig()
    send_input(bridge, clock, 5000.0)                       # the first pose: nothing played yet
    assert motors_of(published) == []
    clock[0] += 0.014
    send_input(bridge, clock, 5014.0, {"time": 5000.0, "intensity": [0.625]})
    (motors,) = motors_of(published)
    assert motors.names == glove.motor_names and motors.intensity.tolist() == [0.625]
    # the played pose's time on this machine's clock: 14 ms before this input's stamp
    assert abs(motors.source_stamp - (1000.014 - 0.014)) < 1e-6


def test_the_page_touch_is_published_0_when_the_study_holds_it_off_the_hand_leaves_or_no_page_tracks():
    from touch4d.messages import StudyTrial
    bridge, published, clock, glove = page_rig()
    send_input(bridge, clock, 5000.0)
    bridge.on_trial(StudyTrial(study="s", participant="P01", phase="stimulus", index=0, total=1, condition="visual",
                               task="front", kind="front-element", stimulus="face", prompt="?", options=["a", "b"],
                               onset=clock[0], time_limit_s=60.0))
    send_input(bridge, clock, 5014.0, {"time": 5000.0, "intensity": [0.9]})
    assert motors_of(published)[-1].intensity.tolist() == [0.0]
    header = frame_fields(bridge)
    assert header["touch_on"] is False and header["draw_objects"] is True     # the page's gate: no touch
    published.clear()
    send_input(bridge, clock, 5028.0, tracking=False)      # the page hid: no hand
    assert motors_of(published)[-1].intensity.tolist() == [0.0]
    published.clear()
    clock[0] += 1.0                                         # silent: no page tracks
    bridge.tick()
    assert motors_of(published) and motors_of(published)[-1].intensity.tolist() == [0.0]


def test_a_played_touch_of_the_wrong_size_is_counted_and_not_published():
    bridge, published, clock, glove = page_rig("glove")
    send_input(bridge, clock, 5000.0, {"time": 4990.0, "intensity": [0.5]})
    assert motors_of(published) == [] and bridge.counts["page_malformed"] == 1


def frame_fields(bridge):
    """The fields of the frame the bridge makes now (something changed since the last)."""
    return unpack_frame(bridge.frame())[0]


def test_touch_page_needs_the_tracker_and_its_controller(tmp_path):
    from test_web_secrets import start_error

    for params in ({"touch": "page"}, {"touch": "page", "tracker": True, "hand_source": "hand"}):
        out = start_error(params)
        assert "touch" in out and "hand_source: controller" in out, out

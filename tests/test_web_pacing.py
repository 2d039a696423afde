"""The page's frame pacing (touch4d/web/static/pacing.js, run by node.js here as test_web_touch runs
touch.js): synthetic XR frame times whose right answer is known. On time, with a dropped frame now
and then: never lowered. Late (45 Hz on a 72 Hz display): one step down the ladder within 1-2 s,
then the next. A load only a lower level holds: the higher level retried ever more rarely (no
upward flapping). Load gone: back up to the node's setting. The setting reaches the page in the
setup frame (framebuffer_scale, foveation, pacing); the browser side: test_web_pacing_browser."""
from __future__ import annotations

import re

import pytest

from pagejs import run_page_module
from test_web_touch import CALIBRATION
from touch4d.bus.params import check_params
from touch4d.errors import ConfigError
from touch4d.nodes.webxr import WebXRNode
from touch4d.tactile import load_glove
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.protocol import parse_page_message, unpack_frame, PageError

# Each scenario: phases of frames, each {"ms": how long, "interval": [ms per frame at level 0, 1, ...]
# (the last for every level below), "drop": every n-th frame takes two intervals, "gap": a pause
# before it, "hz": the display's nominal rate (null: not said)}; the JS below plays them through a
# Pacing, its level choosing the next interval (a closed loop), and returns every change.
RUN = """
import { Pacing } from './pacing.mjs';
import { readFileSync } from 'node:fs';
const input = JSON.parse(readFileSync(0, 'utf8'));
const out = input.scenarios.map(({ scale, foveation, adaptive, phases }) => {
  const p = new Pacing(scale, foveation, adaptive);
  let t = 1000, frames = 0;
  const changes = [], levels = [];
  for (const phase of phases) {
    t += phase.gap || 0;
    const end = t + phase.ms;
    while (t < end) {
      const k = Math.min(p.level, phase.interval.length - 1);
      frames++;
      t += phase.interval[k] * (phase.drop && frames % phase.drop === 0 ? 2 : 1);
      levels.push(p.level);
      const step = p.frame(phase.time === 'nan' ? NaN : t, phase.hz === undefined ? null : phase.hz);
      if (step) changes.push({ t: t - 1000, ...step, level: p.level });
    }
  }
  return { changes, levels, state: p.state };
});
process.stdout.write(JSON.stringify(out));
"""

HZ72, HZ45, HZ90 = 1000 / 72, 1000 / 45, 1000 / 90


def run_pacing(tmp_path, scenarios: list[dict]) -> list[dict]:
    scenarios = [{"scale": 1.0, "foveation": 0.5, "adaptive": True, **s} for s in scenarios]
    return run_page_module(tmp_path, "pacing", RUN, {"scenarios": scenarios})


def test_on_time_frames_are_never_lowered(tmp_path):
    steady, dropping, at_90, no_rate = run_pacing(tmp_path, [
        {"phases": [{"ms": 60000, "interval": [HZ72], "hz": 72}]},
        {"phases": [{"ms": 60000, "interval": [HZ72], "drop": 5, "hz": 72}]},        # one frame in 5 dropped
        {"phases": [{"ms": 60000, "interval": [HZ90], "hz": 90}]},
        {"phases": [{"ms": 60000, "interval": [HZ72]}]},                             # 72 Hz assumed
    ])
    for run in (steady, dropping, at_90, no_rate):
        assert run["changes"] == [] and run["state"]["level"] == 0
        assert (run["state"]["scale"], run["state"]["foveation"]) == (1.0, 0.5)
    assert steady["state"]["fps"] == pytest.approx(72, abs=0.5)
    assert at_90["state"]["fps"] == pytest.approx(90, abs=0.5) and at_90["state"]["nominal"] == 90


def test_sustained_45_hz_lowers_one_step_within_two_seconds_and_keeps_stepping_down(tmp_path):
    (late,) = run_pacing(tmp_path, [{"phases": [{"ms": 3000, "interval": [HZ72], "hz": 72},
                                                {"ms": 10000, "interval": [HZ45], "hz": 72}]}])
    changes = late["changes"]
    # the ladder from (1, 0.5): the scale x0.8 down to 0.5, the foveation +0.25 up to 1
    assert [(c["scale"], c["foveation"]) for c in changes] == [(0.8, 0.75), (0.64, 1.0), (0.512, 1.0), (0.5, 1.0)]
    # once most of the last second's intervals are late (the median), within 2 s of the change
    assert 3000 + 500 <= changes[0]["t"] <= 3000 + 2000
    gaps = [b["t"] - a["t"] for a, b in zip(changes, changes[1:])]
    assert all(1000 <= g <= 2000 for g in gaps), gaps
    assert late["state"]["lowered"] == 4 and late["state"]["raised"] == 0
    assert late["state"]["fps"] == pytest.approx(45, abs=0.5)


def test_the_displays_own_rate_decides_what_is_late(tmp_path):
    at_90, at_72 = run_pacing(tmp_path, [{"phases": [{"ms": 5000, "interval": [HZ72], "hz": 90}]},
                                         {"phases": [{"ms": 5000, "interval": [HZ72], "hz": None}]}])
    assert at_90["changes"] and at_90["changes"][0]["t"] <= 2000    # 72 Hz on a 90 Hz display is late
    assert at_72["changes"] == []


def test_a_load_only_a_lower_level_holds_is_retried_ever_more_rarely(tmp_path):
    (loop,) = run_pacing(tmp_path, [{"phases": [{"ms": 180000, "interval": [HZ45, HZ72], "hz": 72}]}])
    ups = [c["t"] for c in loop["changes"] if c["level"] == 0]
    downs = [c["t"] for c in loop["changes"] if c["level"] == 1]
    assert downs[0] <= 2000 and 2 <= len(ups) <= 5, (ups, downs)
    waits = [b - a for a, b in zip(ups, ups[1:])]
    assert all(b >= 1.8 * a for a, b in zip(waits, waits[1:])), waits       # each retry waits about twice as long
    assert all(any(0 < d - u <= 2000 for d in downs) for u in ups)           # every retry is undone within 2 s
    late = loop["levels"].count(0) / len(loop["levels"])
    assert late < 0.06, f"{late:.1%} of the frames at the level that runs late"
    assert loop["changes"][-1]["level"] == 1


def test_when_the_load_goes_the_page_comes_back_to_the_nodes_setting_without_lowering_again(tmp_path):
    (back,) = run_pacing(tmp_path, [{"scale": 0.9, "foveation": 0.0, "phases": [
        {"ms": 5000, "interval": [HZ45], "hz": 72}, {"ms": 45000, "interval": [HZ72], "hz": 72}]}])
    changes = back["changes"]
    down = [c for c in changes if c["t"] <= 5100]
    up = [c for c in changes if c["t"] > 5100]
    assert len(down) >= 3 and [c["level"] for c in down] == list(range(1, len(down) + 1))
    assert [c["level"] for c in up] == list(range(len(down) - 1, -1, -1))      # up one step at a time, never down
    assert (up[-1]["scale"], up[-1]["foveation"]) == (0.9, 0.0) and up[-1]["t"] <= 5000 + 40000
    assert (down[0]["scale"], down[0]["foveation"]) == (0.72, 0.25)


def test_a_pause_is_not_a_late_frame_and_pacing_off_only_measures(tmp_path):
    paused, off, nonsense = run_pacing(tmp_path, [
        {"phases": [{"ms": 2000, "interval": [HZ72], "hz": 72}, {"gap": 3000, "ms": 5000, "interval": [HZ72],
                                                                  "hz": 72}]},
        {"adaptive": False, "phases": [{"ms": 10000, "interval": [HZ45], "hz": 72}]},
        {"phases": [{"ms": 3000, "interval": [HZ45], "hz": 72, "time": "nan"},
                    {"ms": 3000, "interval": [HZ72], "hz": -5}]},
    ])
    assert paused["changes"] == []
    assert off["changes"] == [] and off["state"]["scale"] == 1.0 and off["state"]["fps"] == pytest.approx(45, abs=0.5)
    assert nonsense["changes"] == [] and nonsense["state"]["nominal"] == 72


def test_the_nodes_settings_reach_the_setup_frame_and_the_pages_scale_its_heartbeat():
    glove = load_glove()
    config = BridgeConfig(tracker=True, framebuffer_scale=0.7, foveation=0.2, pacing=False)
    bridge = WebBridge(config, glove, CALIBRATION, None, publish=lambda *a: None, broadcast=lambda *a: None,
                       send=lambda *a: None, now=lambda: 0.0)
    header, _ = unpack_frame(bridge.setup_frame())
    assert (header["framebuffer_scale"], header["foveation"], header["pacing"]) == (0.7, 0.2, False)
    bridge.connected(1)
    bridge.page_message(1, '{"type": "stats", "fps": 71.5, "scale": 0.56, "foveation": 0.7}', 0.0)
    assert (bridge.page_fps(), bridge.page_scale()) == (71.5, 0.56) and bridge.counts["page_malformed"] == 0
    bridge.page_message(1, '{"type": "stats", "fps": 60}', 0.0)              # left the headset: no layer
    assert (bridge.page_fps(), bridge.page_scale()) == (60, 0.0)
    for bad in ('{"type": "stats", "fps": 60, "scale": 0}', '{"type": "stats", "fps": 60, "scale": 1.5}',
                '{"type": "stats", "fps": 60, "foveation": -0.1}', '{"type": "stats", "fps": 60, "scale": "low"}'):
        with pytest.raises(PageError):
            parse_page_message(bad)


@pytest.mark.parametrize("key,value,expected", [
    ("framebuffer_scale", 0.0, "> 0 and <= 1"), ("framebuffer_scale", 1.5, "> 0 and <= 1"),
    ("foveation", -0.1, ">= 0 and <= 1"), ("foveation", 2.0, ">= 0 and <= 1"),
    ("pacing", "sometimes", "true or false")])
def test_a_wrong_setting_is_refused_by_name(key, value, expected):
    def error(name, expected, got):
        return ConfigError("launch.yaml", f"nodes.tracker.params.{name}", expected, got=got)

    with pytest.raises(ConfigError, match=f"params.{key}': expected .*{re.escape(expected)} for parameter '{key}'"):
        check_params(WebXRNode.PARAMS, {key: value}, error, "webxr")

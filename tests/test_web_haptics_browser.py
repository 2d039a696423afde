"""The held controller as the glove, in a real browser (Debian's chromium, a Quest 3 emulated by
iwer) against launch/quest.yaml: the page pulses the glove hand's controller with the node's
intensity while the hand touches, never in a visual trial, and 0 within 100 ms of being hidden; a
controller without an actuator is said so on the page and in the node's heartbeat; a desktop page
plays it on a gamepad with `dual-rumble`.

iwer's actuator keeps only its last pulse: the test wraps `pulse` to record every one (here only,
never in the page)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, launch_process, wait_until
from touch4d.messages import Heartbeat, MotorCommand, StudyTrial
from touch4d.web.testing import chromium, context_options, enter_vr, headset_page

pytestmark = pytest.mark.timeout(150)

CENTER = (0.0, 1.2, -0.45)          # the screen's centre (config/calibration.yaml): inside the front cell
EDGE = (0.15, 1.2, -0.45)           # on the front cell's side (x = 0.6 units): part of the fist touches
AWAY = (0.6, 1.2, -0.45)            # outside the screen

RECORD_PULSES = """() => {
  window.pulses = [];
  for (const source of touch4d.session.inputSources) {
    const actuator = source.gamepad && source.gamepad.hapticActuators[0];
    if (!actuator) continue;
    const pulse = actuator.pulse.bind(actuator);
    actuator.pulse = (value, duration) => {
      pulses.push([source.handedness, value, duration, performance.timeOrigin + performance.now()]);
      return pulse(value, duration);
    };
  }
}"""


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


@pytest.fixture(scope="module")
def stack():
    port = free_port()
    args = ["launch/quest.yaml", "monitor:=none", f"tracker.port:={port}", "tracker.save_calibration:=false"]
    with launch_process(args) as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        watcher = Node("haptics-test", bus=bus, heartbeat=False)
        try:
            yield {"url": f"http://127.0.0.1:{port}/", "watcher": watcher,
                   "motors": collect(watcher, "tactile/motors", MotorCommand),
                   "beats": collect(watcher, "node/heartbeat", Heartbeat)}
        finally:
            watcher.shutdown()


def controller_page(browser, url):
    """A headset page looking away from the screen (cheap software frames), its pulses recorded."""
    page = headset_page(browser, url, 320, 180)
    enter_vr(page)
    page.evaluate("xr.position.set(0, 1.5, 0.8)")
    page.evaluate("xr.quaternion.set(0, 1, 0, 0)")
    page.evaluate(RECORD_PULSES)
    return page


def move(page, position):
    page.evaluate("xr.controllers.right.position.set({}, {}, {})".format(*position))


def pulses(page, since=0.0):
    """(hand, value, duration ms, page time s) of every pulse from `since` (page clock, s)."""
    return [(h, v, d, t / 1000) for h, v, d, t in page.evaluate("pulses") if t / 1000 >= since]


def page_now(page) -> float:
    return page.evaluate("(performance.timeOrigin + performance.now()) / 1000")


def wait_pulse(page, watcher, predicate, since=0.0, timeout=20.0):
    return wait_until(lambda: [p for p in pulses(page, since) if predicate(p[1])], timeout=timeout, spin=watcher)


def trial(condition):
    return StudyTrial(study="s", participant="P01", phase="stimulus", index=0, total=1, condition=condition,
                      task="front", kind="front-element", stimulus="face", prompt="?", options=["a", "b"],
                      onset=time.time(), time_limit_s=60.0)


def test_touching_pulses_the_glove_hands_controller_with_the_nodes_intensity(browser, stack):
    watcher = stack["watcher"]
    page = controller_page(browser, stack["url"])
    try:
        move(page, AWAY)
        watcher.spin(0.5)
        assert all(v == 0 for _, v, _, _ in pulses(page))
        move(page, CENTER)
        # the front cell is flat along w: every sample at one depth, s = 1, h = 0.5, V = gamma * 0.5 = 1
        full = wait_pulse(page, watcher, lambda v: v > 0.99)
        assert all(abs(v - 1.0) < 1e-4 for _, v, _, _ in full)
        t = page_now(page)
        move(page, EDGE)
        part = wait_pulse(page, watcher, lambda v: 0.1 < v < 0.9, since=t, timeout=60)

        def heard_every_level_played():   # the page may play a command before the watcher has read it
            computed = np.array([float(np.max(m.intensity)) for m in stack["motors"]])
            return all(np.min(np.abs(computed - v)) < 1e-6 for _, v, _, _ in part)

        # what the page played is what the tactile node computed for this pose
        wait_until(heard_every_level_played, timeout=20, spin=watcher)
        played = pulses(page)
        assert {h for h, v, _, _ in played if v > 0} == {"right"}          # the glove hand's controller only
        assert all(10 <= d <= 50 for _, v, d, _ in played if v > 0)       # a little over a frame
        t = page_now(page)          # before the move: the page plays 0 once, on the change
        move(page, AWAY)
        wait_pulse(page, watcher, lambda v: v == 0, since=t)
    finally:
        page.context.close()


def test_hiding_the_page_plays_0_within_100_ms(browser, stack):
    watcher = stack["watcher"]
    page = controller_page(browser, stack["url"])
    try:
        move(page, CENTER)
        wait_pulse(page, watcher, lambda v: v > 0.5)
        t0 = page.evaluate("() => { const t = performance.timeOrigin + performance.now(); "
                           "xr.updateVisibilityState('hidden'); return t / 1000; }")
        zero = wait_pulse(page, watcher, lambda v: v == 0, since=t0, timeout=5)[0]
        assert zero[3] - t0 < 0.1, f"0 played {1000 * (zero[3] - t0):.0f} ms after the page was hidden"
        watcher.spin(0.4)
        assert all(v == 0 for _, v, _, _ in pulses(page, t0))
        page.evaluate("xr.updateVisibilityState('visible')")
        wait_pulse(page, watcher, lambda v: v > 0.5, since=page_now(page))
    finally:
        page.context.close()


def test_a_visual_trial_gives_no_pulse_above_0(browser, stack):
    watcher = stack["watcher"]
    trials = watcher.create_publisher("study/trial", StudyTrial)
    page = controller_page(browser, stack["url"])
    try:
        move(page, CENTER)
        wait_pulse(page, watcher, lambda v: v > 0.5)
        t0 = page_now(page)
        trials.publish(trial("visual"))
        wait_pulse(page, watcher, lambda v: v == 0, since=t0, timeout=5)
        t1 = page_now(page)
        watcher.spin(0.5)
        assert page.evaluate("touch4d.frame.haptic") == 0
        assert all(v == 0 for _, v, _, _ in pulses(page, t1))
        trials.publish(trial("touch"))                  # a touch trial: felt again
        wait_pulse(page, watcher, lambda v: v > 0.5, since=page_now(page))
    finally:
        page.context.close()


def test_a_controller_without_an_actuator_is_said_so_and_nothing_throws(browser, stack):
    watcher, beats = stack["watcher"], stack["beats"]
    page = headset_page(browser, stack["url"], 320, 180)
    try:
        enter_vr(page)
        page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")
        page.evaluate("for (const s of touch4d.session.inputSources) s.gamepad.hapticActuators.length = 0")
        move(page, CENTER)
        page.wait_for_function("touch4d.haptics.output === 'none' && touch4d.frame && touch4d.frame.haptic > 0.5",
                               timeout=20000)
        page.wait_for_function("document.getElementById('status').textContent.includes('no vibration')",
                               timeout=20000)
        assert page.evaluate("touch4d.error") is None
        t = time.time()
        wait_until(lambda: [b for b in beats if b.node == "tracker" and b.stamp > t
                            and b.stats.get("haptics_none", 0) >= 1], timeout=10, spin=watcher)
    finally:
        page.context.close()


GAMEPAD = """
window.effects = [];
const rumble = { playEffect: (type, params) => { effects.push([type, params.strongMagnitude, params.weakMagnitude,
                                                              params.duration]); return Promise.resolve('complete'); } };
navigator.getGamepads = () => [{ index: 0, id: 'test pad', connected: true, vibrationActuator: rumble }];
"""


def test_a_desktop_gamepad_rumbles_with_the_scripted_hands_touch(browser):
    """The demo's scripted hand sweeps over the hypercube; a desktop page (no headset) plays the
    node's intensity on a gamepad (one made here: this machine has none)."""
    port = free_port()
    with launch_process(["launch/demo.yaml", "renderer:=webxr", f"renderer.port:={port}", "motors:=none",
                         "monitor:=none"]) as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        watcher = Node("rumble-test", bus=bus, heartbeat=False)
        beats = collect(watcher, "node/heartbeat", Heartbeat)
        context = browser.new_context(**context_options(320, 180))
        context.add_init_script(GAMEPAD)
        page = context.new_page()
        try:
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_function("effects.some(([type, strong]) => type === 'dual-rumble' && strong > 0.05)",
                                   timeout=60000)
            effects = page.evaluate("effects")
            assert all(t == "dual-rumble" and s == w and 0 <= s <= 1 and 10 <= d <= 50 for t, s, w, d in effects)
            assert page.evaluate("touch4d.haptics.output") == "dual-rumble"
            assert "no vibration" not in page.inner_text("#status")
            wait_until(lambda: [b for b in beats if b.node == "renderer" and b.stats.get("haptics_rumble", 0) >= 1],
                       timeout=15, spin=watcher)
        finally:
            context.close()
            watcher.shutdown()

"""One guard for every haptic output: the fail-safe rules (stop, the study's gate, a stale command, the
watchdog) on a simulated clock, in their order, and the CAN glove and the page's controller each
held to them through the registry of outputs."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.boards.driver import MotorDriver
from touch4d.errors import ConfigError
from touch4d.hapticoutput import (GATE, OUTPUTS, STALE, STOP, WATCHDOG, HapticOutput, OutputGuard, output_class,
                                  register_output)
from touch4d.messages import HandPose, MotorCommand, Stop
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import Placement, load_calibration
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.haptics import PageOutput
from touch4d.web.protocol import unpack_frame

REPO = Path(__file__).resolve().parents[1]
ON = np.array([0.25, 0.75])


def guard(**kw):
    kw = {"watchdog_s": 0.1, "max_age_s": 0.1, "stop_hold_s": 1.0} | kw
    return OutputGuard(2, **kw)


def plays(g, now):
    return g.reason(now) is None and np.array_equal(g.output(now), ON)


def off(g, now):
    return not g.output(now).any()


def test_a_command_plays_until_its_watchdog_and_no_longer():
    g = guard()
    assert g.reason(0.0) == WATCHDOG and off(g, 0.0)          # nothing commanded yet
    g.command(ON, 10.0, age=0.02)
    assert plays(g, 10.0) and plays(g, 10.1)                  # the watchdog's last instant still plays
    assert g.expires(10.05) == pytest.approx(10.1)
    assert g.reason(10.1001) == WATCHDOG and off(g, 10.1001)
    assert g.expires(10.2) == math.inf                        # already off: nothing more by time alone


def test_a_stale_command_turns_off_at_once_and_does_not_feed_the_watchdog():
    g = guard()
    g.command(ON, 10.0, age=0.0)
    g.command(ON, 10.02, age=0.15)                            # older than max_age_s when it came
    assert g.reason(10.02) == STALE and off(g, 10.02)
    assert g.last_command_at == 10.0 and g.counts["stale_command"] == 1
    g.command(ON, 10.03, age=float("nan"))                    # an age that cannot be read: stale
    assert g.reason(10.03) == STALE and g.counts["stale_command"] == 2
    g.command(ON, 10.04, age=None)                            # no stamp: the age check cannot apply
    assert plays(g, 10.04)
    g.command(ON, 10.05, age=-5.0)                            # the sender's clock ahead: used, counted
    assert plays(g, 10.05) and g.counts["command_from_future"] == 1
    unchecked = guard(max_age_s=0.0)                          # 0: the check is off (clocks not synchronised)
    unchecked.command(ON, 10.0, age=30.0)
    assert plays(unchecked, 10.0)


def test_a_closed_gate_holds_the_output_at_0_and_an_open_one_plays_the_held_command_while_fresh():
    g = guard(gate_open=False)
    g.command(ON, 10.0, age=0.01)
    assert g.reason(10.0) == GATE and off(g, 10.0)            # held, not played
    assert g.set_gate(True, 10.05) and plays(g, 10.05)        # 0.06 s old now: plays
    assert not g.set_gate(True, 10.05)                        # no change
    g.set_gate(False, 10.06)
    assert g.reason(10.06) == GATE
    g.command(ON, 10.06, age=0.05)
    g.set_gate(True, 10.12)                                   # 0.11 s old now: dropped, though the watchdog holds
    assert not g.silent(10.12) and off(g, 10.12)


def test_a_stop_holds_everything_off_and_ignores_commands_for_its_hold():
    g = guard()
    g.command(ON, 10.0)
    g.stop(10.01)
    assert g.reason(10.01) == STOP and off(g, 10.01) and g.expires(10.01) == pytest.approx(11.01)
    assert not g.command(ON, 10.5) and g.counts["ignored_during_stop"] == 1
    assert g.reason(10.5) == STOP and off(g, 10.5)
    assert g.reason(11.02) == WATCHDOG                        # the hold over: nothing to play until a command
    assert g.command(ON, 11.02) and plays(g, 11.02)
    latched = guard(stop_hold_s=math.inf)
    latched.stop(10.0)
    assert not latched.command(ON, 1e9) and latched.reason(1e9) == STOP


def test_the_rules_hold_in_their_order_stop_gate_stale_watchdog():
    g = guard()
    g.command(ON, 10.0, age=0.0)
    g.command(ON, 10.01, age=1.0)                             # stale
    g.set_gate(False, 10.01)
    g.stop(10.01)
    assert g.reason(10.02) == STOP
    assert g.reason(11.02) == GATE                            # the stop's hold over, the gate still closed
    g.set_gate(True, 11.02)
    assert g.reason(11.02) == STALE                           # the last command was stale ...
    g.command(ON, 11.03, age=0.0)
    assert plays(g, 11.03)
    assert g.reason(11.2) == WATCHDOG                         # ... and the watchdog is the last word
    assert [g.holds_off(t) for t in (11.03, 11.2)] == [None, None]


# -- the outputs ------------------------------------------------------------------------------------

class Recorder(HapticOutput):
    """A fake actuator: records what its guard lets it play."""

    def __init__(self, motors: int):
        self.guard = OutputGuard(motors, watchdog_s=0.1, stop_hold_s=1.0)
        self.played: list[tuple[float, list]] = []

    def play(self, intensity, now, age=None):
        self.guard.command(intensity, now, age)
        self.played.append((now, self.guard.output(now).tolist()))

    def off(self, now):
        self.guard.silence()
        self.played.append((now, self.guard.output(now).tolist()))


def test_the_registry_names_every_output_and_a_new_one_is_driven_through_its_guard(monkeypatch):
    assert output_class("can") is MotorDriver and output_class("page") is PageOutput
    monkeypatch.setitem(OUTPUTS, "recorder", "touch4d.errors:ConfigError")   # restored after the test
    register_output("recorder", Recorder)
    out = output_class("recorder")(2)
    out.play(ON, 1.0)
    out.guard.stop(1.5)
    out.play(ON, 1.6)
    out.guard.set_gate(False, 3.0)
    out.play(ON, 3.0)
    out.guard.set_gate(True, 3.05)
    out.play(ON, 3.05)
    out.off(3.06)
    assert out.played == [(1.0, [0.25, 0.75]), (1.6, [0.0, 0.0]), (3.0, [0.0, 0.0]), (3.05, [0.25, 0.75]),
                          (3.06, [0.0, 0.0])]
    with pytest.raises(ConfigError, match="key 'output': expected one of can, page, recorder, got 'serial'"):
        output_class("serial")
    monkeypatch.setitem(OUTPUTS, "broken", "touch4d.errors:ConfigError")
    with pytest.raises(ConfigError, match="key 'output': expected a HapticOutput subclass for 'broken'"):
        output_class("broken")


CFG = dataclasses.replace(load_glove_can(REPO / "tests/data/glove_can_test.yaml"),
                          watchdog_s=0.1, command_max_age_s=0.1, stop_hold_s=1.0)


def duty_levels(driver, now):
    return [o.levels for o in driver.outgoing(now, refresh=True, force=True) if o.board]


def test_the_can_glove_obeys_its_guard_gate_included():
    d = MotorDriver(CFG, now=0.0)
    assert isinstance(d, HapticOutput) and isinstance(d.guard, OutputGuard) and d.guard.counts is d.errors
    d.play(np.full(30, 0.8), 1.0, age=0.0)
    assert all(any(levels) for levels in duty_levels(d, 1.0))
    d.gate(False, 1.01)                                       # the study's visual trial: every duty 0 at once
    assert d.guard.reason(1.01) == GATE and not any(map(any, duty_levels(d, 1.01)))
    d.play(np.full(30, 0.8), 1.02, age=0.0)                   # commands keep coming: still 0
    assert not any(map(any, duty_levels(d, 1.02)))
    d.gate(True, 1.03)
    assert all(any(levels) for levels in duty_levels(d, 1.03))
    d.stop(1.04)
    assert d.guard.reason(1.04) == STOP and d.stop_until == pytest.approx(2.04) and d.errors["stops"] == 1
    d.off(3.0)
    assert d.guard.reason(3.0) == WATCHDOG and not any(map(any, duty_levels(d, 3.0)))


class Page:
    """The page's bridge on a hand-set clock, with what it broadcasts and publishes."""

    def __init__(self, **config):
        self.t = 100.0
        self.frames, self.published = [], []
        self.bridge = WebBridge(BridgeConfig(frame_period_s=0.0, **config),
                                load_glove(REPO / "config/gloves/quest-controller.yaml"),
                                load_calibration(REPO / "config/calibration.yaml", "hand_in_grip"), Placement(0.5, 0.3),
                                publish=lambda topic, msg: self.published.append((topic, msg)),
                                broadcast=lambda data, latest: self.frames.append(unpack_frame(data)[0]),
                                send=lambda conn, data: None, now=lambda: self.t)
        self.bridge.on_hand_pose(HandPose(position=np.zeros(3), valid=True))

    def motors(self, value):
        self.bridge.on_motors(MotorCommand(names=["m0"], intensity=np.array([value])))

    def haptic(self):
        self.bridge.tick()
        return self.frames[-1]["haptic"]


def test_the_page_obeys_its_guard_a_stop_included():
    page = Page(stop_hold_s=1.0)
    assert isinstance(page.bridge.output, HapticOutput) and isinstance(page.bridge.output.guard, OutputGuard)
    page.motors(0.5)
    assert page.haptic() == 0.5
    sent, t0 = len(page.frames), page.t
    page.bridge.on_stop(Stop(reason="test", origin="test"))
    stopped = page.frames[sent:]                              # its frame at once: nothing played, no own touch
    assert [(f["haptic"], f["touch_on"]) for f in stopped] == [(0.0, False)]
    assert page.bridge.next_due() == t0 + 1.0                 # the frame that ends the hold is due then
    page.t += 0.03
    page.motors(0.5)                                          # within the hold: ignored
    assert page.haptic() == 0.0 and page.bridge.output.guard.counts["ignored_during_stop"] == 1
    page.t = t0 + 1.0
    page.bridge.tick()
    assert page.frames[-1]["touch_on"] is True                # the hold over: the page's own touch again
    page.motors(0.625)
    assert page.haptic() == 0.625


def test_the_pages_own_touch_is_published_as_0_while_a_stop_holds():
    page = Page(stop_hold_s=1.0, touch="page", tracker=True)
    page.bridge.connected(1, "test")

    def played(page_ms, value):
        source = {"handedness": "right", "grip": [0.1, 1.1, -0.5, 0, 0, 0, 1], "trigger": 0.0, "buttons": [],
                  "joints": None}
        page.bridge.page_message(1, json.dumps({"type": "input", "time": page_ms, "tracking": True, "head": None,
                                                "sources": [source],
                                                "played": {"time": page_ms - 14.0, "intensity": [value]}}), page.t)
        return [m.intensity.tolist() for topic, m in page.published if topic == "tactile/motors"][-1]

    assert played(5000.0, 0.9) == [0.9]
    page.bridge.on_stop(Stop(reason="test", origin="test"))
    page.t += 0.014
    assert played(5014.0, 0.9) == [0.0]                       # what the page played, held off by the stop
    page.t += 1.0                                              # the hold over: what it plays goes out again
    assert played(6014.0, 0.9) == [0.9]


def test_a_stop_on_the_bus_holds_the_page_nodes_output_off():
    """The webxr node hears `safety/stop` (the glove's motors node does too): its page's output is held
    at 0 by its guard, as the CAN glove's is."""
    import threading

    from touch4d.bus import Executor, Node
    from touch4d.bus.container import Container
    from touch4d.bus.testing import running_broker, wait_until
    from touch4d.messages import Stop

    with running_broker() as bus:
        executor = Executor()
        box = Container(executor, bus.for_clients())
        probe = Node("stopper", bus=bus.for_clients())
        stop = probe.create_publisher("safety/stop", Stop)
        try:
            box.load({"load": "A", "namespace": "", "nodes": [{"node": "webxr", "name": "tracker", "params": {
                "port": 0, "save_calibration": False, "tracker": True}}], "ready_file": ""})
            node = box.groups["A"].nodes[0]
            spinning = threading.Thread(target=executor.spin, args=(10.0,))
            spinning.start()
            try:
                guard = node.bridge.output.guard
                assert guard.holds_off(node.bridge.now()) != "stop"
                wait_until(lambda: (stop.publish(Stop(reason="test", origin="test")), probe.spin_once(0.05),
                                    guard.holds_off(node.bridge.now()) == "stop")[-1], timeout=10)
            finally:
                executor.request_shutdown()
                spinning.join()
        finally:
            probe.shutdown()
            box.unload_all()
            executor.close()

"""The motor-side logic without a bus: what is sent when, watchdog, stop, board liveness, retries."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from touch4d.glove.config import load_glove_can
from touch4d.glove.driver import MotorDriver
from touch4d.glove.duty import duty_to_levels, intensity_to_duty
from touch4d.glove.protocol import GloveProtocol

CFG = load_glove_can(Path(__file__).parent / "data" / "glove_can_test.yaml")
PROTO = GloveProtocol(CFG)
NAMES = list(CFG.motor_names)
T0 = 500.0


def frames(outs):
    return [(o.board, PROTO.decode(o.msg)) for o in outs]


def send_all(driver, outs, now):
    for o in outs:
        driver.sent(o, now)
    return outs


@pytest.fixture
def driver():
    d = MotorDriver(CFG, PROTO, now=T0)
    send_all(d, d.outgoing(T0, refresh=True), T0)  # the first tick: NMT START + a frame per board
    return d


def test_first_tick_starts_every_board():
    d = MotorDriver(CFG, PROTO, now=T0)
    out = frames(d.outgoing(T0, refresh=True))
    assert out[0][1].kind == "nmt" and out[0][1].signals == {"Command": 1, "Node": 0}
    assert sorted(b for b, f in out if f.kind == "duty") == [1, 2, 3, 4]


def test_each_motor_reaches_its_board_and_channel_with_its_duty(driver):
    for k in (0, 7, 8, 13, 29):
        v = np.zeros(30)
        v[k] = 0.6
        now = T0 + 0.01 * (k + 1)
        driver.command(NAMES, v, now)
        out = frames(send_all(driver, driver.outgoing(now), now))
        expected = int(duty_to_levels(intensity_to_duty([0.6], CFG.duty))[0])
        board, channel = 1 + k // 8, k % 8
        levels = {b: PROTO.levels(f, 8) for b, f in out}
        assert levels[board][channel] == expected
        assert sum(map(sum, levels.values())) == expected  # nothing else on


def test_only_changed_boards_are_sent_then_refresh_sends_all(driver):
    v = np.zeros(30)
    v[9] = 1.0  # board 2
    driver.command(NAMES, v, T0 + 0.01)
    out = send_all(driver, driver.outgoing(T0 + 0.01), T0 + 0.01)
    assert [o.board for o in out] == [2]
    driver.command(NAMES, v, T0 + 0.02)
    assert driver.outgoing(T0 + 0.02) == []  # unchanged
    out = driver.outgoing(T0 + 0.025, refresh=True)
    assert sorted(o.board for o in out) == [1, 2, 3, 4]


def test_a_change_within_half_a_period_waits_for_the_tick(driver):
    v = np.zeros(30)
    v[0] = 1.0
    now = T0 + 0.001  # the fixture sent every board at T0; half a period is 2.5 ms
    driver.command(NAMES, v, now)
    assert driver.outgoing(now) == []
    out = driver.outgoing(T0 + 0.003, refresh=True)
    assert [o.board for o in out] == [1, 2, 3, 4] and out[0].levels[0] > 0


def test_counter_rolls_per_frame(driver):
    counters = []
    for i in range(1, 300):
        now = T0 + i * 0.005
        out = send_all(driver, driver.outgoing(now, refresh=True), now)
        counters += [PROTO.decode(o.msg).signals["Counter"] for o in out if o.board == 1]
    assert counters[:3] == [2, 3, 4] and max(counters) == 255 and 0 in counters


def test_silence_on_tactile_motors_turns_everything_off(driver):
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.01)
    send_all(driver, driver.outgoing(T0 + 0.01), T0 + 0.01)
    assert np.all(driver.sent_duty() > 0)
    out = driver.outgoing(T0 + 0.01 + CFG.watchdog_s + 0.001, refresh=True)
    assert all(o.levels == (0,) * 8 for o in out) and len(out) == 4
    assert driver.errors["watchdog_off"] == 1


def test_unknown_and_missing_motor_names(driver):
    driver.command(["palm_1", "nope", "back_4"], np.array([1.0, 1.0, 1.0]), T0 + 0.01)
    out = send_all(driver, driver.outgoing(T0 + 0.01), T0 + 0.01)
    duty = driver.sent_duty()
    assert duty[NAMES.index("palm_1")] > 0 and duty[NAMES.index("back_4")] > 0
    assert np.count_nonzero(duty) == 2 and driver.errors["unknown_motor"] == 1
    assert [o.board for o in out] == [1, 2]


def test_stop_sends_nmt_stop_zeroes_holds_then_restarts(driver):
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.01)
    send_all(driver, driver.outgoing(T0 + 0.01), T0 + 0.01)
    stop = PROTO.decode(driver.stop(T0 + 0.012))
    assert stop.kind == "nmt" and stop.signals == {"Command": 2, "Node": 0}
    out = send_all(driver, driver.outgoing(T0 + 0.012, refresh=True, force=True), T0 + 0.012)
    assert len(out) == 4 and all(o.levels == (0,) * 8 for o in out)
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.02)  # during the hold: ignored
    assert all(o.levels == (0,) * 8 for o in driver.outgoing(T0 + 0.03, refresh=True))
    after = T0 + 0.012 + CFG.stop_hold_s + 0.001
    out = frames(driver.outgoing(after, refresh=True))
    assert (0, PROTO.decode(PROTO.nmt("START"))) in out
    driver.command(NAMES, np.full(30, 0.8), after + 0.01)
    assert all(o.levels != (0,) * 8 for o in driver.outgoing(after + 0.01, refresh=True) if o.board)


def heard(driver, board, now, state="ACTIVE"):
    msg = PROTO.status(board, state, (), 0, 0, 0)
    driver.receive(msg, PROTO.decode(msg), now)


def test_board_liveness_reports_a_silent_board_and_its_return(driver):
    assert driver.check_boards(T0 + 0.1) == []  # start grace
    for b in (1, 2, 3, 4):
        heard(driver, b, T0 + 0.2)
    assert len(driver.check_boards(T0 + 0.2)) == 4
    for b in (1, 3, 4):
        heard(driver, b, T0 + 0.5)
    events = driver.check_boards(T0 + 0.55)
    assert events == [f"board 2 not answering for {CFG.board_timeout_s} s"]
    report = {r["id"]: r for r in driver.board_report()}
    assert report[2]["online"] is False and report[2]["state"] == "offline" and "not_answering" in report[2]["faults"]
    assert report[1]["online"] is True and report[1]["state"] == "operational"
    heard(driver, 2, T0 + 0.6, state="PRE_OPERATIONAL")  # it rebooted
    assert driver.check_boards(T0 + 0.6) == ["board 2 online (pre_operational)"]
    out = frames(driver.outgoing(T0 + 0.6, refresh=True))
    assert (0, PROTO.decode(PROTO.nmt("START", 2))) in out


def test_a_board_never_heard_is_reported_after_the_grace(driver):
    heard(driver, 1, T0 + 0.35)
    events = driver.check_boards(T0 + 0.4)
    assert sorted(events) == sorted(["board 1 online (operational)"] +
                                    [f"board {b} not answering for {CFG.board_timeout_s} s" for b in (2, 3, 4)])


def test_a_failed_frame_is_retried_on_the_next_tick(driver):
    driver.command(NAMES, np.full(30, 0.5), T0 + 0.01)
    out = driver.outgoing(T0 + 0.01)
    for o in out:
        driver.failed(o, "tx_queue_full")
    assert driver.errors["tx_queue_full"] == 4
    assert "send_failing" in driver.board_report()[0]["faults"]
    retry = driver.outgoing(T0 + 0.011)  # still changed against what was last sent
    assert [o.levels for o in retry] == [o.levels for o in out]
    send_all(driver, retry, T0 + 0.011)
    assert "send_failing" not in driver.board_report()[0]["faults"]

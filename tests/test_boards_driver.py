"""The motor-side logic without a bus: what is sent when, watchdog, stop, board liveness, retries."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import msgspec
import numpy as np
import pytest

from touch4d.errors import ConfigError
from touch4d.boards.config import glove_can_from_mapping, load_glove_can
from touch4d.boards.driver import FRAMES_PER_PERIOD, MotorDriver
from touch4d.boards.duty import duty_to_levels, intensity_to_duty
from touch4d.boards.protocol import GloveProtocol

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


def test_a_second_change_within_half_a_period_waits_for_the_tick(driver):
    v = np.zeros(30)
    v[0] = 1.0
    t = T0 + 0.005
    ticked = send_all(driver, driver.outgoing(t, refresh=True), t)
    assert len(ticked) == 4 and not any(o.change for o in ticked)
    driver.command(NAMES, v, t + 0.0005)  # a refresh frame 0.5 ms ago does not hold a change back
    first = send_all(driver, driver.outgoing(t + 0.0005), t + 0.0005)
    assert [o.board for o in first] == [1] and first[0].change
    v[1] = 1.0
    driver.command(NAMES, v, t + 0.0015)
    assert driver.outgoing(t + 0.0015) == []  # 1 ms after board 1's change frame: wait
    out = driver.outgoing(t + 0.003, refresh=True)  # the tick, 2.5 ms after the change
    assert [o.board for o in out if o.change] == [1] and out[0].levels[1] > 0


def test_duty_frames_per_board_stay_within_the_counted_worst_case(driver):
    """Commands far faster than the refresh, ticks every period: frames never exceed busload's count."""
    rng = np.random.default_rng(3)
    period = 1 / CFG.refresh_hz
    now, next_tick, sent = T0, T0 + period, {b: 0 for b in (1, 2, 3, 4)}
    while now < T0 + 2.0:
        now += rng.uniform(0.0001, 0.004)
        refresh = now >= next_tick
        if refresh:
            next_tick += period
        else:
            driver.command(NAMES, rng.uniform(0.1, 1, 30), now)
        for o in send_all(driver, driver.outgoing(now, refresh=refresh), now):
            sent[o.board] += 1
    for count in sent.values():
        assert CFG.refresh_hz * 2.0 <= count <= FRAMES_PER_PERIOD * CFG.refresh_hz * 2.0 + 2


def test_refresh_without_commands_sends_every_board_every_tick(driver):
    period = 1 / CFG.refresh_hz
    counts = {b: 0 for b in (1, 2, 3, 4)}
    for i in range(1, 201):
        now = T0 + i * period
        for o in send_all(driver, driver.outgoing(now, refresh=True), now):
            counts[o.board] += 1
    assert counts == {1: 200, 2: 200, 3: 200, 4: 200}


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


def test_a_board_that_applies_none_of_the_frames_sent_is_reported(driver):
    def status(counter, now):
        msg = PROTO.status(3, "ACTIVE", (), counter, 0, 0)
        driver.receive(msg, PROTO.decode(msg), now)

    period = 1 / CFG.refresh_hz
    status(1, T0)
    for i in range(1, 11):
        now = T0 + i * period
        send_all(driver, driver.outgoing(now, refresh=True), now)
    status(11, T0 + 0.05)  # acknowledged the frames: fine
    driver.check_boards(T0 + 0.05)
    assert "commands_not_acked" not in {r["id"]: r for r in driver.board_report()}[3]["faults"]
    for i in range(11, 21):
        now = T0 + i * period
        send_all(driver, driver.outgoing(now, refresh=True), now)
    status(11, T0 + 0.1)  # ten more frames, the same counter
    report = {r["id"]: r for r in driver.board_report()}
    assert "commands_not_acked" in report[3]["faults"] and report[3]["online"]


def test_a_stale_command_turns_every_motor_off_and_never_on(driver):
    stale = CFG.command_max_age_s + 0.05
    assert CFG.command_max_age_s == CFG.watchdog_s   # the default
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.01, age=stale)
    assert all(o.levels == (0,) * 8 for o in driver.outgoing(T0 + 0.01, refresh=True) if o.board)
    assert driver.errors["stale_command"] == 1 and driver.last_command_at is None  # no watchdog food
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.02, age=0.01)
    on = send_all(driver, driver.outgoing(T0 + 0.02, refresh=True), T0 + 0.02)
    assert all(any(o.levels) for o in on if o.board)
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.03, age=stale)   # after fresh ones: off at once
    assert all(o.levels == (0,) * 8 for o in driver.outgoing(T0 + 0.03, refresh=True) if o.board)
    assert driver.is_stale(float("nan")) and not driver.is_stale(-5.0) and not driver.is_stale(None)
    driver.command(NAMES, np.full(30, 0.8), T0 + 0.04, age=-5.0)   # a sender's clock ahead: used, counted
    assert all(any(o.levels) for o in driver.outgoing(T0 + 0.04, refresh=True) if o.board)
    assert driver.errors["command_from_future"] == 1


def test_the_age_check_is_off_with_a_zero_limit():
    d = MotorDriver(dataclasses.replace(CFG, command_max_age_s=0.0), PROTO, now=T0)
    d.command(NAMES, np.full(30, 0.8), T0 + 0.01, age=3600.0)
    assert all(any(o.levels) for o in d.outgoing(T0 + 0.01, refresh=True) if o.board)
    assert d.errors["stale_command"] == 0


def test_an_infinite_stop_hold_never_releases():
    d = MotorDriver(dataclasses.replace(CFG, stop_hold_s=float("inf")), PROTO, now=T0)
    send_all(d, d.outgoing(T0, refresh=True), T0)
    d.stop(T0 + 0.01)
    later = T0 + 1e6
    d.command(NAMES, np.full(30, 0.8), later, age=0.0)
    out = frames(d.outgoing(later, refresh=True))
    assert all(f.kind == "duty" and GloveProtocol.levels(f, 8) == [0] * 8 for _, f in out)  # no START
    assert d.errors["ignored_during_stop"] == 1


def test_board_levels_and_sent_duty_agree_on_a_scrambled_mapping():
    # channels in reverse order on every board: the frame layout and the duty report use one mapping
    cfg = dataclasses.replace(CFG, motor_channel=tuple(7 - c for c in CFG.motor_channel))
    d = MotorDriver(cfg, PROTO, now=T0)
    v = np.linspace(0.1, 1.0, 30)
    d.command(NAMES, v, T0 + 0.01)
    out = send_all(d, d.outgoing(T0 + 0.01, refresh=True), T0 + 0.01)
    want = duty_to_levels(intensity_to_duty(v, CFG.duty))
    for o in (o for o in out if o.board):
        expected = [0] * 8
        for k, c in cfg.motors_of(o.board):
            expected[c] = int(want[k])
        assert o.levels == tuple(expected)
    assert np.allclose(d.sent_duty(), want / 127)


def test_config_rejects_an_infinite_watchdog_and_accepts_a_latching_stop(tmp_path):
    import yaml
    data = yaml.safe_load((Path(__file__).parent / "data" / "glove_can_test.yaml").read_text())
    data["can"]["watchdog_s"] = float("inf")
    with pytest.raises(ConfigError, match="can.watchdog_s.*finite"):
        glove_can_from_mapping(data, "inf.yaml")
    data["can"].update(watchdog_s=0.2, stop_hold_s=float("inf"))
    cfg = glove_can_from_mapping(data, "latch.yaml")
    assert cfg.stop_hold_s == float("inf") and cfg.command_max_age_s == 0.2   # follows watchdog_s
    data["can"]["command_max_age_s"] = -1
    with pytest.raises(ConfigError, match="can.command_max_age_s"):
        glove_can_from_mapping(data, "neg.yaml")


def test_cached_duty_frames_are_the_protocols_encoding(driver):
    for k in range(600):   # more than one counter cycle of a steady pattern, then a changing one
        v = np.full(30, 0.5) if k < 300 else np.linspace(0, 1, 30) * (k % 7) / 7
        driver.command(NAMES, v, T0 + 0.01 + 0.005 * k)
        for o in send_all(driver, driver.outgoing(T0 + 0.01 + 0.005 * k, refresh=True), T0 + 0.01 + 0.005 * k):
            if o.board:
                counter = PROTO.decode(o.msg).signals["Counter"]
                want = PROTO.duty(o.board, o.levels, counter)
                assert (o.msg.arbitration_id, bytes(o.msg.data), o.msg.is_extended_id) == \
                       (want.arbitration_id, bytes(want.data), want.is_extended_id)


class CountingProtocol(GloveProtocol):
    """The glove's protocol, counting the duty frames cantools encodes."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self.encoded = 0

    def duty(self, board, levels, counter):
        self.encoded += 1
        return super().duty(board, levels, counter)


def test_an_idle_glove_is_refreshed_with_its_cached_frames_unchanged():
    proto = CountingProtocol(CFG)
    d = MotorDriver(CFG, proto, now=T0)
    period = 1 / CFG.refresh_hz
    sent = []
    for i in range(600):
        now = T0 + i * period
        sent.append({o.board: o.msg for o in send_all(d, d.outgoing(now, refresh=True), now) if o.board})
    assert all(len(tick) == 4 for tick in sent)
    # a full counter cycle later, every board's frame is the very same object, encoded before
    encoded = proto.encoded
    for i in range(600):
        now = T0 + (600 + i) * period
        for o in send_all(d, d.outgoing(now, refresh=True), now):
            if o.board:
                assert o.msg is sent[(600 + i) % 256 + 256][o.board]
                assert PROTO.decode(o.msg).signals["Counter"] == (600 + i + 1) & 0xFF
                assert PROTO.levels(PROTO.decode(o.msg), 8) == [0] * 8
    assert proto.encoded == encoded


def test_new_duties_are_encoded_once_per_board_and_change():
    proto = CountingProtocol(CFG)
    d = MotorDriver(CFG, proto, now=T0)
    period = 1 / CFG.refresh_hz
    for i in range(300):   # every counter value seen once (the counter's part is then known)
        send_all(d, d.outgoing(T0 + i * period, refresh=True), T0 + i * period)
    rng = np.random.default_rng(3)
    patterns = rng.uniform(0.2, 1.0, (40, 30))
    seen = set()
    before = proto.encoded
    for k, v in enumerate(np.repeat(patterns, 3, axis=0)):   # each pattern held for 3 ticks
        now = T0 + (300 + k) * period
        d.command(NAMES, v, now)
        for o in send_all(d, d.outgoing(now, refresh=True), now):
            if o.board:
                seen.add((o.board, o.levels))
                want = PROTO.duty(o.board, o.levels, PROTO.decode(o.msg).signals["Counter"])
                assert bytes(o.msg.data) == bytes(want.data)
    assert proto.encoded - before == len(seen) == 40 * 4


def test_duties_follow_time_without_input_as_if_computed_every_tick(tmp_path):
    """Watchdog, stop hold and thermal limit act on time alone: the driver, which computes the
    duties again only when they can change, gives every tick what the rules give."""
    from touch4d.boards.duty import ThermalState, thermal_limit

    cfg = dataclasses.replace(CFG, stop_hold_s=0.3,
                              thermal=msgspec.structs.replace(CFG.thermal, max_on_s=0.4, cool_s=0.25))
    d = MotorDriver(cfg, GloveProtocol(cfg), now=T0)
    period = 1 / cfg.refresh_hz
    state, last_command, stop_until = ThermalState.initial(30), None, -np.inf
    v = np.linspace(0.0, 1.0, 30)
    for i in range(1, 800):
        now = T0 + i * period
        if (i < 150 or 300 <= i < 500) and i % 9 == 0:   # commands, silence (watchdog), commands again ...
            d.command(NAMES, v, now)
            if now >= stop_until:
                last_command = now
        if i == 420:                             # ... a stop in the middle of them
            d.stop(now)
            stop_until = now + cfg.stop_hold_s
        send_all(d, d.outgoing(now, refresh=True), now)
        silent = last_command is None or now - last_command > cfg.watchdog_s
        wanted = np.zeros(30) if silent or now < stop_until else intensity_to_duty(v, cfg.duty)
        want, state = thermal_limit(wanted, state, now, cfg.thermal)
        assert d.duty.tolist() == want.tolist(), i
        assert d.duties_on_bus()


def test_refresh_slows_to_the_idle_rate_only_while_every_motor_is_off_and_sent():
    fast, idle = 1 / CFG.refresh_hz, 1 / CFG.idle_refresh_hz
    assert CFG.idle_refresh_hz == 25.0 and idle == pytest.approx(0.04)   # the default: 25 Hz
    d = MotorDriver(CFG, PROTO, now=T0)
    assert d.refresh_period(T0) == fast                    # the first tick's NMT START is due
    send_all(d, d.outgoing(T0, refresh=True), T0)
    assert d.refresh_period(T0) == idle                    # all off, and the boards were sent so
    t = T0 + 0.01
    d.command(NAMES, np.full(30, 0.5), t)
    assert d.refresh_period(t) == fast                     # a command's duties are not yet sent
    send_all(d, d.outgoing(t), t)
    assert d.refresh_period(t) == fast                     # motors on: the boards' watchdogs need feeding
    t += CFG.watchdog_s + 0.001                            # silence: the node's watchdog turns all off
    assert d.refresh_period(t) == fast                     # ... but the zeros are not sent yet
    send_all(d, d.outgoing(t, refresh=True), t)
    assert d.refresh_period(t) == idle
    d.command(NAMES, np.zeros(30), t + 0.001)               # a command of all zeros changes nothing
    assert d.refresh_period(t + 0.001) == idle
    t += 0.01
    d.stop(t)
    send_all(d, d.outgoing(t, refresh=True, force=True), t)
    assert d.refresh_period(t) == fast                     # a stop hold ends in an NMT START, on time
    t += CFG.stop_hold_s + 0.001
    assert d.refresh_period(t) == fast
    out = frames(send_all(d, d.outgoing(t, refresh=True), t))
    assert out[0][1].kind == "nmt" and out[0][1].signals["Command"] == 1   # START, to every board
    assert d.refresh_period(t) == idle


@pytest.mark.parametrize("can, want", [
    ({}, 25.0),                                            # the default
    ({"board_watchdog_s": 0.05}, 40.0),                    # two frames per board watchdog
    ({"refresh_hz": 20.0, "board_watchdog_s": 1.0}, 20.0),  # never faster than the refresh
    ({"idle_refresh_hz": 50.0}, 50.0),
])
def test_idle_refresh_rate_default_follows_the_board_watchdog(can, want):
    data = {"motors": [{"name": "m", "position": [0, 0, 0], "board": 1, "channel": 0}],
            "can": {"boards": [{"id": 1, "channels": 1}], **can}}
    assert glove_can_from_mapping(data, "g.yaml").idle_refresh_hz == want


@pytest.mark.parametrize("can, expected", [
    ({"idle_refresh_hz": 10.0}, ">= 20"),                  # 100 ms between frames: one loss trips a board
    ({"idle_refresh_hz": 300.0}, "<= can.refresh_hz"),
    ({"idle_refresh_hz": "slow"}, "finite number > 0, got 'slow'"),
])
def test_bad_idle_refresh_rate_names_the_key(can, expected):
    data = {"motors": [{"name": "m", "position": [0, 0, 0], "board": 1, "channel": 0}],
            "can": {"boards": [{"id": 1, "channels": 1}], **can}}
    with pytest.raises(ConfigError) as err:
        glove_can_from_mapping(data, "g.yaml")
    assert "'can.idle_refresh_hz'" in str(err.value) and expected in str(err.value)

"""The board emulator: NMT states, duty frames applied, watchdog, status and heartbeat, bad frames."""
from __future__ import annotations

import time
import uuid
from pathlib import Path

import can
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import GloveEmulator
from touch4d.boards.protocol import GloveProtocol

CFG = load_glove_can(Path(__file__).parent / "data" / "glove_can_test.yaml")
PROTO = GloveProtocol(CFG)


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture
def emu():
    """A glove emulator stepped by hand with a fake clock (its bus is a private virtual channel)."""
    clock = Clock()
    e = GloveEmulator(CFG, interface="virtual", channel=f"emu-{uuid.uuid4().hex}", clock=clock)
    e.clock_ = clock
    try:
        yield e
    finally:
        e.stop()


def decoded(frames):
    return [PROTO.decode(f) for f in frames]


def test_boot_heartbeat_then_duty_ignored_until_start(emu):
    out = decoded(emu.poll(emu.clock_.t))
    boot = [f for f in out if f.kind == "heartbeat"]
    assert sorted(f.board for f in boot) == [1, 2, 3, 4]
    assert all(PROTO.state_name(f) == "BOOTUP" for f in boot)
    emu.process(PROTO.duty(1, [50] * 8, 1), emu.clock_.t)
    assert emu.levels(1) == [0] * 8 and emu.boards[1].counters["ignored"] == 1
    emu.process(PROTO.nmt("START", 1), emu.clock_.t)
    emu.process(PROTO.duty(1, [50, 0, 0, 0, 0, 0, 0, 9], 2), emu.clock_.t)
    assert emu.levels(1) == [50, 0, 0, 0, 0, 0, 0, 9]
    assert emu.boards[2].nmt_state == "PRE_OPERATIONAL"  # START was addressed to board 1 only
    status = [f for f in decoded(emu.poll(emu.clock_.t)) if f.kind == "status" and f.board == 1][0]
    assert PROTO.state_name(status) == "ACTIVE"
    assert status.signals["LastCounter"] == 2 and status.signals["ActiveMask"] == 0b10000001


def test_watchdog_turns_every_channel_off_and_the_next_frame_resumes(emu):
    clock = emu.clock_
    emu.process(PROTO.nmt("START"), clock.t)
    emu.process(PROTO.duty(3, [100] * 8, 7), clock.t)
    clock.t += 0.09
    emu.poll(clock.t)
    assert emu.levels(3) == [100] * 8
    clock.t += 0.02  # 110 ms without a duty frame > 100 ms watchdog
    out = [f for f in decoded(emu.poll(clock.t)) if f.kind == "status" and f.board == 3]
    assert emu.levels(3) == [0] * 8
    assert PROTO.state_name(out[0]) == "WATCHDOG_OFF" and "watchdog" in PROTO.faults(out[0])
    emu.process(PROTO.duty(3, [20] * 8, 8), clock.t)
    assert emu.levels(3) == [20] * 8 and emu.boards[3].output_state() == "ACTIVE"


def test_stop_turns_everything_off_and_ignores_duty_until_start(emu):
    clock = emu.clock_
    emu.process(PROTO.nmt("START"), clock.t)
    for b in (1, 2, 3, 4):
        emu.process(PROTO.duty(b, [60] * 8, 1), clock.t)
    emu.process(PROTO.nmt("STOP"), clock.t)
    assert all(emu.levels(b) == [0] * 8 for b in (1, 2, 3, 4))
    emu.process(PROTO.duty(2, [60] * 8, 2), clock.t)
    assert emu.levels(2) == [0] * 8
    states = {f.board: PROTO.state_name(f) for f in decoded(emu.poll(clock.t)) if f.kind == "status"}
    assert states == {1: "STOPPED", 2: "STOPPED", 3: "STOPPED", 4: "STOPPED"}
    emu.process(PROTO.nmt("START"), clock.t)
    emu.process(PROTO.duty(2, [60] * 8, 3), clock.t)
    assert emu.levels(2) == [60] * 8


def test_periodic_status_and_heartbeat_rates(emu):
    clock = emu.clock_
    kinds = []
    for _ in range(200):  # 2 s in 10 ms steps
        kinds += [(f.kind, f.board) for f in decoded(emu.poll(clock.t))]
        clock.t += 0.01
    # 20 Hz status, 2 Hz heartbeat (+ the boot-up heartbeat), per board
    assert 38 <= kinds.count(("status", 1)) <= 42
    assert 4 <= kinds.count(("heartbeat", 1)) <= 6


def test_malformed_and_unknown_frames_are_ignored_and_counted(emu):
    clock = emu.clock_
    emu.process(PROTO.nmt("START"), clock.t)
    emu.process(PROTO.duty(1, [40] * 8, 1), clock.t)
    emu.poll(clock.t)
    bad = [
        can.Message(arbitration_id=0x201, data=bytes([1, 2, 3]), is_extended_id=False),   # short duty for board 1
        can.Message(arbitration_id=0x201, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=0x000, data=bytes([0x55, 0]), is_extended_id=False),    # unknown NMT command
    ]
    for m in bad:
        emu.process(m, clock.t)
    emu.process(can.Message(arbitration_id=0x321, data=b"\xff", is_extended_id=False), clock.t)
    emu.process(can.Message(arbitration_id=0x1234567, data=b"\xff" * 8, is_extended_id=True), clock.t)
    assert emu.levels(1) == [40] * 8
    assert emu.counters["malformed"] == 3 and emu.counters["unknown"] == 2
    assert emu.boards[1].counters["malformed"] == 3 and emu.boards[2].counters["malformed"] == 1
    status = {f.board: f for f in decoded(emu.poll(clock.t + 0.06)) if f.kind == "status"}
    assert status[1].signals["BadFrames"] == 5 and "bad_frame" in PROTO.faults(status[1])
    assert status[2].signals["BadFrames"] == 3


def test_a_removed_board_is_silent_and_comes_back_booting(emu):
    clock = emu.clock_
    emu.process(PROTO.nmt("START"), clock.t)
    emu.remove(2)
    emu.process(PROTO.duty(2, [90] * 8, 1), clock.t)
    emu.process(PROTO.duty(1, [90] * 8, 1), clock.t)
    assert emu.levels(2) == [0] * 8 and emu.levels(1) == [90] * 8
    boards = {f.board for f in decoded(emu.poll(clock.t + 1.0))}
    assert boards == {1, 3, 4}
    emu.restore(2)
    hb = [f for f in decoded(emu.poll(clock.t)) if f.kind == "heartbeat" and f.board == 2]
    assert PROTO.state_name(hb[0]) == "BOOTUP" and emu.boards[2].nmt_state == "PRE_OPERATIONAL"


def test_a_hardware_fault_turns_the_board_off_and_is_reported(emu):
    clock = emu.clock_
    emu.process(PROTO.nmt("START"), clock.t)
    emu.process(PROTO.duty(4, [70] * 8, 1), clock.t)
    emu.boards[4].hardware_faults.add("overtemp")
    status = [f for f in decoded(emu.poll(clock.t)) if f.kind == "status" and f.board == 4][0]
    assert emu.levels(4) == [0] * 8
    assert PROTO.state_name(status) == "FAULT_OFF" and PROTO.faults(status) == ["overtemp"]


def drive_board_1(emu, bus) -> float:
    """Start the boards and send duty 33 to board 1 until the threaded emulator applies it; returns
    the deadline (10 s from now) the rest of the test keeps to."""
    bus.send(PROTO.nmt("START"))
    deadline = time.monotonic() + 10
    while emu.levels(1) != [33] * 8 and time.monotonic() < deadline:
        bus.send(PROTO.duty(1, [33] * 8, 5))
        time.sleep(0.01)
    assert emu.levels(1) == [33] * 8
    return deadline


@pytest.mark.timeout(30)
def test_threaded_emulator_on_a_virtual_channel_answers_and_times_out():
    channel = f"emu-thread-{uuid.uuid4().hex}"
    with GloveEmulator(CFG, interface="virtual", channel=channel) as emu, \
            can.Bus(interface="virtual", channel=channel) as bus:
        deadline = drive_board_1(emu, bus)
        seen = {}
        while len(seen) < 4 and time.monotonic() < deadline:
            m = bus.recv(timeout=0.1)
            f = PROTO.decode(m) if m is not None else None
            if f is not None and f.kind == "status":
                seen[f.board] = f
        assert set(seen) == {1, 2, 3, 4}
        # no more duty frames: the board's own watchdog turns it off (100 ms; generous wait)
        while emu.levels(1) != [0] * 8 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.levels(1) == [0] * 8 and emu.boards[1].watchdog_tripped


@pytest.mark.timeout(30)
def test_an_internal_error_in_the_emulator_loop_turns_every_channel_off_and_keeps_running():
    channel = f"emu-fault-{uuid.uuid4().hex}"
    with GloveEmulator(CFG, interface="virtual", channel=channel) as emu, \
            can.Bus(interface="virtual", channel=channel) as bus:
        deadline = drive_board_1(emu, bus)

        def broken(now):  # the tick (and with it the board watchdog) fails from now on
            raise RuntimeError("firmware bug")

        emu.poll = broken
        while (emu.levels(1) != [0] * 8 or not emu.counters["internal_errors"]) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.levels(1) == [0] * 8 and emu.counters["internal_errors"] >= 1
        assert emu._thread is not None and emu._thread.is_alive()

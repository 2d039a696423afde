"""One conformance suite for the glove boards, run on every implementation of them: the Python
emulator (touch4d/boards/emulator.py), the firmware's core (firmware/core, C) built for the host,
and the same core built for the Cortex-M3 and run under qemu-system-arm. The same frames in, the
same frames and outputs out.

Every scenario drives a whole glove (4 boards) on a simulated clock, asserts what the protocol
says (the DBC, the README), and records its inputs as a script and its outputs as observations;
the last tests replay the scripts on the other implementations and compare everything.
"""
from __future__ import annotations

import subprocess
import uuid
from pathlib import Path

import can
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import COUNTER_WINDOW, make_glove_emulator
from touch4d.boards.firmware import FIRMWARE_DIR, build
from touch4d.boards.protocol import GloveProtocol

CFG = load_glove_can(Path(__file__).parent / "data" / "glove_can_test.yaml")
PROTO = GloveProtocol(CFG)
BOARDS = [b.id for b in CFG.boards]
T0_US = 1_000_000_000                     # the scenarios' clock starts at 1000 s
COUNTERS = ("applied", "nmt", "ignored", "bad_counter", "unknown", "bad_length", "bad_frame_type",
            "bad_command", "error_frame", "watchdog_trips")
NMT_CODE = {"BOOTUP": 0, "STOPPED": 4, "OPERATIONAL": 5, "PRE_OPERATIONAL": 127}
OUTPUT_CODE = {"IDLE": 0, "ACTIVE": 1, "WATCHDOG_OFF": 2, "STOPPED": 3, "FAULT_OFF": 4, "PRE_OPERATIONAL": 5}
FAULT_BITS = {"overtemp": 4, "overcurrent": 8, "undervoltage": 16}
IMPLEMENTATIONS = ["python", "firmware"]


class Run:
    """One scenario on one implementation: inputs at times in ms, outputs recorded (script format
    of firmware/check/t4d_check.c)."""

    def __init__(self, impl: str):
        self.impl = impl
        self.glove = make_glove_emulator(impl, CFG, interface="virtual", channel=f"conf-{uuid.uuid4().hex}",
                                         clock=lambda: T0_US / 1e6)
        self.script = [f"W {round(CFG.board_watchdog_s * 1e6)}", f"B {T0_US}"]
        self.observed: list[tuple] = []

    @staticmethod
    def _us(t_ms: float) -> int:
        return T0_US + round(t_ms * 1000)

    def send(self, t_ms: float, msg: can.Message) -> None:
        t = self._us(t_ms)
        flags = (msg.is_extended_id * 1) | (msg.is_remote_frame * 2) | (msg.is_error_frame * 4) | (msg.is_fd * 8)
        self.script.append(f"F {t} {msg.arbitration_id:x} {flags} {len(msg.data)} {bytes(msg.data).hex()}")
        self.glove.process(msg, t / 1e6)

    def tick(self, t_ms: float) -> list:
        """Tick every board; the decoded frames they sent."""
        t = self._us(t_ms)
        self.script.append(f"T {t}")
        frames = self.glove.poll(t / 1e6)
        self.observed.append(("T", tuple((m.arbitration_id, bytes(m.data)) for m in frames)))
        return [PROTO.decode(m) for m in frames]

    def fault(self, board: int, *names: str) -> None:
        self.script.append(f"H {board} {sum(FAULT_BITS[n] for n in names)}")
        self.glove.boards[board].hardware_faults = set(names)

    def probe(self, board: int) -> dict:
        """A board's NMT and output state, channel levels (and PWM compare values), counters."""
        self.script.append(f"P {board}")
        b = self.glove.boards[board]
        counters = b.counters
        pwm = tuple(b.pwm) if hasattr(b, "pwm") else None
        probe = {"nmt": b.nmt_state, "output": b.output_state(), "levels": list(b.levels), "pwm": pwm,
                 "counters": {k: counters[k] for k in COUNTERS}}
        self.observed.append(("P", board, NMT_CODE[probe["nmt"]], OUTPUT_CODE[probe["output"]],
                              tuple(probe["levels"]), pwm, tuple(probe["counters"].values())))
        return probe

    def close(self) -> None:
        self.glove.stop()


def status_of(frames, board):
    found = [f for f in frames if f.kind == "status" and f.board == board]
    assert len(found) <= 1
    return found[0] if found else None


def start_all(r: Run, t_ms: float = 0.0) -> None:
    r.tick(t_ms)
    r.send(t_ms, PROTO.nmt("START"))


# ---- scenarios: each drives a Run and asserts; the cross-implementation test replays them all ----

def start_and_stop(r: Run) -> None:
    boot = r.tick(0)
    assert sorted((f.kind, f.board, PROTO.state_name(f)) for f in boot) == sorted(
        [("heartbeat", b, "BOOTUP") for b in BOARDS] + [("status", b, "PRE_OPERATIONAL") for b in BOARDS])
    r.send(1, PROTO.duty(1, [50] * 8, 1))
    p = r.probe(1)
    assert p["levels"] == [0] * 8 and p["counters"]["ignored"] == 1 and p["nmt"] == "PRE_OPERATIONAL"
    r.send(2, PROTO.nmt("START", 1))
    r.send(3, PROTO.duty(1, [50, 0, 0, 0, 0, 0, 0, 9], 2))
    assert r.probe(1)["levels"] == [50, 0, 0, 0, 0, 0, 0, 9]
    assert r.probe(2)["nmt"] == "PRE_OPERATIONAL"        # START was addressed to board 1 only
    frames = r.tick(4)
    s = status_of(frames, 1)
    assert PROTO.state_name(s) == "ACTIVE" and s.signals["LastCounter"] == 2 and s.signals["ActiveMask"] == 0b10000001
    assert [f.board for f in frames] == [1]               # the others: no change, not due
    r.send(5, PROTO.nmt("STOP"))
    assert r.probe(1)["levels"] == [0] * 8               # off with the STOP frame, before any tick
    r.send(6, PROTO.duty(1, [60] * 8, 3))
    p = r.probe(1)
    assert p["levels"] == [0] * 8 and p["counters"]["ignored"] == 2 and p["nmt"] == "STOPPED"
    frames = r.tick(7)
    assert {f.board: PROTO.state_name(f) for f in frames} == {b: "STOPPED" for b in BOARDS}
    assert status_of(frames, 1).signals["ActiveMask"] == 0
    r.send(8, PROTO.nmt("START"))
    r.send(9, PROTO.duty(1, [60] * 8, 4))
    assert r.probe(1)["levels"] == [60] * 8 and r.probe(1)["counters"]["nmt"] == 3


def duty_on_the_right_channels(r: Run) -> None:
    start_all(r)
    patterns = {b: [(17 * b + 13 * c) % 128 for c in range(8)] for b in BOARDS}
    for b in BOARDS:
        r.send(1 + b, PROTO.duty(b, patterns[b], 40 + b))
    for b in BOARDS:
        p = r.probe(b)
        assert p["levels"] == patterns[b] and p["counters"]["applied"] == 1
    frames = r.tick(10)
    for b in BOARDS:
        s = status_of(frames, b)
        assert s.signals["LastCounter"] == 40 + b
        assert s.signals["ActiveMask"] == sum(1 << c for c, v in enumerate(patterns[b]) if v)
    r.send(11, PROTO.duty(3, [127] * 8, 50))
    assert r.probe(3)["levels"] == [127] * 8
    assert [r.probe(b)["levels"] for b in (1, 2, 4)] == [patterns[1], patterns[2], patterns[4]]


def wrong_counter_rejected_and_counted(r: Run) -> None:
    start_all(r)
    r.send(1, PROTO.duty(1, [10] * 8, 200))              # any counter after START
    r.send(2, PROTO.duty(1, [20] * 8, 200))              # repeated
    r.send(3, PROTO.duty(1, [30] * 8, 199))              # older
    r.send(4, PROTO.duty(1, [40] * 8, (200 + COUNTER_WINDOW + 1) % 256))   # 128 ahead: as old as new
    p = r.probe(1)
    assert p["levels"] == [10] * 8 and p["counters"]["bad_counter"] == 3 and p["counters"]["applied"] == 1
    s = status_of(r.tick(5), 1)
    assert s.signals["BadFrames"] == 3 and "bad_frame" in PROTO.faults(s) and s.signals["LastCounter"] == 200
    r.send(6, PROTO.duty(1, [50] * 8, (200 + COUNTER_WINDOW) % 256))       # 127 ahead (frames lost): new
    r.send(7, PROTO.duty(1, [60] * 8, (200 + COUNTER_WINDOW + 1) % 256))   # the next one, across 255 -> 0
    assert r.probe(1)["levels"] == [60] * 8 and r.probe(1)["counters"]["applied"] == 3
    s = status_of(r.tick(60), 1)                          # periodic: the flag cleared, the count stays
    assert s.signals["BadFrames"] == 3 and "bad_frame" not in PROTO.faults(s)
    # Repeats do not feed the watchdog: a sender stuck on one frame is cut off.
    stuck = PROTO.duty(1, [60] * 8, (200 + COUNTER_WINDOW + 1) % 256)
    for t in (30, 60, 90, 105):
        r.send(7 + t, stuck)
        r.tick(7 + t)
    p = r.probe(1)
    assert p["levels"] == [0] * 8 and p["output"] == "WATCHDOG_OFF" and p["counters"]["bad_counter"] == 7
    r.send(120, stuck)                                    # after a watchdog trip any counter resumes
    assert r.probe(1)["levels"] == [60] * 8
    r.send(121, PROTO.nmt("START"))                       # so does START (a restarted controller)
    r.send(122, PROTO.duty(1, [70] * 8, 3))
    assert r.probe(1)["levels"] == [70] * 8 and r.probe(1)["counters"]["bad_counter"] == 7


def wrong_length_and_kind_rejected_and_counted(r: Run) -> None:
    start_all(r)
    r.send(1, PROTO.duty(1, [40] * 8, 1))
    r.tick(1)
    bad = [
        can.Message(arbitration_id=0x201, data=bytes([1, 2, 3]), is_extended_id=False),      # short duty, board 1
        can.Message(arbitration_id=0x201, data=bytes(7), is_extended_id=False),               # 7 bytes, board 1
        can.Message(arbitration_id=0x202, data=bytes([5]), is_extended_id=False),             # short duty, board 2
        can.Message(arbitration_id=0x201, is_remote_frame=True, dlc=8, is_extended_id=False),  # remote, board 1
        can.Message(arbitration_id=0x201, data=bytes(8), is_fd=True, is_extended_id=False),   # FD, board 1
        can.Message(arbitration_id=0x000, data=bytes([1]), is_extended_id=False),             # NMT, 1 byte
        can.Message(arbitration_id=0x000, data=bytes([1, 0, 0]), is_extended_id=False),       # NMT, 3 bytes
        can.Message(arbitration_id=0x000, data=bytes([0x55, 0]), is_extended_id=False),       # unknown command
        can.Message(arbitration_id=0x000, data=bytes([0x55, 3]), is_extended_id=False),       # ... to board 3
        can.Message(arbitration_id=0x000, is_error_frame=True, is_extended_id=False),         # error frame
        can.Message(arbitration_id=0x181, data=bytes(3), is_extended_id=False),               # a short status
        can.Message(arbitration_id=0x702, data=bytes([99]), is_extended_id=False),            # bad heartbeat
    ]
    for k, m in enumerate(bad):
        r.send(2 + k, m)
    p1, p2, p3 = r.probe(1), r.probe(2), r.probe(3)
    assert p1["levels"] == [40] * 8 and p1["counters"]["applied"] == 1
    want_1 = {"bad_length": 4, "bad_frame_type": 2, "bad_command": 2, "error_frame": 1}
    want_2 = {"bad_length": 3, "bad_frame_type": 0, "bad_command": 2, "error_frame": 1}
    assert {k: p1["counters"][k] for k in want_1} == want_1
    assert {k: p2["counters"][k] for k in want_2} == want_2
    assert {k: p3["counters"][k] for k in want_2} == {**want_2, "bad_length": 2}
    frames = r.tick(60)
    assert status_of(frames, 1).signals["BadFrames"] == 9 and status_of(frames, 4).signals["BadFrames"] == 5
    assert "bad_frame" in PROTO.faults(status_of(frames, 4))


def unknown_ids_rejected_and_counted(r: Run) -> None:
    start_all(r)
    r.send(1, PROTO.duty(2, [33] * 8, 1))
    unknown = [
        can.Message(arbitration_id=0x321, data=b"\xff", is_extended_id=False),
        can.Message(arbitration_id=0x205, data=bytes(8), is_extended_id=False),      # duty of a board 5 the glove lacks
        can.Message(arbitration_id=0x202, data=bytes(8), is_extended_id=True),       # board 2's id, but extended
        can.Message(arbitration_id=0x1234567, data=b"\xff" * 8, is_extended_id=True),
        can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=0, is_extended_id=False),
    ]
    for k, m in enumerate(unknown):
        r.send(2 + k, m)
    r.send(8, PROTO.status(3, "IDLE"))                   # another board's answer: not unknown
    r.send(9, PROTO.heartbeat(1, "OPERATIONAL"))         # a board's own id from elsewhere: ignored
    for b in BOARDS:
        p = r.probe(b)
        assert p["counters"]["unknown"] == 5 and p["counters"]["bad_length"] == 0
    assert r.probe(2)["levels"] == [33] * 8
    frames = r.tick(60)
    assert all(status_of(frames, b).signals["BadFrames"] == 5 for b in BOARDS)


def watchdog_off_after_100_ms(r: Run) -> None:
    start_all(r, 10)
    r.send(10, PROTO.duty(3, [90] * 8, 1))
    r.tick(10)
    r.tick(10 + 99)
    p = r.probe(3)
    assert p["levels"] == [90] * 8 and p["output"] == "ACTIVE"
    frames = r.tick(10 + 101)
    p = r.probe(3)
    assert p["levels"] == [0] * 8 and p["output"] == "WATCHDOG_OFF" and p["counters"]["watchdog_trips"] == 1
    s = status_of(frames, 3)
    assert PROTO.state_name(s) == "WATCHDOG_OFF" and "watchdog" in PROTO.faults(s)
    assert PROTO.state_name(status_of(frames, 1)) == "WATCHDOG_OFF"   # START without a duty frame: off too
    r.send(120, PROTO.duty(3, [20] * 8, 2))
    p = r.probe(3)
    assert p["levels"] == [20] * 8 and p["output"] == "ACTIVE"
    frames = r.tick(121)
    assert PROTO.state_name(status_of(frames, 3)) == "ACTIVE" and "watchdog" not in PROTO.faults(status_of(frames, 3))


def status_and_heartbeat_timing(r: Run) -> None:
    step, end = 7, 2100                                   # 7 ms never lands on a 50 or 500 ms boundary
    seen = {("status", b): [] for b in BOARDS} | {("heartbeat", b): [] for b in BOARDS}
    for t in range(0, end, step):
        for f in r.tick(t):
            seen[(f.kind, f.board)].append(t)

    def schedule(period):                                 # the first tick at or after each period
        out, t = [0], 0
        while True:
            t = next((x for x in range(t + period, end, 1) if x % step == 0), None)
            if t is None:
                return out
            out.append(t)

    status_period = round(1000 / CFG.status_hz)
    heartbeat_period = round(1000 / CFG.heartbeat_hz)
    for b in BOARDS:
        assert seen[("status", b)] == schedule(status_period)
        assert seen[("heartbeat", b)] == schedule(heartbeat_period)   # boot-up at 0, then the period
    # A change of state is reported at the next tick, whatever the period.
    r.send(end + 1, PROTO.nmt("START", 2))
    r.send(end + 2, PROTO.duty(2, [5] * 8, 1))
    frames = r.tick(end + 3)
    assert [(f.kind, f.board, PROTO.state_name(f)) for f in frames] == [("status", 2, "ACTIVE")]


def stop_within_one_frame(r: Run) -> None:
    start_all(r)
    for b in BOARDS:
        r.send(1, PROTO.duty(b, [100] * 8, 1))
    r.send(2, PROTO.nmt("STOP", 2))                       # one board
    assert r.probe(2)["levels"] == [0] * 8 and r.probe(1)["levels"] == [100] * 8
    r.send(3, PROTO.nmt("STOP"))                          # every board, with one frame
    for b in BOARDS:
        p = r.probe(b)
        assert p["levels"] == [0] * 8 and p["nmt"] == "STOPPED" and (p["pwm"] is None or not any(p["pwm"]))
    frames = r.tick(4)
    assert all(PROTO.state_name(status_of(frames, b)) == "STOPPED" for b in BOARDS)
    assert [f.kind for f in frames] == ["status"] * 4


def reset_and_pre_operational(r: Run) -> None:
    start_all(r)
    r.send(1, PROTO.duty(1, [80] * 8, 1))
    r.send(2, PROTO.duty(2, [80] * 8, 1))
    r.send(3, PROTO.nmt("RESET_NODE", 1))
    p = r.probe(1)
    assert p["levels"] == [0] * 8 and p["nmt"] == "PRE_OPERATIONAL" and p["counters"]["applied"] == 1
    frames = r.tick(4)
    assert [(f.kind, PROTO.state_name(f)) for f in frames if f.board == 1] == [
        ("heartbeat", "BOOTUP"), ("status", "PRE_OPERATIONAL")]
    r.send(5, PROTO.nmt("PRE_OPERATIONAL", 2))
    r.send(6, PROTO.duty(2, [80] * 8, 2))
    p = r.probe(2)
    assert p["levels"] == [0] * 8 and p["output"] == "PRE_OPERATIONAL" and p["counters"]["ignored"] == 1


def hardware_fault_turns_the_board_off(r: Run) -> None:
    start_all(r)
    r.send(1, PROTO.duty(4, [70] * 8, 1))
    r.fault(4, "overtemp")
    frames = r.tick(2)
    s = status_of(frames, 4)
    assert PROTO.state_name(s) == "FAULT_OFF" and PROTO.faults(s) == ["overtemp"] and r.probe(4)["levels"] == [0] * 8
    r.send(3, PROTO.duty(4, [70] * 8, 2))                 # applied (acknowledged), but off
    p = r.probe(4)
    assert p["levels"] == [0] * 8 and p["counters"]["applied"] == 2
    r.fault(4)
    r.send(4, PROTO.duty(4, [70] * 8, 3))
    assert r.probe(4)["levels"] == [70] * 8 and PROTO.state_name(status_of(r.tick(5), 4)) == "ACTIVE"


SCENARIOS = [start_and_stop, duty_on_the_right_channels, wrong_counter_rejected_and_counted,
             wrong_length_and_kind_rejected_and_counted, unknown_ids_rejected_and_counted, watchdog_off_after_100_ms,
             status_and_heartbeat_timing, stop_within_one_frame, reset_and_pre_operational,
             hardware_fault_turns_the_board_off]


def run(scenario, impl: str) -> Run:
    r = Run(impl)
    try:
        scenario(r)
    finally:
        r.close()
    return r


@pytest.mark.parametrize("impl", IMPLEMENTATIONS)
@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.__name__)
def test_scenario(scenario, impl):
    run(scenario, impl)


def without_pwm(observed):
    return [o[:5] + o[6:] if o[0] == "P" else o for o in observed]


def test_the_emulator_and_the_firmware_core_give_the_same_frames_and_outputs():
    for scenario in SCENARIOS:
        python, firmware = run(scenario, "python"), run(scenario, "firmware")
        assert python.script == firmware.script
        assert without_pwm(python.observed) == without_pwm(firmware.observed), scenario.__name__
        pwm = [o[5] for o in firmware.observed if o[0] == "P"]
        levels = [o[4] for o in firmware.observed if o[0] == "P"]
        period = firmware.glove.core.pwm_period
        # duty -> PWM: the nearest compare value, level 127 always on (exact fractions, not the core's)
        assert all(c == (2 * v * period + 127) // 254 for cs, vs in zip(pwm, levels) for c, v in zip(cs, vs))


def parse_check_output(text: str) -> list[list[tuple]]:
    """The check program's output -> observations per scenario (split at each boot)."""
    runs: list[list[tuple]] = []
    for line in text.splitlines():
        if line == "B":
            runs.append([])
        elif line.startswith("T"):
            frames = tuple((int(i, 16), bytes.fromhex(d)) for i, d in (f.split(":") for f in line.split()[1:]))
            runs[-1].append(("T", frames))
        elif line.startswith("P "):
            _, node, nmt, output, levels, pwm, counters = line.split()
            ints = lambda s: tuple(int(x) for x in s.split(","))  # noqa: E731
            runs[-1].append(("P", int(node), int(nmt), int(output), ints(levels), ints(pwm), ints(counters)))
    return runs


@pytest.mark.timeout(300)
def test_the_core_on_the_cortex_m3_under_qemu_gives_the_same_frames_and_outputs(tmp_path):
    """The whole suite's scripts through the core built for the Cortex-M3 (QEMU's stm32vldiscovery,
    an STM32F100: the Blue Pill's family and memory map), then its self-test's verdict."""
    runs = [run(s, "firmware") for s in SCENARIOS]
    script = tmp_path / "script.txt"
    script.write_text("\n".join(line for r in runs for line in r.script) + "\n")
    out = build(CFG, "qemu")
    done = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), "check-qemu", f"BUILD={out}", f"SCRIPT={script}"],
                          capture_output=True, text=True, timeout=240)
    text = done.stdout
    assert "END 0" in text.splitlines(), text + done.stderr
    got = parse_check_output(text)
    assert len(got) == len(runs)
    for r, observed in zip(runs, got):
        assert observed == r.observed

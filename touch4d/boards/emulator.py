"""The motor-board emulator: the reference behaviour for the boards' firmware.

A board boots (heartbeat BOOTUP) into PRE_OPERATIONAL, where duty frames are ignored; NMT START
makes it OPERATIONAL, where each duty frame sets its channels if its Counter is newer than the
last applied one (1..COUNTER_WINDOW ahead, modulo 256: a repeated or old frame must not keep the
watchdog fed; after boot, START or a watchdog trip any Counter is taken, so a restarted controller
is followed). No duty frame applied for more than the watchdog time turns every channel off
(WATCHDOG_OFF) until the next one; NMT STOP turns every channel off and ignores duty frames until
START. It sends its status every status period and at once on a change of state, and its
heartbeat every heartbeat period (the DBC's cycle times). Malformed, unknown and out-of-sequence
frames are ignored and counted by reason (REJECTED). `BoardEmulator` is the pure state machine
(frames in, frames out); `GloveEmulator` runs every board of a glove on one python-can bus, in a
thread. The firmware's core (firmware/core) behaves the same, frame for frame
(tests/test_boards_conformance.py); `make_glove_emulator` picks either by name.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import Counter

import can

from touch4d.boards.config import Board, GloveCan
from touch4d.boards.protocol import FAULT_NAMES, Frame, FrameError, GloveProtocol

log = logging.getLogger("touch4d.boards.emulator")

HARDWARE_FAULTS = ("overtemp", "overcurrent", "undervoltage")
COUNTER_WINDOW = 127  # a duty frame's Counter may be 1..127 ahead of the last applied one
# Why a board rejects a frame (its counters); the first four are "malformed". A status frame's
# BadFrames counts them all.
MALFORMED = ("bad_length", "bad_frame_type", "bad_command", "error_frame")
REJECTED = MALFORMED + ("unknown", "bad_counter")
# The thread blocks on the bus until a frame arrives or a board is due (its watchdog, status or
# heartbeat), but never longer than this: bounds how long remove/restore/stop wait for it.
MAX_WAIT_S = 0.05


class BoardEmulator:
    """One motor board: its NMT state, channel levels, watchdog and counters."""

    def __init__(self, protocol: GloveProtocol, board: Board, cfg: GloveCan, now: float):
        self.protocol = protocol
        self.id = board.id
        self.channels = board.channels
        self.watchdog_s = cfg.board_watchdog_s
        self.status_period = protocol.period_s("status", board.id)
        self.heartbeat_period = protocol.period_s("heartbeat", board.id)
        self.counters: Counter = Counter()
        self.hardware_faults: set[str] = set()
        self._pending: list[can.Message] = []
        self.boot(now)

    def boot(self, now: float) -> None:
        """Power up: every channel off, boot-up heartbeat, then PRE_OPERATIONAL."""
        self.levels = [0] * self.channels
        self.nmt_state = "PRE_OPERATIONAL"
        self.watchdog_tripped = False
        self.last_counter = 0
        self.counter_sync = True  # the next duty frame may carry any Counter
        self.last_duty_at = now
        self.bad_since_status = False
        self._pending = [self.protocol.heartbeat(self.id, "BOOTUP")]
        self._last_output = self.output_state()
        self._next_status = now
        self._next_heartbeat = now + self.heartbeat_period

    def output_state(self) -> str:
        if self.nmt_state == "STOPPED":
            return "STOPPED"
        if self.nmt_state == "PRE_OPERATIONAL":
            return "PRE_OPERATIONAL"
        if self.hardware_faults:
            return "FAULT_OFF"
        if self.watchdog_tripped:
            return "WATCHDOG_OFF"
        return "ACTIVE" if any(self.levels) else "IDLE"

    def faults(self) -> set[str]:
        out = set(self.hardware_faults)
        if self.watchdog_tripped:
            out.add("watchdog")
        if self.bad_since_status:
            out.add("bad_frame")
        return out

    def bad_frame(self, reason: str) -> None:
        """Count a rejected frame (`reason` one of REJECTED); the next status flags it."""
        self.counters[reason] += 1
        if reason in MALFORMED:
            self.counters["malformed"] += 1
        self.bad_since_status = True

    def all_off(self) -> None:
        """Every channel off (what the firmware does on an internal fault)."""
        self.levels = [0] * self.channels

    def handle(self, frame: Frame, now: float) -> None:
        """Apply one decoded frame addressed to this board (or broadcast)."""
        if frame.kind == "nmt":
            command = frame.signals["Command"]
            self.counters["nmt"] += 1
            if command == 1:
                self.nmt_state = "OPERATIONAL"
                self.last_duty_at = now
                self.counter_sync = True
            elif command == 2:
                self.nmt_state = "STOPPED"
                self.levels = [0] * self.channels
            elif command == 0x80:
                self.nmt_state = "PRE_OPERATIONAL"
                self.levels = [0] * self.channels
            elif command == 0x81:
                self.boot(now)
        elif frame.kind == "duty":
            if self.nmt_state != "OPERATIONAL":
                self.counters["ignored"] += 1
                return
            counter = frame.signals["Counter"]
            if not self.counter_sync and not 1 <= (counter - self.last_counter) % 256 <= COUNTER_WINDOW:
                self.bad_frame("bad_counter")
                return
            self.counters["applied"] += 1
            self.last_duty_at = now
            self.watchdog_tripped = False
            self.counter_sync = False
            self.last_counter = counter
            self.levels = [0] * self.channels if self.hardware_faults else GloveProtocol.levels(frame, self.channels)

    def next_due(self) -> float:
        """When `tick` next has work without a frame arriving: a pending frame, watchdog, status or heartbeat."""
        if self._pending:
            return -float("inf")
        due = min(self._next_status, self._next_heartbeat)
        if self.nmt_state == "OPERATIONAL" and not self.watchdog_tripped:
            due = min(due, self.last_duty_at + self.watchdog_s)
        return due

    def tick(self, now: float) -> list[can.Message]:
        """Watchdog, periodic frames and status on change; the frames to send now."""
        if self.nmt_state == "OPERATIONAL" and not self.watchdog_tripped and now - self.last_duty_at > self.watchdog_s:
            # Safety: no command within the watchdog time -> every channel off.
            self.levels = [0] * self.channels
            self.watchdog_tripped = True
            self.counter_sync = True
            self.counters["watchdog_trips"] += 1
        if self.hardware_faults and any(self.levels):
            self.levels = [0] * self.channels
        out, self._pending = self._pending, []
        state = self.output_state()
        if state != self._last_output or now >= self._next_status:
            active = sum(1 << c for c, v in enumerate(self.levels) if v)
            out.append(self.protocol.status(self.id, state, self.faults(), self.last_counter, active,
                                            sum(self.counters[r] for r in REJECTED)))
            self.bad_since_status = False
            self._last_output = state
            self._next_status = now + self.status_period
        if now >= self._next_heartbeat:
            out.append(self.protocol.heartbeat(self.id, self.nmt_state))
            self._next_heartbeat = now + self.heartbeat_period
        return out


class GloveEmulator:
    """Every board of a glove on one python-can bus; `start()` runs it in a thread."""

    def __init__(self, cfg: GloveCan, bus: can.BusABC | None = None, interface: str | None = None,
                 channel: str | None = None, clock=time.monotonic):
        self.cfg = cfg
        self.protocol = GloveProtocol(cfg)
        self.clock = clock
        self._own_bus = bus is None
        self.bus = bus if bus is not None else can.Bus(interface=interface or cfg.interface,
                                                       channel=channel or cfg.channel, bitrate=cfg.bitrate)
        now = clock()
        self.boards = {b.id: self._make_board(b, now) for b in cfg.boards}
        self.removed: set[int] = set()
        self.counters: Counter = Counter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _make_board(self, board: Board, now: float):
        """One board of the glove (a subclass may run another implementation of it)."""
        return BoardEmulator(self.protocol, board, self.cfg, now)

    def levels(self, board_id: int) -> list[int]:
        """Current duty levels of a board's channels."""
        return list(self.boards[board_id].levels)

    def motor_levels(self) -> list[int]:
        """Current level of every motor of the glove, in glove file order."""
        return [self.boards[b].levels[c] for b, c in zip(self.cfg.motor_board, self.cfg.motor_channel)]

    def remove(self, board_id: int) -> None:
        """Unplug a board: it stops receiving and answering."""
        self.removed.add(board_id)

    def restore(self, board_id: int) -> None:
        """Plug a removed board back in: it boots again."""
        self.removed.discard(board_id)
        self.boards[board_id].boot(self.clock())

    def _live(self):
        return [b for bid, b in self.boards.items() if bid not in self.removed]

    def process(self, msg: can.Message, now: float) -> None:
        """Hand one received message to the boards it concerns; count what is malformed or unknown."""
        self.counters["received"] += 1
        try:
            frame = self.protocol.decode(msg)
        except FrameError as exc:
            self.counters["malformed"] += 1
            log.debug("malformed frame 0x%x: %s", msg.arbitration_id, exc)
            targets = self._live()
            if not msg.is_error_frame and not msg.is_extended_id:
                kind = self.protocol.decode_kind(msg.arbitration_id)
                if kind is not None and kind[0] == "duty":
                    targets = [b for b in targets if b.id == kind[1]]
                elif kind is not None and kind[0] != "nmt":
                    targets = []
            for b in targets:
                b.bad_frame(exc.reason)
            return
        if frame is None:
            self.counters["unknown"] += 1
            for b in self._live():
                b.bad_frame("unknown")
            return
        if frame.kind == "nmt":
            for b in self._live():
                if frame.board in (0, b.id):
                    b.handle(frame, now)
        elif frame.kind == "duty" and frame.board not in self.removed:
            self.boards[frame.board].handle(frame, now)

    def poll(self, now: float) -> list[can.Message]:
        """Tick every present board; the frames they send now."""
        out = []
        for b in self._live():
            out.extend(b.tick(now))
        return out

    def next_wait(self, now: float) -> float:
        """How long the thread may block on the bus before a board is due (at most MAX_WAIT_S)."""
        due = min((b.next_due() for b in self._live()), default=now + MAX_WAIT_S)
        return min(max(due - now, 0.0), MAX_WAIT_S)

    def step(self, timeout: float | None = None) -> None:
        """Receive what arrived (waiting up to `timeout`, by default until a board is due), tick and
        send: one round of the thread."""
        if timeout is None:
            timeout = self.next_wait(self.clock())
        msg = self.bus.recv(timeout=timeout)
        while msg is not None:
            self.process(msg, self.clock())
            msg = self.bus.recv(timeout=0)
        for frame in self.poll(self.clock()):
            try:
                self.bus.send(frame, timeout=self.cfg.send_timeout_s)
                self.counters["sent"] += 1
            except can.CanError as exc:
                self.counters["send_errors"] += 1
                log.debug("send failed: %s", exc)

    def start(self) -> "GloveEmulator":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="glove-emulator", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.step()
            except can.CanError as exc:  # a closed or failed bus: keep the thread alive, retry
                self.counters["bus_errors"] += 1
                log.warning("emulator bus error: %s", exc)
                self._stop.wait(0.05)
            except Exception:  # noqa: BLE001 - fail safe: a dead loop would leave its motors running
                self.counters["internal_errors"] += 1
                log.exception("emulator step failed: every channel off")
                self.all_off()
                self._stop.wait(0.05)

    def all_off(self) -> None:
        """Every channel of every board off (what a board's firmware does on an internal fault)."""
        for b in self.boards.values():
            b.all_off()

    def stop(self) -> None:
        """Stop the thread and close the bus if this emulator opened it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._own_bus:
            self.bus.shutdown()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


# Board emulators by name: the motor node's `board_emulator` parameter and `touch4d glove emulate`.
EMULATORS = {
    "python": "touch4d.boards.emulator:GloveEmulator",
    "firmware": "touch4d.boards.firmware:FirmwareGloveEmulator",  # the C core, built for the host (when picked)
}


def make_glove_emulator(kind: str, cfg: GloveCan, **kwargs) -> GloveEmulator:
    """The glove emulator named `kind` (a key of EMULATORS); kwargs go to its constructor."""
    from touch4d.targets import load_target

    if kind not in EMULATORS:
        raise ValueError(f"board emulator {kind!r}: expected one of {sorted(EMULATORS)}")
    return load_target(EMULATORS[kind])(cfg, **kwargs)


__all__ = ["BoardEmulator", "GloveEmulator", "HARDWARE_FAULTS", "FAULT_NAMES", "COUNTER_WINDOW", "MALFORMED",
           "REJECTED", "EMULATORS", "make_glove_emulator"]

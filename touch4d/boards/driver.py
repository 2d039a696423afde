"""The motor-side logic: what to send to the boards, and what the boards' answers mean.

No I/O here: the motor node feeds commands, stops, received frames and the time in, and sends
the frames `outgoing` returns. Rules:
- a board's duty frame goes out at once when its duties changed, but never sooner than
  `CHANGE_GAP` refresh periods after its previous change frame (later ones wait for the tick);
- every refresh tick (refresh_hz), each board is sent again unless it got a change frame within
  the last `REFRESH_AGE` periods, so the boards' watchdogs stay fed and a lost or failed frame is
  retried. A refresh needs REFRESH_AGE periods without a change, in which 2 x REFRESH_AGE change
  frames could have gone, so in the long run a board gets at most 1 / CHANGE_GAP frames per
  period (`FRAMES_PER_PERIOD`, counted by busload.py); a single period can hold 3;
- the output's fail-safe rules are touch4d.hapticoutput's `OutputGuard` (`guard`), as for every
  haptic output: no `tactile/motors` within `watchdog_s` -> every duty 0; a command older than
  `command_max_age_s` when it arrives (its age from its own stamp, so PC and Pi clocks must be
  NTP-synchronised; 0 turns the check off) is stale: it turns every motor off, never on, and does
  not feed the watchdog; the study's gate closed (`gate`) -> every duty 0;
- a stop -> NMT STOP at once, every duty 0, commands ignored for `stop_hold_s`, then NMT START
  (a momentary stop); `stop_hold_s` infinite latches the stop until the node restarts;
- a board heard in a non-operational NMT state is sent START (STOP during a stop hold), at most
  every `RESTART_PERIOD_S`; a board silent for `board_timeout_s` is reported offline.

While every motor is off and every board has been sent that (nothing to change, no stop hold,
no NMT start due), `refresh_period` is that of `idle_refresh_hz`: zeros need feeding only so that
the boards' watchdogs do not trip, and a command still goes out at once.

Idle costs little: the duties are computed again only on an input (command, stop) or when time
alone can change them (the watchdog, the end of a stop hold, the thermal limit), and each board's
frames are encoded once (see `DutyFrames`), so a steady board is refreshed with the same objects.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple

import can
import numpy as np

from touch4d.boards.config import GloveCan
from touch4d.boards.duty import (
    ThermalState, duty_to_levels, intensity_to_duty, levels_to_duty, thermal_deadline, thermal_limit,
)
from touch4d.boards.protocol import Frame, GloveProtocol
from touch4d.hapticoutput import HapticOutput, OutputGuard

RESTART_PERIOD_S = 0.1
CHANGE_GAP = 0.5     # periods between two change frames of one board
REFRESH_AGE = 0.8    # periods since a board's last change frame before a tick refreshes it
FRAMES_PER_PERIOD = 1 / CHANGE_GAP
FRAMES_KEPT = 1024   # duty frames kept per board (one steady pattern's 256 counters fit, and some more)


class Outgoing(NamedTuple):
    """A frame to send: board id (0 for NMT), the message, the duty levels it carries, sent for a change."""

    board: int
    msg: can.Message
    levels: tuple = ()
    change: bool = False


@dataclass
class BoardView:
    """What the controller knows of one board."""

    id: int
    channels: int
    motors: np.ndarray          # motor index per used channel
    motor_channels: np.ndarray  # channel of each of those motors
    sent_levels: tuple | None = None
    last_change_sent: float = -np.inf
    counter: int = 0
    last_heard: float | None = None
    last_frame_stamp: float = 0.0
    nmt_state: str = "UNKNOWN"
    output_state: str = "UNKNOWN"
    board_faults: list = field(default_factory=list)
    acked_counter: int | None = None
    frames_since_status: int = 0  # duty frames sent since the board's last status
    ack_stale: bool = False       # the board's LastCounter did not move although frames went out
    online: bool | None = None  # None until heard or the start grace (board_timeout_s) ends
    last_nmt_at: float = -np.inf
    send_failures: int = 0


class DutyFrames:
    """The duty frames of one board, each part encoded by cantools once.

    The DBC gives the counter and the channels disjoint bits, so a frame is the bitwise OR of the
    encoding of its levels (counter 0; once per change of levels) and that of its counter (levels 0;
    once per counter value). Each (levels, counter) frame is kept as the can.Message to send: a
    steady board is refreshed with the same objects, encoding nothing.
    """

    def __init__(self, protocol: GloveProtocol, board: int, channels: int):
        self.protocol, self.board = protocol, board
        self._zero = (0,) * channels
        empty = protocol.duty(board, self._zero, 0)
        self._id, self._length = empty.arbitration_id, len(empty.data)
        self._counters: dict[int, int] = {}
        self._levels: dict[tuple, int] = {}
        self._frames: dict[tuple, can.Message] = {}
        for counter in range(256):   # every counter part up front: no encoding in the loop for it
            self._bits(self._counters, counter, self._zero, counter)

    def _bits(self, cache: dict, key, levels: tuple, counter: int) -> int:
        bits = cache.get(key)
        if bits is None:
            if len(cache) >= FRAMES_KEPT:
                cache.clear()
            bits = cache[key] = int.from_bytes(self.protocol.duty(self.board, levels, counter).data, "little")
        return bits

    def frame(self, levels: tuple, counter: int) -> can.Message:
        """The duty frame carrying `levels` (one per channel) and `counter`."""
        msg = self._frames.get((levels, counter))
        if msg is None:
            bits = self._bits(self._levels, levels, levels, 0) | self._bits(self._counters, counter, self._zero, counter)
            if len(self._frames) >= FRAMES_KEPT:
                self._frames.clear()
            msg = self._frames[(levels, counter)] = can.Message(
                arbitration_id=self._id, data=bits.to_bytes(self._length, "little"), is_extended_id=False)
        return msg


class MotorDriver(HapticOutput):
    """Decides the duty frames and NMT commands for every board of one glove: the "can" HapticOutput."""

    def __init__(self, cfg: GloveCan, protocol: GloveProtocol | None = None, now: float = 0.0):
        self.cfg = cfg
        self.protocol = protocol or GloveProtocol(cfg)
        self.names = list(cfg.motor_names)
        self._index = {n: k for k, n in enumerate(self.names)}
        self._names_cache: tuple[tuple, np.ndarray, np.ndarray] | None = None
        m = len(self.names)
        self.duty = np.zeros(m)            # after the guard and the thermal limit: what is to be sent
        self.thermal = ThermalState.initial(m)
        self._restart_pending = True  # the first refresh tick broadcasts NMT START
        self.watchdog_off = True
        self.errors: Counter = Counter()
        self.guard = OutputGuard(m, cfg.watchdog_s, cfg.command_max_age_s, cfg.stop_hold_s, counts=self.errors)
        self.period = 1.0 / cfg.refresh_hz
        board_of = np.asarray(cfg.motor_board)
        channel_of = np.asarray(cfg.motor_channel)
        self.boards = {}
        self._frames: dict[int, DutyFrames] = {}
        for b in cfg.boards:
            idx = np.flatnonzero(board_of == b.id)
            self.boards[b.id] = BoardView(b.id, b.channels, idx, channel_of[idx])
            self._frames[b.id] = DutyFrames(self.protocol, b.id, b.channels)
        self._started = now
        self._valid_until = -np.inf     # the duties hold until then, unless an input comes (update)
        self._levels: dict[int, tuple] = {}   # each board's levels for the current duties

    # -- inputs -------------------------------------------------------------------------------

    @property
    def intensity(self) -> np.ndarray:
        return self.guard.intensity

    @property
    def last_command_at(self) -> float | None:
        return self.guard.last_command_at

    @property
    def stop_until(self) -> float:
        return self.guard.stop_until

    def is_stale(self, age: float | None) -> bool:
        """Whether a command `age` seconds old (from its own stamp; None: unknown) is too old to use."""
        return self.guard.is_stale(age)

    def play(self, intensity, now: float, age: float | None = None) -> None:
        """A command in glove file order (HapticOutput)."""
        self.command(self.names, intensity, now, age)

    def off(self, now: float) -> None:
        """Every motor off now (HapticOutput): `silence`."""
        self.silence(now)

    def gate(self, open_: bool, now: float) -> None:
        """The study's gate: closed, every duty 0 from the next `outgoing`; open, the held command if fresh."""
        if self.guard.set_gate(open_, now):
            self._valid_until = -np.inf

    def command(self, names, intensity, now: float, age: float | None = None) -> None:
        """A `tactile/motors` command: intensity per named motor (unnamed motors go to 0).

        `age`: how old the command was when it arrived (see `is_stale`); a stale one only turns
        every motor off, so a command delayed by a stall cannot buzz the motors after it.
        """
        key = tuple(names)
        if self._names_cache is None or self._names_cache[0] != key:
            known = [(i, self._index[n]) for i, n in enumerate(key) if n in self._index]
            unknown = len(key) - len(known)
            if unknown:
                self.errors["unknown_motor"] += unknown
            src = np.array([i for i, _ in known], dtype=np.int64)
            dst = np.array([k for _, k in known], dtype=np.int64)
            self._names_cache = (key, src, dst)
        _, src, dst = self._names_cache
        values = np.zeros(len(self.names))
        values[dst] = np.asarray(intensity, dtype=np.float64)[src]
        if self.guard.command(values, now, age):   # False: a stop's hold ignored it
            self._valid_until = -np.inf

    def silence(self, now: float) -> None:
        """The commands' source is gone (the broker died): every motor off now, as the watchdog
        would after `watchdog_s`; the next command turns them on again."""
        self.guard.silence()
        self._valid_until = -np.inf

    def stop(self, now: float) -> can.Message:
        """Safety stop: every duty 0 and commands ignored for stop_hold_s (inf: until restart);
        returns the NMT STOP to send first."""
        self.guard.stop(now)
        self._valid_until = -np.inf
        self._restart_pending = True
        for b in self.boards.values():
            b.last_nmt_at = now
        return self.protocol.nmt("STOP", 0)

    def receive(self, msg: can.Message, frame: Frame | None, now: float) -> None:
        """A decoded frame from the bus (None: an id the glove does not use)."""
        if frame is None:
            self.errors["unknown_rx"] += 1
            return
        if frame.kind not in ("status", "heartbeat") or frame.board not in self.boards:
            return  # another controller's frames, or our own echoed
        b = self.boards[frame.board]
        b.last_heard = now
        b.last_frame_stamp = msg.timestamp or 0.0
        if frame.kind == "heartbeat":
            b.nmt_state = GloveProtocol.state_name(frame)
        else:
            b.output_state = GloveProtocol.state_name(frame)
            b.board_faults = GloveProtocol.faults(frame)
            acked = frame.signals["LastCounter"]
            # Frames went out but the board applied none: it does not receive us (or ignores us).
            b.ack_stale = (b.frames_since_status >= 3 and acked == b.acked_counter
                           and b.output_state not in ("STOPPED", "PRE_OPERATIONAL"))
            b.acked_counter = acked
            b.frames_since_status = 0
            if b.output_state in ("STOPPED", "PRE_OPERATIONAL"):
                b.nmt_state = b.output_state
            elif b.nmt_state in ("UNKNOWN", "STOPPED", "PRE_OPERATIONAL", "BOOTUP"):
                b.nmt_state = "OPERATIONAL"

    # -- outputs ------------------------------------------------------------------------------

    def update(self, now: float) -> np.ndarray:
        """The duty of every motor: the guard (stop, gate, stale, watchdog), intensity -> duty, thermal
        limit; computed again only after an input or once time alone can change it."""
        if now < self._valid_until:
            return self.duty
        silent = self.guard.silent(now)
        if silent and not self.watchdog_off and now >= self.stop_until:
            self.errors["watchdog_off"] += 1
        self.watchdog_off = silent
        held = self.guard.reason(now)
        wanted = np.zeros(len(self.names)) if held else intensity_to_duty(self.intensity, self.cfg.duty)
        duty, self.thermal = thermal_limit(wanted, self.thermal, now, self.cfg.thermal)
        self._valid_until = min(self.guard.expires(now), thermal_deadline(wanted, self.thermal, now, self.cfg.thermal))
        if not self._levels or not np.array_equal(duty, self.duty):
            motor_levels = duty_to_levels(duty)
            self._levels = {b: self.board_levels(b, motor_levels) for b in self.boards}
        self.duty = duty
        return duty

    def refresh_period(self, now: float) -> float:
        """Seconds to the next refresh tick: 1 / refresh_hz, or 1 / idle_refresh_hz while all is off
        and sent (see the module doc)."""
        self.update(now)
        if (self._restart_pending or now < self.stop_until or self.duty.any()
                or any(b.sent_levels != self._levels[b.id] for b in self.boards.values())):
            return self.period
        return 1.0 / self.cfg.idle_refresh_hz

    def board_levels(self, board_id: int, motor_levels: np.ndarray | None = None) -> tuple:
        """The duty levels of one board's channels (from every motor's levels, if already computed)."""
        b = self.boards[board_id]
        motor_levels = duty_to_levels(self.duty) if motor_levels is None else np.asarray(motor_levels)
        levels = np.zeros(b.channels, dtype=np.int64)
        levels[b.motor_channels] = motor_levels[b.motors]
        return tuple(levels.tolist())

    def outgoing(self, now: float, refresh: bool = False, force: bool = False) -> list[Outgoing]:
        """Frames to send now.

        `refresh=False` (on a command): only changed boards; `refresh=True` (the refresh tick):
        also every board due for a refresh, and any NMT start/stop due.
        `force` (a stop, shutdown): every board now, whatever its last frame's age.
        """
        self.update(now)
        out: list[Outgoing] = []
        stopped = now < self.stop_until
        if refresh:
            if self._restart_pending and not stopped:
                self._restart_pending = False
                out.append(Outgoing(0, self.protocol.nmt("START", 0)))
                for b in self.boards.values():
                    b.last_nmt_at = now
            for b in self.boards.values():
                want_stop = stopped and b.nmt_state == "OPERATIONAL"
                want_start = not stopped and b.nmt_state in ("BOOTUP", "PRE_OPERATIONAL", "STOPPED")
                if (want_stop or want_start) and now - b.last_nmt_at >= RESTART_PERIOD_S:
                    b.last_nmt_at = now
                    self.errors["nmt_restart" if want_start else "nmt_restop"] += 1
                    out.append(Outgoing(0, self.protocol.nmt("STOP" if want_stop else "START", b.id)))
        gap, age = CHANGE_GAP * self.period - 1e-9, REFRESH_AGE * self.period - 1e-9
        for b in self.boards.values():
            levels = self._levels[b.id]
            change = levels != b.sent_levels
            if force or (change and now - b.last_change_sent >= gap) or (refresh and now - b.last_change_sent >= age):
                b.counter = (b.counter + 1) & 0xFF
                out.append(Outgoing(b.id, self._frames[b.id].frame(levels, b.counter), levels, change))
        return out

    def sent(self, out: Outgoing, now: float) -> None:
        """A frame from `outgoing` went out."""
        if out.board == 0:
            return
        b = self.boards[out.board]
        b.frames_since_status += 1
        if out.change:
            b.last_change_sent = now
        b.sent_levels = out.levels
        b.send_failures = 0

    def failed(self, out: Outgoing, kind: str) -> None:
        """A frame from `outgoing` could not be sent (kind: send_error, tx_queue_full, bus_off, ...).

        The board's duties stay unsent, so the next tick sends them again.
        """
        self.errors[kind] += 1
        if out.board:
            self.boards[out.board].send_failures += 1

    def check_boards(self, now: float) -> list[str]:
        """Update which boards are online; returns a line per board that changed, for the log."""
        events = []
        for b in self.boards.values():
            heard = b.last_heard is not None and now - b.last_heard <= self.cfg.board_timeout_s
            if heard and b.online is not True:
                events.append(f"board {b.id} online ({b.nmt_state.lower()})")
                b.online = True
            elif not heard and b.online is not False and (b.online or now - self._started > self.cfg.board_timeout_s):
                self.errors["board_offline"] += 1
                events.append(f"board {b.id} not answering for {self.cfg.board_timeout_s} s")
                b.online = False
        return events

    def duties_on_bus(self) -> bool:
        """Whether every board's last sent frame carries the duties to be sent now (as of the last
        `outgoing`)."""
        return bool(self._levels) and all(b.sent_levels == self._levels[b.id] for b in self.boards.values())

    def sent_duty(self) -> np.ndarray:
        """The duty last sent to every motor (0..1, glove file order)."""
        out = np.zeros(len(self.names))
        for b in self.boards.values():
            if b.sent_levels is not None:
                out[b.motors] = levels_to_duty(np.asarray(b.sent_levels)[b.motor_channels])
        return out

    def board_report(self) -> list[dict]:
        """The `boards` field of MotorStatus."""
        out = []
        for b in self.boards.values():
            faults = [] if b.online else ["not_answering"]
            online = bool(b.online)
            faults += list(b.board_faults) if online else []
            if b.send_failures:
                faults.append("send_failing")
            if online and b.ack_stale:
                faults.append("commands_not_acked")
            state = b.nmt_state.lower() if online else "offline"
            if online and b.nmt_state == "OPERATIONAL" and b.output_state not in ("UNKNOWN",):
                state = "operational" if b.output_state in ("ACTIVE", "IDLE") else b.output_state.lower()
            out.append({"id": b.id, "online": online, "faults": faults,
                        "last_frame": float(b.last_frame_stamp), "state": state})
        return out

"""Encode and decode the glove's CAN frames through the cantools database of dbc.py.

Frames are built and read only with `Message.encode(..., strict=True)` / `decode`, never by
packing bytes by hand, so the DBC a firmware author reads is the protocol the code speaks.
Values are raw (duty levels 0..127, state codes), as on the wire.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from types import MappingProxyType

import can
import cantools

from touch4d.boards.config import GloveCan
from touch4d.errors import Touch4dError
from touch4d.boards.dbc import (
    DUTY_LEVELS, FAULT_FLAGS, NMT_COMMANDS, NMT_STATES, OUTPUT_STATES, build_database,
)

NMT_COMMAND_CODES = {v: k for k, v in NMT_COMMANDS.items()}
NMT_STATE_CODES = {v: k for k, v in NMT_STATES.items()}
OUTPUT_STATE_CODES = {v: k for k, v in OUTPUT_STATES.items()}


def _snake(flag: str) -> str:
    """DBC flag name -> fault name: 'BadFrame' -> 'bad_frame'."""
    return re.sub(r"(?<!^)([A-Z])", r"_\1", flag).lower()


FAULT_NAMES = tuple(_snake(f) for f in FAULT_FLAGS)
DECODED_KEPT = 4096  # decoded frames kept: a steady board repeats its 256 duty frames, its status a few


class FrameError(Touch4dError, ValueError):
    """A frame with a known id that does not follow the protocol (length, flags, values).

    `reason` names the fault as the boards count it: 'error_frame', 'bad_frame_type' (remote or
    FD), 'bad_length', 'bad_command' (an unknown NMT command) or 'bad_value' (an unknown state)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class Frame:
    """A decoded glove frame: kind ('nmt', 'duty', 'status', 'heartbeat'), board node id, raw signals
    (read-only: a frame decoded once is handed out again for the same bytes)."""

    kind: str
    board: int
    signals: MappingProxyType


class GloveProtocol:
    """The frames of one glove configuration, by board."""

    def __init__(self, cfg: GloveCan):
        self.cfg = cfg
        self.db = build_database(cfg)
        self._ids: dict[int, tuple[str, int, cantools.database.can.Message]] = {}
        self._messages: dict[tuple[str, int], cantools.database.can.Message] = {}
        self._ids[cfg.ids.stop] = ("nmt", 0, self.db.get_message_by_name("NMT"))
        self._messages[("nmt", 0)] = self._ids[cfg.ids.stop][2]
        for b in cfg.boards:
            for kind, name, base in (("duty", "Duty", cfg.ids.duty), ("status", "Status", cfg.ids.status),
                                     ("heartbeat", "Heartbeat", cfg.ids.heartbeat)):
                message = self.db.get_message_by_name(f"{name}_B{b.id}")
                self._ids[base + b.id] = (kind, b.id, message)
                self._messages[(kind, b.id)] = message
        self._decoded: dict[tuple[int, bytes], Frame] = {}

    def _frame(self, kind: str, board: int, signals: dict) -> can.Message:
        message = self._messages[(kind, board)]
        data = message.encode(signals, scaling=False, strict=True)
        return can.Message(arbitration_id=message.frame_id, data=data, is_extended_id=False)

    def nmt(self, command: str, node: int = 0) -> can.Message:
        """An NMT frame; `nmt("STOP")` is the broadcast stop, `nmt("START", 3)` starts board 3."""
        return self._frame("nmt", 0, {"Command": NMT_COMMAND_CODES[command], "Node": node})

    def duty(self, board: int, levels, counter: int) -> can.Message:
        """The duty frame of one board: one level 0..127 per channel, and the rolling counter."""
        signals = {"Counter": counter & 0xFF}
        signals.update({f"Duty_Ch{c}": int(v) for c, v in enumerate(levels)})
        return self._frame("duty", board, signals)

    def status(self, board: int, state: str, faults=(), last_counter: int = 0, active_mask: int = 0,
               bad_frames: int = 0) -> can.Message:
        """A board's status frame (sent by the board); faults are names of FAULT_NAMES."""
        signals = {"State": OUTPUT_STATE_CODES[state], "LastCounter": last_counter & 0xFF,
                   "ActiveMask": active_mask, "BadFrames": min(bad_frames, 0xFFFF)}
        signals.update({f"Fault_{f}": int(_snake(f) in faults) for f in FAULT_FLAGS})
        return self._frame("status", board, signals)

    def heartbeat(self, board: int, state: str) -> can.Message:
        """A board's CANopen heartbeat with its NMT state."""
        return self._frame("heartbeat", board, {"State": NMT_STATE_CODES[state]})

    def period_s(self, kind: str, board: int) -> float:
        """The DBC's cycle time of one board's frame ('duty', 'status', 'heartbeat'), in seconds."""
        return self._messages[(kind, board)].cycle_time / 1000.0

    def decode_kind(self, frame_id: int) -> tuple[str, int] | None:
        """(kind, board) of a standard frame id of this glove, None if the glove does not use it."""
        known = self._ids.get(frame_id)
        return None if known is None else known[:2]

    def decode(self, msg: can.Message) -> Frame | None:
        """The frame of a received message; None for an id the glove does not use.

        Raises FrameError for a glove id with the wrong length, flags or values.
        """
        if msg.is_error_frame:
            raise FrameError("error frame", "error_frame")
        known = self._ids.get(msg.arbitration_id)
        if known is None or msg.is_extended_id:
            return None
        kind, board, message = known
        if msg.is_remote_frame or msg.is_fd:
            raise FrameError(f"{message.name}: remote or FD frame", "bad_frame_type")
        key = (msg.arbitration_id, bytes(msg.data))
        frame = self._decoded.get(key)
        if frame is None:
            frame = self._decode(kind, board, message, key[1])
            if len(self._decoded) >= DECODED_KEPT:
                self._decoded.clear()
            self._decoded[key] = frame
        return frame

    @staticmethod
    def _decode(kind: str, board: int, message, data: bytes) -> Frame:
        if len(data) != message.length:
            raise FrameError(f"{message.name}: expected {message.length} data bytes, got {len(data)}", "bad_length")
        try:
            signals = MappingProxyType(message.decode(data, decode_choices=False, scaling=False))
        except (cantools.database.DecodeError, ValueError) as exc:
            raise FrameError(f"{message.name}: {exc}", "bad_length") from None
        if kind == "nmt":
            if signals["Command"] not in NMT_COMMANDS:
                raise FrameError(f"NMT: unknown command {signals['Command']}", "bad_command")
            return Frame(kind, signals["Node"], signals)
        if kind == "heartbeat" and signals["State"] not in NMT_STATES:
            raise FrameError(f"{message.name}: unknown NMT state {signals['State']}", "bad_value")
        if kind == "status" and signals["State"] not in OUTPUT_STATES:
            raise FrameError(f"{message.name}: unknown state {signals['State']}", "bad_value")
        return Frame(kind, board, signals)

    @staticmethod
    def levels(frame: Frame, channels: int) -> list[int]:
        """The duty levels of a decoded duty frame, by channel."""
        return [int(frame.signals[f"Duty_Ch{c}"]) for c in range(channels)]

    @staticmethod
    def faults(frame: Frame) -> list[str]:
        """The fault names set in a decoded status frame."""
        return [_snake(f) for f in FAULT_FLAGS if frame.signals[f"Fault_{f}"]]

    @staticmethod
    def state_name(frame: Frame) -> str:
        """The state name of a decoded status or heartbeat frame."""
        names = OUTPUT_STATES if frame.kind == "status" else NMT_STATES
        return names[frame.signals["State"]]


__all__ = ["GloveProtocol", "Frame", "FrameError", "DUTY_LEVELS", "FAULT_NAMES"]

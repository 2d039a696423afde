"""Pose -> pulse as the study server sees it: when each page input arrives and when each frame,
with the controller's intensity it carries, leaves for the page (`touch4d study serve --wire-trace`).

With the page's WebSocket spliced byte for byte (touch4d.web.splice), `page_bytes` and `frame_bytes`
are fed each direction's bytes as they pass and read them into messages with aiohttp's own
WebSocket frame reader, only while a trace is asked for.

The trace is a CSV, one row per message: participant, `in` or `out`, the input's `time` (the page's
clock, ms: it names the input) or the frame's `haptic` (0..1), and the server's monotonic clock (ns).
`pose_to_pulse` pairs each move of a controller (the input that moves it into or out of an object)
with the first frame after it whose intensity follows: the server's share of the latency, without
the network or the page.
"""
from __future__ import annotations

import bisect
import csv
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from aiohttp import WSMessage, WSMsgType
from aiohttp.http import WebSocketReader

from .protocol import MAX_PAGE_MESSAGE, header_span, is_kind

TOUCHING = 0.05   # a frame's haptic above this: the controller plays the touch
_INPUT = re.compile(r'"type"\s*:\s*"input"')
_TIME = re.compile(r'"time"\s*:\s*(-?[0-9][0-9.eE+-]*)')
_HAPTIC = re.compile(rb'"haptic":(-?[0-9][0-9.eE+-]*)')   # the node writes its frames without spaces


class WireTrace:
    """Appends the rows to `path` (buffered: the event loop never waits on the disk for long)."""

    def __init__(self, path: Path):
        self._file = open(path, "w", buffering=1 << 20, newline="")
        self._rows = csv.writer(self._file)

    def page_in(self, participant: str, text: str) -> None:
        """A page's text message, at its arrival: a row when it is an input. Read by pattern, not
        parsed: the trace runs in the server it measures (a JSON parse per message was a third of
        the server's CPU at 16 participants)."""
        now = time.monotonic_ns()
        if _INPUT.search(text, 0, 64) is None:
            return   # not an input (its type comes first, as every page writes it)
        stamp = _TIME.search(text)
        try:
            page_time = float(stamp.group(1)) if stamp is not None else None
        except ValueError:
            return   # not a number ("1e"): the participant's node refuses it, and says why
        if page_time is not None:
            self._rows.writerow((participant, "in", repr(page_time), now))

    def frame_out(self, participant: str, data: bytes) -> None:
        """A binary message for the page, as it leaves: a row when it is a frame (its header read by
        pattern, as `page_in`)."""
        now = time.monotonic_ns()
        if not is_kind(data, "frame"):
            return
        haptic = _HAPTIC.search(data, *header_span(data))
        try:
            level = float(haptic.group(1)) if haptic else 0.0
        except ValueError:
            return
        self._rows.writerow((participant, "out", repr(level), now))

    def page_bytes(self, participant: str) -> Callable[[bytes], None]:
        """A feed for the bytes a page sends (its WebSocket frames, masked): `page_in` for each text
        message as its last byte arrives."""
        def message(msg: WSMessage) -> None:
            if msg.type == WSMsgType.TEXT:
                self.page_in(participant, msg.data)
        return _frames(message, MAX_PAGE_MESSAGE)

    def frame_bytes(self, participant: str) -> Callable[[bytes], None]:
        """A feed for the bytes sent to a page, called once they left: `frame_out` for each binary
        message they complete."""
        def message(msg: WSMessage) -> None:
            if msg.type == WSMsgType.BINARY:
                self.frame_out(participant, msg.data)
        return _frames(message, 0)   # the participant's own node: no limit to its frames

    def close(self) -> None:
        self._file.close()


def _frames(on_message: Callable[[WSMessage], None], max_msg_size: int) -> Callable[[bytes], None]:
    """Bytes of one direction of a WebSocket in, `on_message` per message out (aiohttp's frame reader;
    after a protocol error it reads nothing more: the page's node closes that connection). Its
    message queue is aiohttp's own (3.11 on, an internal module: imported only when a trace is
    asked for), but each message is handed on as the reader completes it (nothing is queued: nobody
    awaits `read()`, and the reader never stalls)."""
    from aiohttp._websocket.reader import WebSocketDataQueue

    class Messages(WebSocketDataQueue):
        def __init__(self):
            super().__init__(None, 1 << 16, loop=None)   # no protocol to pause, no loop: never awaited

        def feed_data(self, data: WSMessage, size: int = 0) -> None:
            on_message(data)

    return WebSocketReader(Messages(), max_msg_size, compress=False, decode_text=True).feed_data


@dataclass(frozen=True)
class Move:
    """A page input that moves the controller into (`touching`) or out of an object."""

    participant: str
    time_ms: float      # the input's `time`
    touching: bool


def pose_to_pulse(trace: Path, moves: list[Move]) -> tuple[list[float], int]:
    """Seconds from each move's input arriving to the first later frame for its participant whose
    haptic follows it (above TOUCHING when touching, 0 when not); and how many moves had none (or
    whose input never arrived)."""
    arrivals: dict[tuple[str, float], int] = {}
    frames: dict[str, list[tuple[int, float]]] = {}
    with open(trace, newline="") as f:
        for participant, way, value, ns in csv.reader(f):
            if way == "in":
                arrivals.setdefault((participant, float(value)), int(ns))
            else:
                frames.setdefault(participant, []).append((int(ns), float(value)))
    latencies, missed = [], 0
    for move in moves:
        t_in = arrivals.get((move.participant, float(move.time_ms)))
        sent = frames.get(move.participant, [])   # in the order they left: by time
        start = len(sent) if t_in is None else bisect.bisect_right(sent, (t_in, float("inf")))
        t_out = next((t for t, haptic in sent[start:] if (haptic > TOUCHING if move.touching else haptic == 0.0)),
                     None)
        if t_out is None:
            missed += 1
        else:
            latencies.append((t_out - t_in) / 1e9)
    return latencies, missed

"""The replay engine: republishes a log's messages with their recorded timing, scaled by a rate.

By default each message is re-stamped as it goes out (`touch4d.log.restamp`): `stamp` = now,
`source_stamp` shifted by the same amount (so latencies measured downstream are this run's), a
fresh per-topic `seq`, and the recorded stamp kept in the header's `recorded_stamp`: live nodes
downstream of a replayed tracker see messages as from a live one (the motor node's stale-command
guard lets them through). With `restamp` off, the recorded bytes go out unchanged, so a replayed
log recorded again is byte-identical.

The log is streamed: the plan comes from the file's summary section when it has one, so the first
message goes out without reading the log through.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from collections import deque
from typing import Callable, Iterator

import zmq

from touch4d.bus import names, transport
from touch4d.bus.config import BusConfig
from touch4d.errors import Touch4dError

from .reader import LogFileError, LogMessage, LogReader
from .restamp import restamp
from touch4d.bus.realtime import raise_thread_priority, reset_thread_priority
from touch4d.bus.transport import bus_context
from .summary import LogSummary, indexed_summary, summarize


@dataclass
class ReplayOptions:
    rate: float = 1.0
    loop: bool = False
    start: float = 0.0                      # seconds from the log's first message
    topics: list[str] | None = None         # None: every topic in the log
    remap: dict[str, str] = field(default_factory=dict)
    restamp: bool = True                    # stamps = now, the recorded stamp kept in recorded_stamp
    realtime: bool = True                   # best-effort SCHED_FIFO for the sending thread


@dataclass
class ReplayStats:
    sent: int = 0
    passes: int = 0
    late_max: float = 0.0                   # worst lateness of a send behind its due time, seconds
    restamp_failed: int = 0                 # payloads sent unchanged: not a message map with a stamp
    realtime: bool = False                  # the sending thread ran with real-time priority
    stopped: bool = False                   # stopped early (Ctrl+C, stop())


def parse_remap(items: list[str] | None) -> dict[str, str]:
    """["a:=b", ...] -> {"a": "b"}; raises ValueError naming a malformed item."""
    out = {}
    for item in items or []:
        src, sep, dst = item.partition(":=")
        if not sep or not src or not dst:
            raise ValueError(f"remap {item!r}: expected FROM:=TO, e.g. hand/pose:=hand/pose_recorded")
        out[src] = dst
    return out


class Plan:
    """A checked replay: the log's summary, the topics to send, what the user named that is not there."""

    def __init__(self, reader: LogReader, options: ReplayOptions) -> None:
        if not 0 < options.rate < math.inf:
            raise LogFileError(f"{reader.path}: --rate must be a finite number > 0, got {options.rate}")
        if not 0 <= options.start < math.inf:
            raise LogFileError(f"{reader.path}: --start must be a finite number >= 0 seconds, got {options.start}")
        # A complete log's index says all a plan needs; only a damaged or unfinished one is read through.
        self.summary: LogSummary = indexed_summary(reader) or summarize(reader.path, recover=reader.recover)
        available = {t.topic for t in self.summary.topics}
        named = list(options.topics) if options.topics is not None else sorted(available)
        self.unknown = [t for t in named if t not in available]
        self.unknown_remaps = [t for t in options.remap if t not in available]
        self.topics = [t for t in named if t in available]
        if not self.topics:
            raise LogFileError(f"{reader.path}: none of the topics to replay are in this log "
                               f"({', '.join(named) or 'none named'}); its topics are: "
                               f"{', '.join(sorted(available)) or '(none)'}")
        self.origin = self.summary.start + int(options.start * 1e9)
        chosen = [t for t in self.summary.topics if t.topic in self.topics]
        last = max(t.last for t in chosen)
        self.duration = max(0.0, (last - self.origin) / 1e9)
        # A loop starts over one mean message interval after the last message (not at the same
        # instant), so a looped stream stays evenly paced; a log of one instant repeats once a second.
        first = max(self.origin, min(t.first for t in chosen))
        count = sum(t.count for t in chosen)
        gap = (last - min(t.first for t in chosen)) / 1e9 / (count - 1) if count > 1 else 0.0
        self.loop_period = max(0.0, (last - first) / 1e9) + gap or 1.0
        if options.start > 0 and last < self.origin:
            raise LogFileError(f"{reader.path}: --start {options.start} s is past the end of the selected "
                               f"messages ({(last - self.summary.start) / 1e9:.3f} s)")

    def warnings(self) -> list[str]:
        out = []
        if self.unknown:
            out.append(f"not in the log, not replayed: {', '.join(self.unknown)}")
        if self.unknown_remaps:
            out.append(f"remapped topics not in the log: {', '.join(self.unknown_remaps)}")
        return out


class Restamper:
    """Re-stamps payloads (see `touch4d.log.restamp`) with a gapless `seq` per published topic."""

    def __init__(self) -> None:
        self._seq: dict[str, int] = {}

    def __call__(self, topic: str, payload: bytes, now: float) -> bytes | None:
        seq = self._seq.get(topic, 0)
        fresh = restamp(payload, now, seq)
        if fresh is not None:
            self._seq[topic] = seq + 1
        return fresh


class _ReadAhead:
    """Messages read from the file ahead of their send time, while the replay would only sleep.

    Reading (a chunk's decompression, record parsing) then never delays a message that is due; at
    most `limit` messages or `max_bytes` of payload wait in memory."""

    def __init__(self, messages: Iterator[LogMessage], limit: int = 20000, max_bytes: int = 64 << 20) -> None:
        self._it = messages
        self._buffer: deque[LogMessage] = deque()
        self._limit, self._max_bytes = limit, max_bytes
        self._bytes = 0
        self._done = False

    def fill(self, clock: Callable[[], float], until: float) -> None:
        while (not self._done and len(self._buffer) < self._limit and self._bytes < self._max_bytes
               and clock() < until):
            self._pull()

    def _pull(self) -> None:
        try:
            msg = next(self._it)
        except StopIteration:
            self._done = True
            return
        self._buffer.append(msg)
        self._bytes += len(msg.data)

    def __iter__(self) -> Iterator[LogMessage]:
        while True:
            if not self._buffer:
                if self._done:
                    return
                self._pull()
                continue
            msg = self._buffer.popleft()
            self._bytes -= len(msg.data)
            yield msg


class Replayer:
    """Sends a planned replay through `send(topic, payload)`, on time; `run` returns when done or stopped."""

    def __init__(self, reader: LogReader, plan: Plan, options: ReplayOptions,
                 send: Callable[[str, bytes], None], *, clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.reader, self.plan, self.options, self.send = reader, plan, options, send
        self.clock, self.sleep = clock, sleep   # injectable: tests replay on a virtual clock
        self.stop_event = threading.Event()
        self.position = 0.0  # seconds into the log (from --start), of the last message sent
        self.stats = ReplayStats()

    def stop(self) -> None:
        self.stop_event.set()

    def _sleep_until(self, due: float, ahead: _ReadAhead) -> bool:
        """Read ahead, then sleep until `due` (clock seconds) in slices so a stop is seen; False if stopped."""
        ahead.fill(self.clock, due - 0.002)
        while not self.stop_event.is_set():
            left = due - self.clock()
            if left <= 0:
                return True
            self.sleep(min(left, 0.05))
        return False

    def run(self, progress: Callable[[Replayer], None] | None = None, progress_interval: float = 0.1) -> ReplayStats:
        """Send every planned message at its due time (looping if asked); returns the stats."""
        if self.options.realtime:
            self.stats.realtime = raise_thread_priority()
        try:
            return self._run(progress, progress_interval)
        finally:
            if self.stats.realtime:
                reset_thread_priority()

    def _run(self, progress, progress_interval: float) -> ReplayStats:
        opts, plan, stats = self.options, self.plan, self.stats
        topics = set(plan.topics)
        restamper = Restamper() if opts.restamp else None
        remap = opts.remap
        next_progress = 0.0
        wall0 = None
        while not self.stop_event.is_set():
            ahead = _ReadAhead(self.reader.messages(topics, start=plan.origin if opts.start > 0 else None))
            if wall0 is None:
                ahead.fill(self.clock, self.clock() + 0.05)  # the first chunks are read before the clock starts
                wall0 = last_rest = self.clock()
            for msg in ahead:
                if self.stop_event.is_set():
                    break
                offset = (msg.log_time - plan.origin) / 1e9
                due = wall0 + offset / opts.rate
                now = self.clock()
                if due > now:
                    if not self._sleep_until(due, ahead):
                        break
                    last_rest = due
                elif now - last_rest > 0.05:
                    # behind schedule for 50 ms (a high --rate): let other threads run a moment
                    self.sleep(0.001)
                    last_rest = self.clock()
                late = self.clock() - due
                if late > stats.late_max:
                    stats.late_max = late
                payload, topic = msg.data, remap.get(msg.topic, msg.topic)
                if restamper is not None:
                    fresh = restamper(topic, payload, time.time())
                    if fresh is None:
                        stats.restamp_failed += 1
                    else:
                        payload = fresh
                self.send(topic, payload)
                stats.sent += 1
                self.position = offset
                if progress is not None and self.clock() >= next_progress:
                    progress(self)
                    next_progress = self.clock() + progress_interval
            else:
                stats.passes += 1
                if not opts.loop:
                    break
                wall0 += plan.loop_period / opts.rate
                continue
            break
        stats.stopped = self.stop_event.is_set()
        if progress is not None:
            progress(self)
        return stats


class BusSender:
    """Publishes raw (topic, payload) frames to the broker, waiting until the broker has subscribed."""

    def __init__(self, bus: BusConfig, *, context: zmq.Context | None = None, timeout: float = 5.0,
                 realtime: bool = True, namespace: str = "") -> None:
        """`namespace`: a log's topics go out under NAMESPACE/ (touch4d.bus.names), so a recording
        made in one namespace replays into another."""
        self._own_context = context is None
        self._namespace = names.check_namespace(namespace)
        self._keys: dict[str, bytes] = {}
        self._context = context or bus_context(realtime)
        # The transport's publisher sees the broker's subscription arrive: then nothing is lost.
        self._sock = transport.publisher(self._context, bus, hwm=0, linger=1000)
        if not transport.await_broker(self._sock, timeout):
            self.close(linger=0)
            raise Touch4dError(f"no bus broker answered at {bus.pub_endpoint} within {timeout:.0f} s "
                               f"(start one with `touch4d launch` or the bus broker command)")

    def __call__(self, topic: str, payload: bytes) -> None:
        key = self._keys.get(topic)
        if key is None:
            key = self._keys[topic] = names.resolve(topic, self._namespace).encode()
        self._sock.send_multipart([key, payload], copy=len(payload) < 4096)

    def close(self, linger: int | None = None) -> None:
        self._sock.close(linger)
        if self._own_context:
            self._context.term()

"""The recording engine: a dedicated subscriber thread stamps messages, a writer thread logs them.

The subscriber socket has no receive high-water mark, so a burst queues in memory instead of being
dropped, and its thread does nothing but receive and stamp (receive times stay accurate while the
writer compresses). The writer flushes a chunk at least every `flush_interval` seconds, so a
recorder killed with SIGKILL leaves a file from which everything older than that is recovered.
"""
from __future__ import annotations

import errno
import json
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import zmq

from touch4d.bus import names, transport
from touch4d.bus.config import BusConfig
from touch4d.bus.realtime import raise_thread_priority
from touch4d.bus.transport import INTERNAL_PREFIX, bus_context
from touch4d.errors import Touch4dError

from .writer import LogWriter, WallClock


def _wanted(topic: bytes, wanted: set[bytes]) -> bool:
    """Exact topics asked for (a subscription matches by prefix), or every topic but the bus's own."""
    return topic in wanted if wanted else not topic.startswith(INTERNAL_PREFIX)


HEARTBEAT = b"node/heartbeat"
WRITE_PERIOD_S = 0.05   # the writer thread looks for messages this often when idle: it wakes (and takes
                        # the interpreter lock from the node's thread) 20 times a second, not 100; a crash
                        # loses at most this more than the flush interval


def _size(n: int) -> str:
    """Bytes for people: 512 B, 6.1 kB, 12.17 MB, 1.02 GB."""
    if n < 1000:
        return f"{n} B"
    return f"{n / 1e3:.1f} kB" if n < 1e6 else f"{n / 1e6:.2f} MB" if n < 1e9 else f"{n / 1e9:.2f} GB"


@dataclass
class RecordingReport:
    """What a finished recording holds, for the end-of-recording report (and the file's metadata)."""

    path: str
    counts: dict[str, int]
    lost: dict[str, int]                       # topic -> messages missing from its seq sequence
    malformed: dict[str, int]                  # topic -> payloads that were not message maps
    missing: list[str] = field(default_factory=list)   # topics asked for that never arrived
    duration: float = 0.0
    bytes: int = 0                             # the messages' payloads, uncompressed
    file_bytes: int = 0                        # the log file on disk (compressed, with index and schemas)
    error: str = ""

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def metadata(self) -> dict[str, str]:
        return {"counts": json.dumps(self.counts), "lost": json.dumps(self.lost),
                "malformed": json.dumps(self.malformed), "missing": json.dumps(self.missing),
                "duration": f"{self.duration:.3f}"}

    def lines(self) -> list[str]:
        out = [f"recorded {self.total} messages ({_size(self.file_bytes)} on disk, {_size(self.bytes)} of messages "
               f"uncompressed) on {len(self.counts)} topic(s) in {self.duration:.1f} s to {self.path}"]
        for topic, n in sorted(self.counts.items()):
            extra = f", {self.lost[topic]} lost (seq gaps)" if self.lost.get(topic) else ""
            extra += f", {self.malformed[topic]} not messages" if self.malformed.get(topic) else ""
            out.append(f"  {topic}: {n}{extra}")
        out.append(f"seq gaps: {sum(self.lost.values())} message(s) lost before the recorder"
                   if self.lost else "seq gaps: none")
        if self.missing:
            out.append(f"no messages on: {', '.join(self.missing)}")
        if self.error:
            out.append(f"error: {self.error}")
        return out


class Recorder:
    """Records `topics` (all when empty) from the bus into the MCAP file `path`. In `namespace`:
    its topics (all: everything under NAMESPACE/ and the global ones), written by their names
    relative to it, so the log replays into any namespace (touch4d.bus.names)."""

    def __init__(self, bus: BusConfig, path: str | os.PathLike, topics: list[str] | None = None, *,
                 flush_interval: float = 0.5, context: zmq.Context | None = None,
                 chunk_size: int = 1 << 20, realtime: bool = True, namespace: str = "") -> None:
        self.bus = bus
        self.path = os.fspath(path)
        self.topics = list(dict.fromkeys(topics or []))
        self.namespace = names.check_namespace(namespace)
        self._wanted = {names.resolve(t, self.namespace).encode() for t in self.topics}
        self.flush_interval = flush_interval
        self.chunk_size = chunk_size
        self.realtime = realtime
        self._own_context = context is None
        self._context = context or bus_context(realtime)
        self._queue: deque[tuple[str, bytes, int]] = deque()   # (topic, payload, receive time ns)
        self._names: dict[bytes, str] = {}
        self._resolved: dict[str, bytes] = {}   # an offered topic -> its name on the bus
        self._stopping = threading.Event()
        self._received = threading.Event()
        self._threads: list[threading.Thread] = []
        self._clock = WallClock()
        self._writer: LogWriter | None = None
        self._started = 0.0
        self.error = ""
        self.received = 0
        self.offered = 0   # handed over in-process (offer)

    def start(self, timeout: float = 5.0) -> None:
        """Open the file, subscribe, start the threads; returns once the broker forwards to us.

        No broker within `timeout`: a Touch4dError, and the file is removed again (none is left)."""
        existed = os.path.lexists(self.path)
        self._writer = LogWriter(self.path, chunk_size=self.chunk_size)   # an unwritable path fails first
        sock = transport.subscriber(self._context, self.bus, hwm=0,  # unbounded: a slow disk queues, never drops
                                    topics=self._subscriptions())
        self._started = time.monotonic()
        try:
            early = self._sync(sock, timeout)
        except BaseException:
            sock.close(linger=0)
            self._writer.close()
            self._writer = None
            if not existed:
                os.unlink(self.path)
            if self._own_context:
                self._context.term()
            raise
        self._queue.extend(early)
        self.received += len(early)
        self._threads = [threading.Thread(target=self._receive, args=(sock,), name="recorder-receive", daemon=True),
                         threading.Thread(target=self._write, name="recorder-write", daemon=True)]
        for thread in self._threads:
            thread.start()

    def _sync(self, sock: zmq.Socket, timeout: float) -> list[tuple[str, bytes, int]]:
        """The transport's slow-joiner sync: from its return on nothing is missed. Returns the
        messages that arrived meanwhile (they are recorded too)."""
        early: list[tuple[str, bytes, int]] = []

        def keep(frames: list[bytes]) -> None:
            if self._keeps(frames):
                early.append((self._name(frames[0]), frames[-1] if len(frames) > 1 else b"", self._clock()))

        pub = transport.publisher(self._context, self.bus)
        try:
            if transport.sync(sock, pub, timeout, owner="recorder", other=keep):
                return early
        finally:
            pub.close(linger=0)
        raise Touch4dError(f"recorder: no bus broker forwarded messages at {self.bus.sub_endpoint} "
                           f"within {timeout:.0f} s (is one running?)")

    def _receive(self, sock: zmq.Socket) -> None:
        if self.realtime:
            self.realtime = raise_thread_priority()  # receive stamps stay accurate on a busy machine
        try:
            while not self._stopping.is_set():
                if sock.poll(50):
                    self._drain(sock)
            self._drain(sock)  # what had arrived when the stop came
        finally:
            sock.close(linger=0)
            self._received.set()

    def _drain(self, sock: zmq.Socket) -> None:
        keeps, append, clock, known = self._keeps, self._queue.append, self._clock, self._names
        while True:
            try:
                frames = sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if keeps(frames):
                append((known.get(frames[0]) or self._name(frames[0]), frames[-1] if len(frames) > 1 else b"", clock()))
                self.received += 1

    def offer(self, topic: str, payload: bytes) -> None:
        """A message no socket brings (a group's private topic, `Node.tap_private`; `topic` relative to
        the namespace), from the thread that published it: recorded as if received (deque appends
        are atomic; the receive thread's count is its own)."""
        bus_topic = self._resolved.get(topic)
        if bus_topic is None:
            bus_topic = self._resolved[topic] = names.resolve(topic, self.namespace).encode()
        if not self._stopping.is_set() and self._keeps([bus_topic, payload]):
            self._queue.append((topic, payload, self._clock()))
            self.offered += 1

    def _keeps(self, frames: list[bytes]) -> bool:
        """Whether a message is this recording's: a topic wanted. (In a namespace, of the heartbeats
        only its own stack's come: `_subscriptions`, so another participant's nodes stay out of this
        participant's log.)"""
        return _wanted(names.bus_key(frames[0]), self._wanted)

    def _subscriptions(self) -> list[bytes]:
        """The topics asked for, or every topic (of its namespace, and the global ones); in a
        namespace, of the heartbeats only its own stack's (names.heartbeat_key)."""
        if not self.namespace:
            return sorted(self._wanted) or [b""]
        keys = sorted(self._wanted) or [f"{self.namespace}/".encode()] + [
            t.encode() for t in sorted(names.GLOBAL_TOPICS | names.BROADCAST_TOPICS)]
        return [names.heartbeat_key(self.namespace) if k == HEARTBEAT else k for k in keys]

    def _name(self, topic: bytes) -> str:
        """A topic's name as text (relative to the namespace), decoded once per topic."""
        name = self._names.get(topic)
        if name is None:
            text = names.bus_key(topic).decode("utf-8", "replace")
            name = self._names[topic] = (names.relative(text, self.namespace) or text) if self.namespace else text
        return name

    def _write(self) -> None:
        writer, queue = self._writer, self._queue
        last_flush = time.monotonic()
        dirty = False
        try:
            while True:
                done = self._received.is_set()
                n = min(len(queue), 2000)  # a batch at a time: the flush below stays on time
                writer.write_many(queue.popleft() for _ in range(n))
                dirty = dirty or n > 0
                now = time.monotonic()
                if dirty and now - last_flush >= self.flush_interval:
                    writer.flush()
                    last_flush, dirty = now, False
                if not n:
                    if done:
                        break
                    time.sleep(WRITE_PERIOD_S)
        except Exception as exc:  # noqa: BLE001 - disk full, I/O error: stop and say so, never hang
            self.error = self._write_error(exc)
            self._stopping.set()

    def _write_error(self, exc: Exception) -> str:
        """What went wrong writing, and where the part already written is."""
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            cause = f"no room left ({exc.strerror})"
        else:
            cause = f"{type(exc).__name__}: {exc}"
        return (f"writing {self.path}: {cause}; recording stopped after {_size(self._writer.bytes)} of messages. "
                f"What was written before is in the file: `touch4d log recover {self.path}` makes it a complete log")

    def report(self) -> RecordingReport:
        w = self._writer
        counts = dict(w.counts) if w else {}
        return RecordingReport(
            self.path, counts, w.gaps.report() if w else {}, {k: v for k, v in (w.malformed if w else {}).items() if v},
            [t for t in self.topics if t not in counts], time.monotonic() - self._started if self._started else 0.0,
            w.bytes if w else 0, error=self.error)

    def stop(self) -> RecordingReport:
        """Stop receiving, write everything queued, close the file with its metadata; the report."""
        self._stopping.set()
        for thread in self._threads:
            thread.join()
        if self._own_context and self._threads:
            self._context.term()
        report = self.report()
        if self._writer is not None:
            try:
                self._writer.close(report.metadata())
            except OSError as exc:
                report.error = report.error or f"closing {self.path}: {exc}"
            try:
                report.file_bytes = os.path.getsize(self.path)
            except OSError:
                pass
        return report

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the recording stops by itself (a write error); True if it did."""
        return self._stopping.wait(timeout)

"""The executor: one thread's loop of timers, socket readers and calls handed over by other threads.

A node owns one (`node.executor`), or shares one with the other nodes of its process (a launch
file's `group`, run by touch4d.bus.process, or a container's groups, touch4d.bus.container); it
registers its sockets as readers and its timers, and `spin_once` waits for whichever comes first.
Everything runs on the thread that spins, so node code needs no locks. A callback that raises is
handed to `on_error(where, exc)` (inside the `except`, so a traceback can be logged) and the loop
goes on.

A process that serves pages (touch4d.web.server) asks for `asyncio_loop()`: from then on the
executor spins on that asyncio loop (its sockets watched by the loop, its timers the loop's), and the
page server runs on it too, so pages and nodes share one thread: a page's message and the frame it
causes are not handed between threads (each hand-over cost a wake-up of the other thread, and the
two contended for the interpreter lock).
"""
from __future__ import annotations

import asyncio
import math
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import zmq

from touch4d.bus.local import LocalRoutes
from touch4d.eventloop import new_event_loop

MAX_CATCH_UP = 0.05  # s: how far behind a timer may fall and still make up its missed ticks
# s: a timer due this soon runs now. An event loop's clock counts whole milliseconds (libuv's, under
# uvloop), so its wake-up for a timer may come up to a millisecond early: without the slack that turn
# would find nothing due and the loop would turn again, and again, until the due time. A periodic
# timer's slack is at most a quarter of its period (a 1 kHz tick is never run twice in a row).
TIMER_SLACK = 0.001
# s: on an asyncio loop a turn asks only the sockets whose FD fired (and those that still held messages),
# not all of them (a container holds hundreds); every socket is asked at least this often anyway, for an
# edge that an operation on a socket took without its FD saying so (ZeroMQ's FD is edge-triggered).
FULL_POLL_S = 0.1


@dataclass
class Timer:
    """Calls `callback()` every `period` seconds on the executor's thread, until cancelled."""

    period: float
    callback: Callable[[], Any]
    next_due: float
    cancelled: bool = False
    on_error: Callable[[Any, Exception], None] | None = None   # None: the executor's
    slack: float = 0.0    # run when due within this (TIMER_SLACK, at most a quarter of the period)

    def cancel(self) -> None:
        self.cancelled = True


def _reraise(where, exc: Exception) -> None:
    raise exc


class Executor:
    """Timers, readers (a socket or file descriptor -> a callback returning how much it handled)
    and thread-safe calls, run by `spin_once` / `spin`."""

    def __init__(self, on_error: Callable[[Any, Exception], None] = _reraise):
        self.on_error = on_error
        self.timers: list[Timer] = []
        self._next_due = -math.inf   # when the next timer is due (kept by run_timers)
        self._calls: deque = deque()  # (callback, args) handed over by other threads, or queued by this one
        self._readers: dict = {}
        self._poller = zmq.Poller()
        self._stopping = False
        self._closed = False
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._poller.register(self._wake_r, zmq.POLLIN)
        self._loop: asyncio.AbstractEventLoop | None = None   # set by asyncio_loop(): spin on it
        self._fds: dict = {}           # reader -> the file descriptor the loop watches for it
        self._loop_thread: int | None = None
        self._step_pending = False
        self._timer_handle: asyncio.TimerHandle | None = None
        self._armed_due = math.nan
        self._spun = 0                 # handled during a spin on the loop (spin_once's answer)
        self._in_step = False
        self._serves_tls = False
        self._spinning = False   # our spin runs the loop (not a page server starting or stopping)
        self._once = False
        self._ready: set = set()     # on a loop: readers whose FD fired, or that held more than one turn took
        self._full_poll_due = 0.0
        self._interrupted = False   # interrupt(): the current spin returns (its spinner has work between spins)
        self.local = LocalRoutes()   # its nodes' subscriptions, for intra-process delivery (touch4d.bus.local)

    # ---- what runs ---------------------------------------------------------------------------

    def add_reader(self, sock, callback: Callable[[], int]) -> None:
        """Call `callback()` when `sock` (a ZeroMQ socket or a file descriptor) is readable."""
        self._readers[sock] = callback
        self._poller.register(sock, zmq.POLLIN)
        if self._loop is not None:
            self._watch(sock)

    def remove_reader(self, sock) -> None:
        """Stop watching `sock` (a node of a shared executor shutting down); unknown: nothing."""
        if self._readers.pop(sock, None) is not None:
            self._poller.unregister(sock)
            self._ready.discard(sock)
            fd = self._fds.pop(sock, None)
            if fd is not None and not self._loop.is_closed():
                self._loop.remove_reader(fd)

    def create_timer(self, period: float, callback: Callable[[], Any], first_due: float | None = None,
                     on_error: Callable[[Any, Exception], None] | None = None) -> Timer:
        """Call `callback()` every `period` s; its exceptions go to `on_error` (default: the executor's)."""
        if not period > 0:
            raise ValueError(f"timer period must be > 0 s, got {period}")
        timer = Timer(float(period), callback, time.monotonic() + period if first_due is None else first_due,
                      on_error=on_error, slack=min(TIMER_SLACK, period / 4))
        self.timers.append(timer)
        self._next_due = min(self._next_due, timer.next_due)
        self._rearm()
        return timer

    def call_later(self, delay: float, callback: Callable[[], Any],
                   on_error: Callable[[Any, Exception], None] | None = None) -> Timer:
        """Call `callback()` once, `delay` s from now and never sooner (cancel the returned timer to call
        nothing): a deadline costs one wake-up, where a timer that polls a flag wakes the thread at its
        rate. Its due time has TIMER_SLACK added, so the slack never runs it early."""
        timer: Timer

        def once() -> None:
            timer.cancel()
            callback()

        timer = self.create_timer(max(float(delay), 1e-6), once,
                                  first_due=time.monotonic() + max(0.0, delay) + TIMER_SLACK, on_error=on_error)
        timer.slack = TIMER_SLACK   # the whole slack, as it was added to its due time
        return timer

    def set_timer_period(self, timer: Timer, period: float) -> None:
        """Change a timer's period; a shorter one takes effect at once (the next tick at most
        `period` from now), a longer one after the tick already due."""
        if not period > 0:
            raise ValueError(f"timer period must be > 0 s, got {period}")
        timer.period = float(period)
        timer.slack = min(TIMER_SLACK, timer.period / 4)
        timer.next_due = min(timer.next_due, time.monotonic() + timer.period)
        self._next_due = min(self._next_due, timer.next_due)
        self._rearm()

    def call_soon(self, callback: Callable, *args) -> None:
        """Run `callback(*args)` at the next spin; from the executor's own thread."""
        self._calls.append((callback, args))
        if self._loop is not None:
            self._step_soon()

    def call_soon_threadsafe(self, callback: Callable, *args) -> None:
        """Run `callback(*args)` at the next spin; safe from any thread. The poll wakes at once."""
        self._calls.append((callback, args))
        if self._loop is not None and threading.get_ident() == self._loop_thread:
            self._step_soon()   # from the loop's own thread (a page server's callback): no wake-up to send
        else:
            self._wake(b"c")

    def request_shutdown(self) -> None:
        """Ask `spin` to return; safe from signal handlers and other threads."""
        self._stopping = True
        self._wake(b"x")

    def interrupt(self) -> None:
        """Make the current (or next) `spin` return soon, without shutting down: whoever spins has
        work to do between spins (a container loading a group: a page server binds on the loop while
        it is not running). Safe from any thread."""
        self._interrupted = True
        if self._loop is not None and threading.get_ident() == self._loop_thread:
            self._step_soon()
        else:
            self._wake(b"i")

    @property
    def stopping(self) -> bool:
        return self._stopping

    # ---- spinning ----------------------------------------------------------------------------

    def spin_once(self, timeout: float = 0.1) -> int:
        """Wait up to `timeout` s for a reader or a due timer and handle them; returns how many."""
        if self._loop is not None:
            return self._spin_loop(timeout, once=True)
        handled = self.run_timers() + self.run_calls()
        if handled or self._stopping:
            timeout = 0.0
        elif self._next_due - time.monotonic() < timeout:
            timeout = max(0.0, self._next_due - time.monotonic())
        # Round up: a sub-millisecond wait rounded down to 0 would busy-poll until the timer is due.
        handled += self._read(self._poller.poll(math.ceil(timeout * 1000) if timeout > 0 else 0))
        return handled + self.run_calls() + self.run_timers()

    def _read(self, events) -> int:
        """Call the reader of each socket the poll found readable (the wake-up pipe: drained)."""
        handled = 0
        for sock, _ in events:
            reader = self._readers.get(sock)
            if reader is not None:
                handled += reader()
            else:
                try:
                    self._wake_r.recv(4096)
                except BlockingIOError:
                    pass
        return handled

    def spin(self, duration: float | None = None) -> None:
        """Spin until `request_shutdown()` (or for `duration` seconds)."""
        if self._loop is not None:
            self._spin_loop(duration)
            return
        end = None if duration is None else time.monotonic() + duration
        while not self._stopping and not self._interrupted:
            left = 0.1 if end is None else end - time.monotonic()
            if left <= 0:
                break
            self.spin_once(min(left, 0.1))
        self._interrupted = False

    def run_calls(self) -> int:
        ran = 0
        while self._calls:
            callback, args = self._calls.popleft()
            try:
                callback(*args)
            except Exception as exc:  # noqa: BLE001 - a failing callback must not stop the loop
                self.on_error(getattr(callback, "__name__", "call_soon_threadsafe"), exc)
            ran += 1
        return ran

    def run_timers(self) -> int:
        """Run the due timers (each due within its `slack`); keeps `_next_due`, when the next one is
        due, for `spin_once`'s wait."""
        now = time.monotonic()
        if now + TIMER_SLACK < self._next_due or self._stopping:
            return 0   # the common case of a spin woken by a message: nothing due
        ran = 0
        next_due, cancelled = math.inf, False
        timers = list(self.timers)   # a copy: a callback may create timers
        for timer in timers:
            if timer.cancelled:
                cancelled = True
                continue
            if timer.next_due <= now + timer.slack and not self._stopping:
                # Fixed rate: a late tick (poll wakes at millisecond granularity) is made up on the
                # next spins, so a 1 kHz timer averages 1 kHz; after a stall of more than
                # MAX_CATCH_UP the missed ticks are skipped rather than fired in a burst.
                timer.next_due += timer.period
                if now - timer.next_due > max(MAX_CATCH_UP, 2 * timer.period):
                    timer.next_due = now + timer.period
                try:
                    timer.callback()
                except Exception as exc:  # noqa: BLE001 - a failing timer must not stop the loop
                    (timer.on_error or self.on_error)(timer, exc)
                ran += 1
            if timer.next_due < next_due:   # cancelled by its own callback: a wake for nothing
                next_due = timer.next_due
        if len(self.timers) != len(timers):   # created by a callback
            next_due = min([next_due] + [t.next_due for t in self.timers[len(timers):]])
        if cancelled:
            self.timers = [t for t in self.timers if not t.cancelled]
        self._next_due = next_due
        return ran

    def close(self) -> None:
        """Stop and release the wake-up pipe (the readers' sockets are their owners' to close), and
        the asyncio loop if any (what still runs on it is cancelled first)."""
        self._stopping = True
        if not self._closed:
            self._closed = True
            loop = self._loop
            if loop is not None and not loop.is_closed() and not loop.is_running():
                for fd in self._fds.values():
                    loop.remove_reader(fd)
                loop.remove_reader(self._wake_r.fileno())
                tasks = asyncio.all_tasks(loop)
                for task in tasks:
                    task.cancel()
                if tasks:
                    loop.run_until_complete(asyncio.wait(tasks, timeout=1.0))
                loop.close()
            self._wake_r.close()
            self._wake_w.close()

    # ---- on an asyncio loop ------------------------------------------------------------------

    def asyncio_loop(self, serves_tls: bool = False) -> asyncio.AbstractEventLoop:
        """The asyncio loop this executor spins on from now on (made at the first call, before the
        first spin; `serves_tls`: touch4d.eventloop): a page server given it serves on the
        executor's thread (see the module's doc)."""
        if self._loop is not None and serves_tls != self._serves_tls:
            raise ValueError("one executor's loop serves TLS itself or not: a second page server "
                             f"{'with' if serves_tls else 'without'} TLS in this process cannot share it")
        if self._loop is None:
            self._serves_tls = serves_tls
            self._loop = new_event_loop(serves_tls)
            for sock in self._readers:
                self._watch(sock)
            self._loop.add_reader(self._wake_r.fileno(), self._fd_ready, self._wake_r)
        return self._loop

    def _watch(self, sock) -> None:
        # A ZeroMQ socket's FD only says "look": the step asks that socket (ZMQ_EVENTS), which also
        # re-arms it, so a level-triggered watch of it neither misses nor spins (_poll_ready).
        fd = sock.getsockopt(zmq.FD) if isinstance(sock, zmq.Socket) else sock
        self._fds[sock] = fd
        self._loop.add_reader(fd, self._fd_ready, sock)

    def _fd_ready(self, sock) -> None:
        self._ready.add(sock)
        self._step_soon()

    def _poll_ready(self) -> list:
        """The readable among the readers whose FD fired (a turn's poll without asking every socket);
        every FULL_POLL_S, all of them."""
        now = time.monotonic()
        if now >= self._full_poll_due:
            self._full_poll_due = now + FULL_POLL_S
            self._ready.clear()
            events = self._poller.poll(0)
        elif not self._ready:
            return []
        else:
            socks, self._ready = self._ready, set()
            events = []
            for sock in socks:
                if isinstance(sock, zmq.Socket):
                    try:
                        if not sock.getsockopt(zmq.EVENTS) & zmq.POLLIN:   # also re-arms its FD
                            continue
                    except zmq.ZMQError:   # closed meanwhile
                        continue
                events.append((sock, zmq.POLLIN))   # a plain FD: the loop watches it level-triggered
        # a ZeroMQ socket may hold more than its reader takes at once, and its FD will not say so again
        self._ready.update(sock for sock, _ in events if isinstance(sock, zmq.Socket))
        return events

    def _spin_loop(self, duration: float | None, once: bool = False) -> int:
        loop = self._loop
        self._loop_thread = threading.get_ident()
        self._spun, self._once = 0, once
        stop = loop.call_later(max(0.0, duration), loop.stop) if duration is not None else None
        self._spinning = True
        self._step_soon()
        try:
            loop.run_forever()
        finally:
            self._spinning = False
            if stop is not None:
                stop.cancel()
            if self._timer_handle is not None:   # the next spin arms its own
                self._timer_handle.cancel()
                self._timer_handle, self._armed_due = None, math.nan
            self._once = False
            self._interrupted = False
        return self._spun

    def _rearm(self) -> None:
        """A timer changed outside a step: a step soon arms the loop's wake-up for it (a step re-arms
        at its end anyway)."""
        if self._loop is not None and not self._in_step:
            self._step_soon()

    def _step_soon(self) -> None:
        if not self._step_pending:
            self._step_pending = True
            self._loop.call_soon(self._step)

    def _timer_due(self) -> None:
        self._timer_handle, self._armed_due = None, math.nan
        self._step()

    def _step(self) -> None:
        """One turn on the loop: due timers, calls, and every socket with something to read (asked
        again until none has: a callback's send on a socket may have taken its FD's signal)."""
        self._step_pending = False
        if not self._spinning:
            return   # the loop runs for someone else (a page server starting or stopping): the next spin turns
        self._in_step = True
        try:
            self._turn()
        finally:
            self._in_step = False

    def _turn(self) -> None:
        handled = self.run_timers() + self.run_calls()
        for _ in range(8):
            events = self._poll_ready()
            if not events:
                break
            handled += self._read(events) + self.run_calls()
        else:
            self._step_soon()   # still busy: the loop's other work gets a turn first
        handled += self.run_timers()
        self._spun += handled
        if self._stopping or self._interrupted or (self._once and self._spun):
            # once a spin: uvloop's stop queues its stop as a callback, and a second one left queued
            # would stop whatever runs the loop next (a page server closing its pages) at once
            self._spinning = False
            self._loop.stop()
        elif self._calls:
            self._step_soon()
        # the next timer, or the next full poll while sockets are watched (an edge taken unseen: FULL_POLL_S)
        due = min(self._next_due, self._full_poll_due) if self._fds else self._next_due
        if due != self._armed_due:
            if self._timer_handle is not None:
                self._timer_handle.cancel()
            self._armed_due = due
            self._timer_handle = self._loop.call_at(due, self._timer_due) if math.isfinite(due) else None

    def _wake(self, byte: bytes) -> None:
        try:
            self._wake_w.send(byte)
        except OSError:
            pass

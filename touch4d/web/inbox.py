"""What one page sent, on its way from the server's loop to the node's callbacks (one thread or two:
touch4d.web.server): bounded whatever the page sends, so a flood from one page can neither grow a
queue nor take the node's thread.

- Inputs (poses, at a headset's frame rate) are paced: one is handed over at most every
  1 / `input_hz` seconds; one arriving sooner is held, and a newer one replaces it (the node gets
  the latest pose, later by at most the pace, never a backlog). The hand-over slot holds one input:
  a node that has not taken it yet gets the newer one instead.
- Other messages (session, stats, recenter, response) keep their order, at most `burst` at once and
  `rate` per second on average (a token bucket); more are dropped and counted.

The server's thread calls `offer` (and `release` when the time it returned has come); the node's
thread calls `take`. `offer` and `release` return whether the node must be woken to take.
"""
from __future__ import annotations

import collections
import threading

MAX_INPUT_HZ = 144.0     # inputs per second and page, at most: a Quest runs at 72-120 Hz
OTHER_RATE = 20.0        # other messages per second and page, on average (a page sends ~1: its stats)
OTHER_BURST = 20         # and at most this many at once


class TokenBucket:
    """At most `burst` at once and `rate` per second on average: `spend(now)` says whether one more may go."""

    def __init__(self, rate: float, burst: float):
        self.rate, self.burst = rate, burst
        self._tokens = float(burst)
        self._filled_at: float | None = None

    def spend(self, now: float) -> bool:
        if self._filled_at is not None:
            self._tokens = min(self.burst, self._tokens + max(0.0, now - self._filled_at) * self.rate)
        self._filled_at = now
        if self._tokens < 1:
            return False
        self._tokens -= 1
        return True


class Inbox:
    def __init__(self, input_hz: float = MAX_INPUT_HZ, rate: float = OTHER_RATE, burst: int = OTHER_BURST):
        self.interval = 1.0 / input_hz
        self.rate, self.burst = rate, burst
        # the server's thread only
        self._next_input = float("-inf")    # when the next input may be handed over
        self._held = None                   # (data, arrival): an input waiting for its time
        self._bucket = TokenBucket(rate, burst)
        # shared, under the lock
        self._lock = threading.Lock()
        self._queue: collections.deque = collections.deque()   # (data, arrival), in order
        self._input = None
        self._told = False                  # the node was woken and has not taken yet
        self.replaced = 0                   # inputs superseded before the node took them
        self.dropped = 0                    # other messages over the bucket

    # ---- the server's thread ---------------------------------------------------------------------

    def offer(self, data, arrival: float, is_input: bool, always: bool = False) -> tuple[bool, float | None]:
        """Accept what the page sent at `arrival` (`always`: past the bucket, e.g. the error that
        ends a connection). Returns (wake the node now, call `release` at this time or None)."""
        if is_input:
            if self._held is not None:
                self.replaced += 1
            self._held = (data, arrival)
            if arrival < self._next_input:
                return False, self._next_input
            return self.release(arrival), None
        if not (always or self._bucket.spend(arrival)):
            self.dropped += 1
            return False, None
        with self._lock:
            self._queue.append((data, arrival))
            return self._tell(), None

    def release(self, now: float) -> bool:
        """Hand the held input over (its time has come); whether to wake the node."""
        if self._held is None:
            return False
        held, self._held = self._held, None
        self._next_input = max(now, self._next_input) + self.interval
        with self._lock:
            if self._input is not None:
                self.replaced += 1
            self._input = held
            return self._tell()

    def _tell(self) -> bool:
        told, self._told = self._told, True
        return not told

    # ---- the node's thread -----------------------------------------------------------------------

    def take(self) -> list[tuple]:
        """Everything handed over, (data, arrival) in order of arrival."""
        with self._lock:
            items = list(self._queue)
            self._queue.clear()
            if self._input is not None:
                items.append(self._input)
                items.sort(key=lambda item: item[1])
                self._input = None
            self._told = False
        return items

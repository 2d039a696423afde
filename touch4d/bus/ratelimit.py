"""A state topic's publish policy, kept in one place for every node that publishes one (`scene/state`).

A change goes out at once, unless the previous message went out under 1/max_rate ago: then it goes out
when that spacing has passed (the latest state then, so the last change is never lost and a burst of
changes costs one message). Every 1/rate, on a steady beat whether or not the state changes, it goes
out again for late joiners (a repeat: a listener that sees two messages of one revision knows nothing
changed between). No two messages are ever closer than 1/max_rate, the steady one included. Pure timing
logic: a clock and a one-shot scheduler are handed in (a node's `call_later`), so it is tested
without a bus.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable


class RateLimitedPublisher:
    """Calls `send()` (which publishes the current state) on change at most `max_rate` times a second,
    and on a steady beat every 1/`rate` s; `call_later(delay, callback)` returns something with
    `cancel()` (touch4d.bus.Node.call_later), `clock()` counts seconds (the scheduler's clock)."""

    def __init__(self, send: Callable[[], Any], *, rate: float, max_rate: float,
                 call_later: Callable[[float, Callable[[], Any]], Any], clock: Callable[[], float] = time.monotonic):
        for name, value in (("rate", rate), ("max_rate", max_rate)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"RateLimitedPublisher: {name}: expected a finite number > 0 (Hz), got {value!r}")
        self.send = send
        self.min_period = 1.0 / max_rate
        self.period = max(1.0 / rate, self.min_period)   # the steady one keeps the spacing too
        self.call_later = call_later
        self.clock = clock
        self.last = -math.inf      # when the last message went out (read after sending: its stamp is earlier)
        self.dirty = False         # a change waits for min_period to pass
        self.next_steady = math.inf   # the steady beat's next time (set by the first message)
        self._wake = None          # the one pending call_later, and when it is due
        self._wake_at = math.inf

    @classmethod
    def for_node(cls, node, send: Callable[[], Any], *, rate: float, max_rate: float) -> "RateLimitedPublisher":
        """One that runs on `node`'s thread and timers; the first message goes out now."""
        publisher = cls(send, rate=rate, max_rate=max_rate, call_later=node.call_later)
        publisher.publish()
        return publisher

    def changed(self, changed: bool = True) -> None:
        """The state changed (or not: nothing): publish now, or when min_period has passed since the last."""
        if not changed:
            return
        if self.clock() - self.last >= self.min_period:
            self.publish()
        else:
            self.dirty = True
            self._arm()

    def publish(self) -> None:
        """Send the state now (the first message; `changed` for every later one)."""
        try:
            self.send()
        finally:                   # a send that raised leaves the steady schedule running
            self.last = self.clock()
            self.dirty = False
            if self.next_steady == math.inf:
                self.next_steady = self.last + self.period
            self._arm()

    def due(self) -> float:
        """When the next message is due: a waiting change's, or the steady one (kept min_period after the last)."""
        spaced = self.last + self.min_period
        return spaced if self.dirty else max(self.next_steady, spaced)

    def _arm(self) -> None:
        """Keep one wake-up at or before `due()`: an earlier one finds nothing due and re-arms itself (so
        a change published at once costs no timer)."""
        due = self.due()
        if self._wake is not None:
            if self._wake_at <= due:
                return
            self._wake.cancel()
        self._wake_at = due
        self._wake = self.call_later(max(0.0, due - self.clock()), self._on_wake)

    def _on_wake(self) -> None:
        self._wake, self._wake_at = None, math.inf
        now = self.clock()
        if now >= self.due() - 1e-9:            # a waiting change, or the steady re-publish
            if now >= self.next_steady - 1e-9:  # the beat goes on from its own times, not from this one's
                self.next_steady += self.period * (math.floor((now - self.next_steady) / self.period + 1e-9) + 1)
            self.publish()
        else:
            self._arm()

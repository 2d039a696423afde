"""When a supervised process that died is started again: the one restart policy of the launcher (a
node or group that `respawn`s, backing off while it keeps failing to start) and of the container
pool (a group whose containers keep dying: loaded alone, then given up).

Pure: no process, no sleep; times come from `clock`, so a test drives it with a clock of its own.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Hashable


@dataclass(frozen=True)
class Verdict:
    """What becomes of a unit that died: `restart` it (else it is given up) after `delay` seconds,
    `alone` (in a process of its own from now on); `deaths`: its deaths within the window."""

    restart: bool
    delay: float
    alone: bool
    deaths: int


class RestartPolicy:
    """Per unit (any key: a launch's process name, a pool's group id), its deaths and what follows.

    `delay`: seconds before a restart after a death once it had started (a unit may have its own:
    `died(..., delay=)`); a death before it said it started multiplies its last delay by `backoff`, up
    to `max_delay` (a node that cannot start is not restarted in a tight loop). Deaths older than
    `window` seconds are forgotten; a unit with `isolate_after` deaths within it runs alone from then
    on (for good), one with `give_up_after` is not restarted (None: never)."""

    def __init__(self, *, delay: float = 0.0, backoff: float = 1.0, max_delay: float = math.inf,
                 window: float = math.inf, isolate_after: int | None = None, give_up_after: int | None = None,
                 clock: Callable[[], float] = time.monotonic):
        if delay < 0 or backoff < 1 or max_delay < 0 or window <= 0:
            raise ValueError(f"restart policy: expected delay >= 0, backoff >= 1, max_delay >= 0 and window > 0, "
                             f"got {delay}, {backoff}, {max_delay} and {window}")
        for name, count in (("isolate_after", isolate_after), ("give_up_after", give_up_after)):
            if count is not None and count < 1:
                raise ValueError(f"restart policy: {name}: expected at least 1 or None, got {count}")
        self.delay, self.backoff, self.max_delay, self.window = delay, backoff, max_delay, window
        self.isolate_after, self.give_up_after, self.clock = isolate_after, give_up_after, clock
        self._deaths: dict[Hashable, list[float]] = {}   # key -> when it died (clock), within the window
        self._delay: dict[Hashable, float] = {}          # key -> the delay before its last restart
        self._alone: set[Hashable] = set()

    def died(self, key: Hashable, *, started: bool = True, delay: float | None = None) -> Verdict:
        """Count a death of `key` (`started`: after it said it was running) and say what follows;
        `delay`: this unit's own delay after a death once started (default: the policy's)."""
        base = self.delay if delay is None else delay
        now = self.clock()
        self._deaths[key] = [t for t in self._deaths.get(key, ()) if now - t < self.window] + [now]
        wait = min(self._delay.get(key, base) * self.backoff, self.max_delay) if not started else base
        self._delay[key] = wait
        return self._verdict(key, now, wait)

    def verdict(self, key: Hashable) -> Verdict:
        """What follows for `key` now, no death counted (one counted earlier may have left the window)."""
        return self._verdict(key, self.clock(), self._delay.get(key, self.delay))

    def alone(self, key: Hashable) -> bool:
        """Whether `key` runs alone: once isolated, for good."""
        return self.verdict(key).alone

    def _verdict(self, key: Hashable, now: float, wait: float) -> Verdict:
        deaths = sum(1 for t in self._deaths.get(key, ()) if now - t < self.window)
        if self.isolate_after is not None and deaths >= self.isolate_after:
            self._alone.add(key)
        give_up = self.give_up_after is not None and deaths >= self.give_up_after
        return Verdict(restart=not give_up, delay=wait, alone=key in self._alone, deaths=deaths)

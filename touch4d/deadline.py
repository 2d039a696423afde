"""One timer at the earliest deadline asked for: a runner that wakes only when something is due (a
node's bridge, a served participant's session), not at a rate. Asked again for a deadline no earlier
than the one armed, it changes nothing: an event that only moves a deadline later costs no timer."""
from __future__ import annotations

import math
from typing import Callable


class Deadline:
    """`arm(due)` after every event; `callback` runs at the earliest due (`clock`'s time; -inf: now,
    inf: never). `call_later(delay_s, callback)` is the loop's or node's and returns a cancellable handle."""

    def __init__(self, call_later: Callable, clock: Callable[[], float], callback: Callable[[], None]):
        self._call_later, self._clock, self._callback = call_later, clock, callback
        self._timer = None
        self.due = math.inf

    def arm(self, due: float) -> None:
        if self._timer is not None:
            if self.due <= due:
                return
            self._timer.cancel()
            self._timer = None
        self.due = due
        if due != math.inf:
            self._timer = self._call_later(max(0.0, due - self._clock()) if math.isfinite(due) else 0.0, self._fire)

    def cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer, self.due = None, math.inf

    def _fire(self) -> None:
        self._timer, self.due = None, math.inf
        self._callback()

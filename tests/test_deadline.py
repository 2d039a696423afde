"""One timer at the earliest deadline asked for (touch4d.deadline), on a fake loop: a later deadline
costs no timer, an earlier one replaces the armed one, -inf is now, inf is never, a fired one re-arms."""
from __future__ import annotations

import math

from touch4d.deadline import Deadline


class Loop:
    def __init__(self):
        self.now, self.timers = 100.0, []

    def call_later(self, delay, callback):
        timer = Timer(self.now + delay, callback)
        self.timers.append(timer)
        return timer

    def run_until(self, t):
        while True:
            due = sorted((x for x in self.timers if not x.cancelled and not x.done), key=lambda x: x.at)
            if not due or due[0].at > t:
                self.now = t
                return
            self.now = due[0].at
            due[0].done = True
            due[0].callback()


class Timer:
    def __init__(self, at, callback):
        self.at, self.callback, self.cancelled, self.done = at, callback, False, False

    def cancel(self):
        self.cancelled = True


def test_the_earliest_deadline_alone_holds_a_timer_and_fires_once():
    loop, fired = Loop(), []
    deadline = Deadline(loop.call_later, lambda: loop.now, lambda: fired.append(loop.now))
    deadline.arm(105.0)
    deadline.arm(107.0)                        # later: nothing new
    assert len(loop.timers) == 1
    deadline.arm(103.0)                        # earlier: replaces it
    assert [t.cancelled for t in loop.timers] == [True, False] and loop.timers[1].at == 103.0
    loop.run_until(110.0)
    assert fired == [103.0] and deadline.due == math.inf
    deadline.arm(-math.inf)                    # due now
    loop.run_until(110.0)
    assert fired == [103.0, 110.0]
    deadline.arm(math.inf)                     # never: no timer
    assert len(loop.timers) == 3
    deadline.arm(111.0)
    deadline.cancel()
    loop.run_until(120.0)
    assert fired == [103.0, 110.0]

"""The restart policy (touch4d.bus.supervisor) the launcher and the container pool share: delays,
backoff, isolation and giving up, driven by a clock of the test's own (no process, no sleep)."""
from __future__ import annotations

import pytest

from touch4d.bus.supervisor import RestartPolicy, Verdict


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_a_unit_that_keeps_failing_to_start_backs_off_to_the_cap_and_a_start_resets_it():
    """The launcher's: each failed start doubles the wait (0.5, 1, 2, 4, then 5 s at most); a death after
    the unit said it started waits its own delay again."""
    policy = RestartPolicy(backoff=2.0, max_delay=5.0, clock=Clock())
    waits = [policy.died("tracker", started=False, delay=0.25).delay for _ in range(6)]
    assert waits == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0]
    assert policy.died("tracker", started=True, delay=0.25).delay == 0.25
    assert policy.died("tracker", started=False, delay=0.25).delay == 0.5
    # each unit its own: another's failures do not lengthen this one's wait
    assert policy.died("renderer", started=True, delay=1.5) == Verdict(restart=True, delay=1.5, alone=False, deaths=1)


def test_a_unit_whose_process_keeps_dying_is_isolated_then_given_up_and_old_deaths_are_forgotten():
    """The pool's: two deaths within the window, alone (for good); three, not restarted; a death
    older than the window no longer counts."""
    clock = Clock()
    policy = RestartPolicy(window=600.0, isolate_after=2, give_up_after=3, clock=clock)
    assert policy.died("A") == Verdict(restart=True, delay=0.0, alone=False, deaths=1)
    assert not policy.alone("A") and not policy.alone("never died")
    clock.now += 599.0
    assert policy.died("A") == Verdict(restart=True, delay=0.0, alone=True, deaths=2)
    clock.now += 2.0                                     # the first death is out of the window now
    assert policy.verdict("A") == Verdict(restart=True, delay=0.0, alone=True, deaths=1)   # alone for good
    assert policy.died("A").restart                     # two within the window: restarted
    assert not policy.died("A").restart                 # three: given up
    assert policy.verdict("A").deaths == 3 and policy.alone("A")
    clock.now += 600.0
    assert policy.verdict("A") == Verdict(restart=True, delay=0.0, alone=True, deaths=0)
    assert policy.verdict("B") == Verdict(restart=True, delay=0.0, alone=False, deaths=0)


@pytest.mark.parametrize("kwargs, named", [({"delay": -1}, "delay >= 0"), ({"backoff": 0.5}, "backoff >= 1"),
                                           ({"window": 0}, "window > 0"), ({"isolate_after": 0}, "isolate_after"),
                                           ({"give_up_after": 0}, "give_up_after")])
def test_a_policy_that_cannot_work_is_refused_and_named(kwargs, named):
    with pytest.raises(ValueError, match=named):
        RestartPolicy(**kwargs)

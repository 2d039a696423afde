"""The state topic's publish policy without a bus: a simulated clock and scheduler, changes at chosen
times, and when each message went out."""
import heapq
import itertools

import numpy as np
import pytest

from touch4d.bus.ratelimit import RateLimitedPublisher


class Loop:
    """A simulated clock and one-shot scheduler; a wake-up runs `late()` seconds after it is due (a loaded
    machine), never early, as the node's executor does."""

    def __init__(self, late=lambda: 0.0):
        self.now = 0.0
        self.late = late
        self.queue = []
        self.order = itertools.count()
        self.scheduled = 0

    def call_later(self, delay, callback):
        assert delay >= 0
        entry = [self.now + delay + self.late(), next(self.order), callback, False]
        heapq.heappush(self.queue, entry)
        self.scheduled += 1
        return Handle(entry)

    def run_until(self, t):
        """Run every wake-up due by `t`, each at its time; the clock ends at `t`."""
        while self.queue and self.queue[0][0] <= t:
            due, _, callback, cancelled = heapq.heappop(self.queue)
            if not cancelled:
                self.now = due
                callback()
        self.now = t


class Handle:
    def __init__(self, entry):
        self.entry = entry

    def cancel(self):
        self.entry[3] = True


def run(change_times, end, rate, max_rate, late=lambda: 0.0):
    """Changes at `change_times` (each turning a counter) until `end`: (when each message went out, the
    counter it carried), and the changes' counter values with their times."""
    loop = Loop(late)
    state, sent = [0], []
    publisher = RateLimitedPublisher(lambda: sent.append((loop.now, state[0])), rate=rate, max_rate=max_rate,
                                     call_later=loop.call_later, clock=lambda: loop.now)
    publisher.publish()
    for t in change_times:
        loop.run_until(t)
        state[0] += 1
        publisher.changed()
    loop.run_until(end)
    return np.array(sent), loop


def test_without_changes_the_state_goes_out_every_period():
    sent, loop = run([], 10.0, rate=2.0, max_rate=120.0)
    np.testing.assert_allclose(sent[:, 0], np.arange(0.0, 10.01, 0.5))
    assert loop.scheduled == len(sent)          # one wake-up per message, no polling


def test_changes_faster_than_max_rate_go_out_at_max_rate_and_the_last_is_never_lost():
    changes = np.arange(0.1, 2.0, 0.02)         # 50 Hz for 1.9 s at max_rate 4
    sent, _ = run(changes, 5.0, rate=0.5, max_rate=4.0)
    times, counters = sent[:, 0], sent[:, 1]
    assert np.diff(times).min() >= 0.25 - 1e-9
    during = times[(times > changes[0]) & (times <= changes[-1] + 0.25)]
    assert len(during) >= 7                     # they keep coming while it changes (~1.9 s at 4 Hz)
    last = np.flatnonzero(counters == len(changes))[0]
    assert changes[-1] <= times[last] <= changes[-1] + 0.25   # within one spacing of the last change
    assert 0 < times[last + 1] - times[last] <= 2.0 + 1e-9  # then the steady re-publish, 1/rate later


@pytest.mark.parametrize("rate, max_rate", [(2.0, 10.0), (9.0, 10.0), (30.0, 10.0)])
@pytest.mark.parametrize("seed", range(3))
def test_no_two_messages_are_closer_than_max_rate_allows_and_no_gap_is_longer_than_the_period(rate, max_rate,
                                                                                               seed):
    """Changes at uneven times (the generator picks them) and wake-ups up to 30 ms late: every change is
    out within one spacing (plus the lateness) with the newest state, the steady one included in the spacing."""
    rng = np.random.default_rng(seed)
    changes = np.sort(rng.uniform(0.0, 6.0, 200))
    changes = changes[(changes < 2.0) | (changes > 4.0)]   # a quiet stretch: only steady messages
    sent, _ = run(changes, 8.0, rate, max_rate, late=lambda: rng.uniform(0.0, 0.03))
    times, counters = sent[:, 0], sent[:, 1]
    spacing, period = 1.0 / max_rate, max(1.0 / rate, 1.0 / max_rate)
    assert np.diff(times).min() >= spacing - 1e-9
    assert np.diff(times).max() <= period + 0.03 + 1e-9
    assert np.all(np.diff(counters) >= 0)
    for k, t in enumerate(changes, start=1):     # change k is out (counter >= k) within a spacing
        first = times[np.flatnonzero(counters >= k)[0]]
        assert t <= first <= t + spacing + 0.03 + 1e-9, (k, t, first)


def test_a_change_long_after_the_last_message_goes_out_at_once():
    sent, _ = run([1.3, 1.31, 2.5], 2.51, rate=1.0, max_rate=10.0)
    np.testing.assert_allclose(sent[:, 0], [0.0, 1.0, 1.3, 1.4, 2.0, 2.5])
    assert sent[:, 1].tolist() == [0, 0, 1, 2, 2, 3]


def test_the_steady_beat_goes_on_while_the_state_changes():
    """Changes every 0.3 s never leave 0.5 s without a message, yet the state goes out again on its own
    beat: a repeat of the last change (the same counter twice in a row), at each half second."""
    changes = np.arange(0.15, 4.0, 0.3)
    sent, _ = run(changes, 4.0, rate=2.0, max_rate=20.0)
    times, counters = sent[:, 0], sent[:, 1]
    for beat in np.arange(0.5, 4.0, 0.5):
        k = np.flatnonzero(np.abs(times - beat) < 1e-9)
        assert len(k) == 1, (beat, times)
        assert counters[k[0]] == counters[k[0] - 1]          # a repeat: nothing changed since the one before
    assert np.diff(times).min() >= 0.05 - 1e-9


def test_a_send_that_raises_leaves_the_steady_schedule_running():
    loop = Loop()
    sent = []

    def send():
        sent.append(loop.now)
        if len(sent) == 2:
            raise RuntimeError("the topic refused it")

    publisher = RateLimitedPublisher(send, rate=1.0, max_rate=10.0, call_later=loop.call_later, clock=lambda: loop.now)
    publisher.publish()
    with pytest.raises(RuntimeError):
        loop.run_until(1.5)
    loop.run_until(3.0)
    assert sent == [0.0, 1.0, 2.0, 3.0]


@pytest.mark.parametrize("rate, max_rate", [(0, 10.0), (2.0, -1), (2.0, float("nan")), ("2", 10.0)])
def test_bad_rates_are_named(rate, max_rate):
    with pytest.raises(ValueError, match="rate: expected a finite number > 0"):
        RateLimitedPublisher(lambda: None, rate=rate, max_rate=max_rate, call_later=Loop().call_later)

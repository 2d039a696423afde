"""The executor alone, without sockets: fixed-rate timers, errors handed on, wake-ups from other threads."""
import threading
import time

from touch4d.bus.executor import Executor, Timer


def test_a_timer_keeps_its_rate_and_a_failing_one_is_reported_without_stopping_the_loop():
    failures = []
    ex = Executor(on_error=lambda where, exc: failures.append((where, str(exc))))
    ticks = []
    ex.create_timer(0.01, lambda: ticks.append(time.monotonic()))
    bad = ex.create_timer(0.05, lambda: 1 / 0)
    start = time.monotonic()
    ex.spin(0.3)
    elapsed = time.monotonic() - start
    # Fixed rate: late ticks are made up, never more than the period allows (a stall of a loaded
    # machine may skip some, so only the upper bound is tight).
    assert elapsed / 0.01 / 3 <= len(ticks) <= elapsed / 0.01 + 1
    assert failures and all(w is bad and msg == "division by zero" for w, msg in failures)
    assert len(failures) >= 4
    ex.close()


def test_a_call_from_another_thread_wakes_a_waiting_spin_at_once_and_shutdown_ends_spin():
    ex = Executor()
    got = []
    threading.Timer(0.05, lambda: ex.call_soon_threadsafe(got.append, time.monotonic())).start()
    start = time.monotonic()
    ex.spin_once(5.0)                                      # would wait 5 s without the wake-up
    assert got and time.monotonic() - start < 1.0
    threading.Timer(0.05, ex.request_shutdown).start()
    start = time.monotonic()
    ex.spin()
    assert ex.stopping and time.monotonic() - start < 1.0
    ex.close()


def test_a_shorter_period_takes_effect_at_once_and_a_cancelled_timer_stops():
    ex = Executor()
    ticks = []
    timer = ex.create_timer(10.0, lambda: ticks.append(1))
    assert isinstance(timer, Timer)
    ex.set_timer_period(timer, 0.01)
    ex.spin(0.1)
    assert len(ticks) >= 5
    timer.cancel()
    n = len(ticks)
    ex.spin(0.05)
    assert len(ticks) == n and ex.timers == []
    ex.close()


def test_call_later_runs_once_at_its_deadline_and_a_cancelled_one_never():
    ex = Executor()
    fired, never = [], []
    start = time.monotonic()
    ex.call_later(0.03, lambda: fired.append(time.monotonic() - start))
    ex.call_later(0.02, lambda: never.append(1)).cancel()
    ex.spin(0.15)
    assert len(fired) == 1 and 0.03 <= fired[0] < 0.15 and never == []
    assert ex.timers == []                                 # nothing left behind to wake the loop
    ex.close()

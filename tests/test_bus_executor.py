"""The executor alone, without sockets: fixed-rate timers, errors handed on, wake-ups from other threads."""
import asyncio
import threading
import time
import uuid

import numpy as np
import pytest
import zmq

import touch4d.bus.executor as executor_module
from touch4d.bus.executor import Executor, Timer
from touch4d.eventloop import new_event_loop


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


def test_after_its_spin_the_loop_runs_a_page_servers_shutdown_to_the_end_without_node_work():
    """Once spin has returned, the loop may run someone else's coroutine (a page server closing its
    pages): a wake-up, a call or a timer then neither stops that loop half-way nor runs node work."""
    for _ in range(5):                                      # a race: each round may lose it
        ex = Executor()
        loop = ex.asyncio_loop()
        ticks, calls = [], []
        ex.create_timer(0.005, lambda: ticks.append(1))
        threading.Timer(0.05, ex.request_shutdown).start()
        ex.spin()
        assert ticks
        ex.request_shutdown()                              # again, as a node's shutdown does: a wake-up
        ex.call_soon_threadsafe(calls.append, 1)
        n = len(ticks)

        async def closing() -> str:
            await asyncio.sleep(0.03)
            return "closed"

        assert loop.run_until_complete(closing()) == "closed"
        assert len(ticks) == n and calls == []
        ex.close()


def test_a_timer_runs_within_its_slack_but_a_fast_one_never_twice_in_a_row(monkeypatch):
    """The slack, on a hand-moved clock: a 90 Hz tick due within a millisecond runs now; a 1 kHz
    tick's slack is a quarter of its period, so the turn after a tick does not run the next one."""
    clock = [100.0]
    monkeypatch.setattr(executor_module.time, "monotonic", lambda: clock[0])
    slow_ex, fast_ex = Executor(), Executor()
    slow, fast = [], []
    slow_ex.create_timer(1 / 90, lambda: slow.append(clock[0]))
    fast_ex.create_timer(0.001, lambda: fast.append(clock[0]))
    clock[0] = 100.0 + 1 / 90 - 0.0009                      # 0.9 ms before the slow tick's due time
    assert slow_ex.run_timers() == 1 and len(slow) == 1
    clock[0] = 100.0 + 0.0010005                             # just after the fast tick's due time
    assert fast_ex.run_timers() == 1
    assert fast_ex.run_timers() == 0 and len(fast) == 1    # the next turn: its next tick is 1 ms away
    slow_ex.close()
    fast_ex.close()


def test_on_a_loop_a_timer_costs_one_turn_a_tick_and_a_deadline_is_never_early():
    """The page-serving loop's clock counts milliseconds (libuv's under uvloop): a 90 Hz timer still
    costs one turn a tick, not a turn that finds nothing due and more until the due time; and a
    deadline (call_later) still never runs before its delay."""
    ex = Executor()
    ex.asyncio_loop()
    turns, ticks, early = [], [], []
    turn = ex._turn
    ex._turn = lambda: (turns.append(1), turn())
    ex.create_timer(1 / 90, lambda: ticks.append(1))

    def ask(delay: float) -> None:
        asked = time.monotonic()
        ex.call_later(delay, lambda: fired(delay, asked))

    def fired(delay: float, asked: float) -> None:
        early.append(time.monotonic() - asked < delay)
        if len(early) < 40:
            ask(delay + 0.0003)

    ask(0.0031)
    ex.spin(0.5)
    assert len(ticks) >= 20 and len(early) >= 20 and not any(early)
    assert len(turns) <= len(ticks) + len(early) + 10      # one turn a tick or deadline, and a few more
    ex.close()


@pytest.mark.parametrize("factory", [lambda serves_tls=False: asyncio.new_event_loop(), new_event_loop],
                         ids=["asyncio", "default"])
def test_on_an_asyncio_loop_timers_readers_calls_and_the_loops_own_work_share_one_thread(monkeypatch, factory):
    """A page-serving process's executor (asyncio_loop): its timers keep their rate, a socket's
    messages are read, a call from another thread wakes it, the loop's own callbacks (a page server's)
    run on the same thread, spin_once answers, and a shutdown request ends spin at once."""
    monkeypatch.setattr(executor_module, "new_event_loop", factory)
    ex = Executor()
    loop = ex.asyncio_loop()
    ticks, got, threads = [], [], set()
    ex.create_timer(0.01, lambda: ticks.append(time.monotonic()))
    ctx = zmq.Context.instance()
    inbound, outbound = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    # an address of its own each run: a closed socket's inproc name is freed later, by ZeroMQ's reaper
    # thread, so the next parameter's bind of the same name could find it still taken
    address = f"inproc://executor-on-a-loop-{uuid.uuid4().hex}"
    inbound.bind(address)
    outbound.connect(address)

    def read() -> int:
        n = 0
        while True:
            try:
                got.append(inbound.recv(zmq.NOBLOCK))
            except zmq.Again:
                return n
            threads.add(threading.get_ident())
            n += 1

    ex.add_reader(inbound, read)
    threading.Timer(0.05, lambda: outbound.send(b"from the socket")).start()
    threading.Timer(0.08, lambda: ex.call_soon_threadsafe(got.append, b"from a thread")).start()
    loop.call_later(0.1, lambda: ex.call_soon_threadsafe(lambda: (got.append(b"from the loop"),
                                                                    threads.add(threading.get_ident()))))
    start = time.monotonic()
    ex.spin(0.3)
    elapsed = time.monotonic() - start
    assert got == [b"from the socket", b"from a thread", b"from the loop"]
    assert threads == {threading.get_ident()}
    assert elapsed / 0.01 / 3 <= len(ticks) <= elapsed / 0.01 + 1
    outbound.send(b"again")
    # spin_once answers with the work it did (the timer's tick may come before the message)
    deadline = time.monotonic() + 5.0
    while got[-1] != b"again":
        assert ex.spin_once(1.0) >= 1 and time.monotonic() < deadline
    threading.Timer(0.05, ex.request_shutdown).start()
    start = time.monotonic()
    ex.spin()
    assert time.monotonic() - start < 1.0
    ex.remove_reader(inbound)
    ex.close()
    assert loop.is_closed()
    inbound.close(linger=0)
    outbound.close(linger=0)


def test_one_executor_loop_serves_tls_itself_or_not_never_both():
    """A second page server of the other kind in one process is refused, not given a loop on which
    its secure WebSockets would never open (touch4d.eventloop)."""
    ex = Executor()
    loop = ex.asyncio_loop(serves_tls=False)
    assert ex.asyncio_loop(serves_tls=False) is loop
    with pytest.raises(ValueError, match="TLS"):
        ex.asyncio_loop(serves_tls=True)
    ex.close()


def test_on_a_loop_a_turn_asks_only_the_sockets_that_fired_and_each_message_still_comes_at_once():
    """A container's executor watches hundreds of sockets: a turn reads those whose FD fired (and
    those that held more than one read took), every socket only every FULL_POLL_S; a message that
    comes meanwhile is read at once, and a burst larger than one read is read to its end."""
    ex = Executor()
    ex.asyncio_loop()
    ctx = zmq.Context.instance()
    idle = [ctx.socket(zmq.PULL) for _ in range(60)]         # sockets nothing is sent to
    for k, sock in enumerate(idle):
        sock.bind(f"inproc://idle-{k}")
        ex.add_reader(sock, lambda: 0)
    inbound, outbound = ctx.socket(zmq.PULL), ctx.socket(zmq.PUSH)
    inbound.bind("inproc://busy")
    outbound.connect("inproc://busy")
    got, lag = [], []

    def read() -> int:                                        # one message a read: the rest wait a turn
        try:
            sent = float(inbound.recv(zmq.NOBLOCK))
        except zmq.Again:
            return 0
        got.append(sent)
        lag.append(time.monotonic() - sent)
        return 1

    ex.add_reader(inbound, read)
    polls = []
    poll = ex._poller.poll
    ex._poller.poll = lambda timeout=None: (polls.append(1), poll(timeout))[1]
    stop = time.monotonic() + 0.6

    def send(burst: int) -> None:
        for _ in range(burst):
            outbound.send(repr(time.monotonic()).encode())
        if time.monotonic() < stop:
            threading.Timer(0.01, send, args=(1 if burst > 1 else 5,)).start()

    threading.Timer(0.05, send, args=(1,)).start()
    ex.spin(0.8)
    assert len(got) >= 100                                    # every message of every burst read
    assert np.percentile(lag, 99) < 0.05                      # none waited for the next full poll
    assert len(polls) <= 0.8 / executor_module.FULL_POLL_S + 3   # every socket asked only that often
    for sock in [*idle, inbound]:
        ex.remove_reader(sock)
        sock.close(linger=0)
    outbound.close(linger=0)
    ex.close()


@pytest.mark.parametrize("on_loop", [False, True], ids=["poll", "loop"])
def test_interrupt_returns_from_spin_without_shutting_down_and_the_next_spin_spins(on_loop):
    """A container's commands run between spins: `interrupt` (from a callback or another thread)
    ends the current spin soon; the executor is not stopping, and the next spin runs as before."""
    ex = Executor()
    if on_loop:
        ex.asyncio_loop()
    ticks = []
    ex.create_timer(0.01, lambda: ticks.append(1))
    threading.Timer(0.05, ex.interrupt).start()
    start = time.monotonic()
    ex.spin(5.0)
    assert time.monotonic() - start < 1.0 and not ex.stopping
    ex.call_soon(ex.interrupt)                                # from a callback on its own thread
    start = time.monotonic()
    ex.spin(5.0)
    assert time.monotonic() - start < 1.0
    ticks.clear()
    start = time.monotonic()
    ex.spin(0.2)                                              # no interrupt left over: it spins its time
    # (its timer fires meanwhile; how often, a loaded machine decides)
    assert time.monotonic() - start >= 0.2 - 1e-3 and len(ticks) >= 2
    ex.close()

"""Best-effort real-time scheduling for the threads whose timing is the product (replay, receive stamps).

On a busy machine a normal thread that sleeps until a message is due can wake several
milliseconds late; a SCHED_FIFO thread preempts normal work when it wakes. Only threads that
block between short bursts of work use it. Without the privilege (not root, no CAP_SYS_NICE,
not Linux) nothing changes and the caller learns so.
"""
from __future__ import annotations

import os

import zmq

PRIORITY = 10  # low among real-time priorities: above every normal process, below kernel threads
# A loop that many nodes share (a container's, a study server's) runs one below the threads that feed
# it (ZeroMQ's I/O threads, a recorder's receiver, the broker: PRIORITY): a FIFO thread is never
# preempted by one of its own priority, so a loop that spun waiting for their work on their core
# would wait for ever; below them, they always get to run.
LOOP_PRIORITY = PRIORITY - 1


NOT_PERMITTED = "real-time priority not permitted (needs root or CAP_SYS_NICE)"   # what the logs say then


def raise_thread_priority(priority: int = PRIORITY, *, alone: bool = False) -> bool:
    """Make the calling thread SCHED_FIFO at `priority`; False (and unchanged) if not permitted.
    `alone`: the threads and processes it starts afterwards run at normal priority (SCHED_RESET_ON_FORK)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | (os.SCHED_RESET_ON_FORK if alone else 0), os.sched_param(priority))
    except (OSError, AttributeError):
        return False
    return True


def raise_loop_priority(priority: int = LOOP_PRIORITY) -> bool:
    """A loop shared by many nodes (a container's, a study server's): the calling thread alone at
    `priority`, so it preempts their background threads (a recorder's writer) instead of lending them
    its priority. False (and unchanged) if not permitted."""
    return raise_thread_priority(priority, alone=True)


def reset_thread_priority() -> None:
    """Back to normal scheduling for the calling thread."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


def realtime_permitted(priority: int = PRIORITY) -> bool:
    """Whether this process may use SCHED_FIFO at `priority` (tried on the calling thread, then undone)."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        os.sched_setscheduler(0, policy, param)
    except (OSError, AttributeError):
        return False
    return True


def bus_context(realtime: bool = True) -> zmq.Context:
    """A ZeroMQ context whose I/O threads run real-time when permitted (they carry every message).

    Only set when permitted: libzmq aborts if it cannot apply a scheduling policy it was given."""
    context = zmq.Context()
    if realtime and realtime_permitted():
        context.set(zmq.THREAD_SCHED_POLICY, os.SCHED_FIFO)
        context.set(zmq.THREAD_PRIORITY, PRIORITY)
    return context

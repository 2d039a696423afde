"""What every bus process does first and last, a node's, a group's or a container's
(touch4d.bus.process, touch4d.bus.container): logging, dying with whoever started it, real-time
priority, telling its starter that it is built; and reading a group's node list.
"""
from __future__ import annotations

import argparse
import ctypes
import logging
import os
import signal
import sys

from touch4d.bus import names
from touch4d.bus.realtime import NOT_PERMITTED, PRIORITY, raise_thread_priority
from touch4d.errors import Touch4dError

LAUNCHER_PID_ENV = "TOUCH4D_LAUNCHER_PID"
PARENT_PID_ENV = "TOUCH4D_PARENT_PID"   # a program that starts `touch4d launch` and wants the launch to end with it
READY_FD_ENV = "TOUCH4D_READY_FD"
_PR_SET_PDEATHSIG = 1


def die_with_parent(env: str = LAUNCHER_PID_ENV) -> None:
    """If $`env` names this process's parent, ask the kernel to SIGTERM this process when that parent
    dies, even by SIGKILL (Linux prctl PR_SET_PDEATHSIG); exit at once if the parent is already gone.
    The variable is removed: this process's own children are not told to watch a grandparent."""
    parent = os.environ.pop(env, None)
    if not parent or not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != int(parent):
        sys.exit(0)  # the parent died before the request took hold


def configure(args: argparse.Namespace, name: str) -> None:
    """What every node process does first: logging, dying with the launcher, real-time priority."""
    logging.basicConfig(level=args.log_level.upper(), stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")
    die_with_parent()
    if args.realtime:
        # Before any thread exists: the ZeroMQ I/O threads and the node's own threads inherit it.
        if raise_thread_priority():
            logging.getLogger(name).info("real-time priority (SCHED_FIFO %d)", PRIORITY)
        else:
            logging.getLogger(name).warning("%s: running at normal priority", NOT_PERMITTED)


def tell_ready() -> None:
    """Tell the launcher (if it asked, through $TOUCH4D_READY_FD) that the node is built."""
    fd = os.environ.pop(READY_FD_ENV, None)
    if fd is None:
        return
    try:
        os.write(int(fd), b"1")
        os.close(int(fd))
    except (OSError, ValueError):
        pass


class GroupError(Touch4dError, ValueError):
    """A group's node list that cannot be run: the text names the entry and what was expected (a ValueError
    too, for code that catches that)."""


def group_members(entries: list, namespace: str, where: str) -> tuple[list[tuple[str, type, dict]], set[str]]:
    """A group's nodes (`--nodes`, the launcher's JSON list: node, name, params, params_source,
    private) as (role, class, constructor arguments) under `namespace`, and the bus topics the group
    keeps in its process. Raises GroupError naming the entry."""
    from touch4d.bus.registry import NodeNotFound, find

    members, private = [], set()
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or not isinstance(entry.get("node"), str):
            raise GroupError(f"{where}[{i}]: expected an object with a \"node\", got {entry!r}")
        ref, role = entry["node"], entry.get("name")
        try:
            node_class = find(ref).load()
        except NodeNotFound as exc:
            raise GroupError(f"node {role}: node {ref!r}: {exc}") from None
        members.append((role, node_class, {"params": entry.get("params", {}), "kind": ref, "role": role,
                                           "params_source": entry.get("params_source"),
                                           "namespace": namespace}))
        topics = entry.get("private", [])
        if not isinstance(topics, list) or not all(isinstance(t, str) and t for t in topics):
            raise GroupError(f"{where}[{i}].private: expected a list of topics, got {topics!r}")
        private.update(names.resolve(t, namespace) for t in topics)
    return members, private

"""A container: the groups of several launches in one process, loaded and unloaded while it runs
(ROS 2's component container). Every node of every group shares one executor (one thread); each
group keeps its namespace, its private topics (touch4d.bus.local) and its page server's port.

Why: a study server's participants each run the same five nodes. Sixteen interpreters each keep
their own copy of the code's objects and data warm in the caches; one interpreter for eight
participants keeps one, and the same page input costs a quarter to a third less CPU (docs/bus.md). The price is
isolation: a crash takes every group of the container, which its supervisor (touch4d.bus.pool, the
parent side; this module is what runs inside the container) then loads again in a new one (each
participant loses at most the trial it was in, as when the server is killed).

    python -m touch4d.bus --container NAME [--bus FILE] [--log-level LEVEL]

Commands come on stdin, one JSON object a line:
  {"load": ID, "namespace": NS, "nodes": [...], "ready_file": PATH, "log": PATH}
      `nodes` as a group's `--nodes` (touch4d.bus.process.group_members); the ready file gets
      "ready" once every node is built, or "failed: REASON" (what was built is shut down again);
      after "ready", the ports its nodes bound as JSON where any serves one (`Node.endpoints`:
      `ready {"tracker": {"page": 40123}}`), so a port 0 asked for is found here, never raced for;
      `log`, optional: the group's log lines (its nodes' loggers, NS/ROLE) are appended there too.
  {"unload": ID}
      its nodes shut down, in reverse order; the others spin on.
A node that asks to stop (`Node.request_shutdown`) stops its own group, which is loaded again after
RESPAWN_DELAY_S, as a launcher restarts a group's process. A group with a `realtime` node (an
entry's "realtime": true) raises the container's loop thread, and it alone, to SCHED_FIFO where
permitted. End of stdin (the supervisor gone), SIGINT or SIGTERM: every group is unloaded and the
process exits.

Loads and unloads run between spins (`Executor.interrupt`): a page server binds its port while the
loop is not running. Meanwhile the other groups wait: a load costs them the time its nodes take to
build (tens of ms), once per participant joining.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
from dataclasses import dataclass, field

import zmq

from touch4d.atomic import write_atomic
from touch4d.bus import names
from touch4d.bus.config import resolve_bus_config
from touch4d.bus.executor import Executor
from touch4d.bus.heap import freeze_startup_heap
from touch4d.bus.logfiles import GroupLog
from touch4d.bus.realtime import LOOP_PRIORITY, NOT_PERMITTED, raise_loop_priority
from touch4d.bus.startup import GroupError, configure, group_members, tell_ready

log = logging.getLogger("container")

RESPAWN_DELAY_S = 0.5     # a group whose node asked to stop is built again after this
MAX_LINE = 1 << 20        # bytes of one command: a group's node list is a few kB
# s: how long a thread that wants the interpreter lock waits for the one holding it (CPython's default
# 5 ms). Each group's recorder writes from threads of its own: eight groups' writers made the loop
# wait up to 5 ms at a time, each; at 0.5 ms, p99 pose -> pulse at 16 participants fell from 18-24 ms
# to 12-13 ms (bench/bench_serve.py, back to back).
SWITCH_INTERVAL_S = 0.0005


@dataclass
class Group:
    """One loaded group: its command (to load it again), its nodes, its private topics, its log."""

    id: str
    command: dict
    nodes: list = field(default_factory=list)
    private: frozenset = frozenset()
    handler: logging.Handler | None = None


class _InNamespace(logging.Filter):
    """The records of one namespace's loggers (a node's logger is named NS/ROLE)."""

    def __init__(self, namespace: str):
        super().__init__()
        self.prefix = f"{namespace}/"

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name.startswith(self.prefix)


class Container:
    """The groups loaded on `executor`; `commands` come from the supervisor (`feed`)."""

    def __init__(self, executor: Executor, bus, name: str = "container"):
        self.executor, self.bus, self.name = executor, bus, name
        self.groups: dict[str, Group] = {}
        self.pending: list[dict] = []
        self._buffer = b""
        self._respawn: set[str] = set()   # groups a node of which asked to stop: loaded again soon
        self._frozen = False
        self._realtime: bool | None = None   # the loop thread's real-time priority: None until a group asks

    # ---- commands ----------------------------------------------------------------------------

    def feed(self, data: bytes) -> None:
        """Bytes read from the supervisor: each whole line a command, run after the current spin."""
        self._buffer += data
        *lines, self._buffer = self._buffer.split(b"\n")
        if len(self._buffer) > MAX_LINE:
            log.error("stdin: a command longer than %d bytes without a newline: dropped", MAX_LINE)
            self._buffer = b""
        for line in lines:
            if not line.strip():
                continue
            try:
                command = json.loads(line)
                if not isinstance(command, dict) or not ({"load", "unload"} & command.keys()):
                    raise ValueError("not an object with \"load\" or \"unload\"")
            except ValueError as exc:
                log.error("stdin: expected a JSON command {\"load\": ID, ...} or {\"unload\": ID}, got %.200r (%s)",
                          line, exc)
                continue
            self._queue(command)

    def run_pending(self) -> None:
        """The commands received, and the groups due to be loaded again (between spins)."""
        commands, self.pending = self.pending, []
        for command in commands:
            if "reload" in command:   # from _stop_requested, after RESPAWN_DELAY_S
                group = self.groups.get(command["reload"])
                if group is not None and group.id in self._respawn:
                    log.warning("%s: a node asked to stop: loading the group again", group.id)
                    self.unload(group.id)
                    self.load(group.command)
            elif "load" in command:
                self.load(command)
            else:
                self.unload(str(command["unload"]))

    # ---- groups ------------------------------------------------------------------------------

    def load(self, command: dict) -> None:
        """Build a group's nodes on the shared executor; its ready file says how it went."""
        gid, ready = str(command.get("load")), command.get("ready_file")
        if gid in self.groups:
            self._tell(ready, f"failed: a group {gid!r} is loaded already")
            return
        namespace = command.get("namespace") or ""
        group = Group(gid, command)
        try:
            namespace = names.check_namespace(namespace)
            if namespace and any(g.command.get("namespace") == namespace for g in self.groups.values()):
                raise ValueError(f"load {gid}: namespace {namespace!r} is another loaded group's")
            nodes = command.get("nodes")
            if not isinstance(nodes, list):
                raise GroupError(f"load {gid}: nodes: expected a JSON list, got {nodes!r}")
            members, private = group_members(nodes, namespace, f"load {gid}: nodes")
        except (GroupError, ValueError) as exc:
            log.error("%s", exc)
            self._tell(ready, f"failed: {exc}")
            return
        if command.get("log"):
            try:
                group.handler = GroupLog(command["log"])
            except OSError as exc:
                log.warning("%s: log %s: %s (its lines go to the container's output only)", gid, command["log"], exc)
            else:
                group.handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
                group.handler.addFilter(_InNamespace(namespace))
                logging.getLogger().addHandler(group.handler)
        group.private = frozenset(t.encode() for t in private)
        if any(entry.get("realtime") is True for entry in nodes):
            self._raise_priority(group)
        self.groups[gid] = group
        self._set_private()
        try:
            for role, node_class, kwargs in members:
                node = node_class(**kwargs, bus=self.bus, executor=self.executor)
                # request_shutdown may come from any thread: the respawn is arranged on the executor's
                node.group_stop = lambda gid=gid: self.executor.call_soon_threadsafe(self._stop_requested, gid)
                group.nodes.append(node)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - one group that cannot start must not stop the others
            self._log(group).error("%s: node %s could not start: %s", gid, role, exc,
                                   exc_info=not isinstance(exc, (OSError, ValueError)))
            self.unload(gid)
            self._tell(ready, f"failed: node {role}: {exc}")
            return
        if not self._frozen:
            freeze_startup_heap()   # the imports' objects, once: a later group's are its own to collect
            self._frozen = True
        self._log(group).info("%s: %d node(s) loaded in container %s (pid %d): %s", gid, len(group.nodes), self.name,
                              os.getpid(), f"every topic under {namespace}/" if namespace else "no namespace")
        served = {node.name: ends for node in group.nodes if (ends := node.endpoints())}
        self._tell(ready, f"ready {json.dumps(served)}" if served else "ready")

    def _raise_priority(self, group: Group) -> None:
        """A group whose node asks for `realtime` (its haptic loop): the container's loop thread runs
        SCHED_FIFO from then on, where permitted, and it alone (touch4d.bus.realtime.raise_loop_priority:
        a recorder's writer thread stays below the loop it records). Raised once, kept while it runs."""
        if self._realtime is not None:
            return
        self._realtime = raise_loop_priority()
        if self._realtime:
            self._log(group).info("%s: the container's loop runs at real-time priority (SCHED_FIFO %d) from now on",
                                  group.id, LOOP_PRIORITY)
        else:
            self._log(group).warning("%s: %s: the container's loop runs at normal priority", group.id, NOT_PERMITTED)

    def unload(self, gid: str) -> None:
        """Shut a group's nodes down (reverse order); an unknown id: nothing."""
        group = self.groups.pop(gid, None)
        self._respawn.discard(gid)
        if group is None:
            return
        for node in reversed(group.nodes):
            try:
                node.shutdown()
            except Exception:  # noqa: BLE001 - every node of the group must get its shutdown
                log.exception("%s: node %s failed to shut down", gid, node.name)
        self._set_private()
        self._log(group).info("%s: unloaded", gid)
        if group.handler is not None:
            logging.getLogger().removeHandler(group.handler)
            group.handler.close()

    def unload_all(self) -> None:
        for gid in list(self.groups)[::-1]:
            self.unload(gid)

    @staticmethod
    def _log(group: Group) -> logging.Logger:
        """The container's lines about a group, in the group's log too (NS/container)."""
        return logging.getLogger(names.node_name("container", group.command.get("namespace") or ""))

    def _stop_requested(self, gid: str) -> None:
        if gid in self.groups and gid not in self._respawn:
            self._respawn.add(gid)
            self.executor.call_later(RESPAWN_DELAY_S, lambda: self._queue({"reload": gid}))

    def _queue(self, command: dict) -> None:
        self.pending.append(command)
        self.executor.interrupt()

    def _set_private(self) -> None:
        self.executor.local.private = frozenset().union(*(g.private for g in self.groups.values()))

    @staticmethod
    def _tell(ready_file, text: str) -> None:
        if not ready_file:
            return
        try:
            write_atomic(ready_file, text + "\n")   # whole or absent: the supervisor never reads half a line
        except OSError as exc:
            log.error("ready file %s: %s", ready_file, exc)


def run_container(argv: list[str]) -> int:
    """`python -m touch4d.bus --container NAME`: see the module's doc."""
    parser = argparse.ArgumentParser(prog="touch4d.bus --container",
                                     description="Run the groups a supervisor loads, in one process.")
    parser.add_argument("--container", required=True, help="the container's name (its log lines)")
    parser.add_argument("--bus", help="bus config file (default: $TOUCH4D_BUS, else config/bus.yaml)")
    parser.add_argument("--log-level", default=os.environ.get("TOUCH4D_LOG_LEVEL", "INFO"))
    args = parser.parse_args(argv)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    args.realtime = False   # a container's groups share its thread: no node of them asks for more
    configure(args, args.container)
    executor = Executor()
    container = Container(executor, resolve_bus_config(args.bus), args.container)

    def stop(signum, frame):
        executor.request_shutdown()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)
    stdin = sys.stdin.fileno()
    os.set_blocking(stdin, False)

    def read() -> int:
        try:
            data = os.read(stdin, 65536)
        except BlockingIOError:
            return 0
        if not data:   # the supervisor is gone
            executor.remove_reader(stdin)
            executor.request_shutdown()
            return 0
        container.feed(data)
        return 1

    executor.add_reader(stdin, read)
    tell_ready()
    try:
        while not executor.stopping:
            executor.spin()
            container.run_pending()
    finally:
        container.unload_all()
        executor.close()
        zmq.Context.instance().destroy(linger=1000)
    return 0



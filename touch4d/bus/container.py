"""A container: the groups of several launches in one process, loaded and unloaded while it runs
(ROS 2's component container). Every node of every group shares one executor (one thread); each
group keeps its namespace, its private topics (touch4d.bus.local) and its page server's port.

Why: a study server's participants each run the same five nodes. Sixteen interpreters each keep
their own copy of the code's objects and data warm in the caches; one interpreter for eight
participants keeps one, and the same page input costs a quarter to a third less CPU (docs/bus.md). The price is
isolation: a crash takes every group of the container, which its supervisor then loads again in a
new one (each participant loses at most the trial it was in, as when the server is killed).

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
import logging.handlers
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import zmq

from touch4d.atomic import write_atomic
from touch4d.bus import names
from touch4d.bus.config import resolve_bus_config
from touch4d.bus.executor import Executor
from touch4d.bus.heap import freeze_startup_heap
from touch4d.bus.process import GroupError, _configure, _tell_ready, group_members
from touch4d.bus.realtime import LOOP_PRIORITY, NOT_PERMITTED, raise_loop_priority

log = logging.getLogger("container")

RESPAWN_DELAY_S = 0.5     # a group whose node asked to stop is built again after this
# A container that keeps dying (a node that crashes its process: a native fault, memory) must not take
# its other groups down with it again and again. A group whose containers died ISOLATE_AFTER times
# within CRASH_WINDOW_S is loaded alone from then on (a container of its own), and one whose
# containers died GIVE_UP_AFTER times is not loaded again (its ready file says why): the group at
# fault ends up alone and stopped, the others lose at most ISOLATE_AFTER trials each.
CRASH_WINDOW_S = 600.0
ISOLATE_AFTER = 2
GIVE_UP_AFTER = 3
# s: a container whose command pipe stays full this long (it reads none of its commands: hung in a
# node's C code, say) is taken for hung and killed, and started again as one that died. The
# supervisor never waits on a container: commands the pipe does not take wait in its memory.
UNREAD_LIMIT_S = 10.0
MAX_LINE = 1 << 20        # bytes of one command: a group's node list is a few kB
# s: how long a thread that wants the interpreter lock waits for the one holding it (CPython's default
# 5 ms). Each group's recorder writes from threads of its own: eight groups' writers made the loop
# wait up to 5 ms at a time, each; at 0.5 ms, p99 pose -> pulse at 16 participants fell from 18-24 ms
# to 12-13 ms (bench/bench_serve.py, back to back).
SWITCH_INTERVAL_S = 0.0005
# bytes of one log file (a container's NAME.log, a group's `log`): past it the file becomes NAME.log.1
# (the one before goes) and a new one begins, so a log costs at most twice this of disk, whatever a
# client makes a node write.
LOG_CAP = 8 << 20


def open_log(path, mode: str = "a", **kwargs):
    """`path` opened to append to ("a" or "ab"), created 0600, never through a symlink (OSError ELOOP:
    one planted there, say in a participant's folder, would have the server write where it points)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        return os.fdopen(fd, mode, **kwargs)
    except BaseException:
        os.close(fd)
        raise


class _GroupLog(logging.handlers.RotatingFileHandler):
    """A group's log lines (its `log` file): capped at LOG_CAP, one older file kept, opened by open_log."""

    def __init__(self, path):
        super().__init__(path, maxBytes=LOG_CAP, backupCount=1, encoding="utf-8")

    def _open(self):
        return open_log(self.baseFilename, "a", encoding=self.encoding)


class CappedLog:
    """A container's output: what its pipe carries, copied into `path` by a thread of its own until
    the file holds `cap` bytes; then it becomes PATH.1 (the one before goes) and a new one begins."""

    def __init__(self, path, cap: int | None = None):
        self.path, self.cap = Path(path), LOG_CAP if cap is None else cap
        self.file = open_log(self.path, "ab")
        self.size = os.fstat(self.file.fileno()).st_size
        self.thread: threading.Thread | None = None

    def follow(self, pipe) -> None:
        """Copy what `pipe` carries until its end (the container and whatever inherited it exited)."""
        self.thread = threading.Thread(target=self._copy, args=(pipe,), name=f"log {self.path.name}", daemon=True)
        self.thread.start()

    def _copy(self, pipe) -> None:
        try:
            while chunk := os.read(pipe.fileno(), 1 << 16):
                chunk = chunk[-self.cap:]   # one read over the cap: its end kept
                if self.size and self.size + len(chunk) > self.cap:
                    self.file.close()
                    os.replace(self.path, self.path.with_name(self.path.name + ".1"))
                    self.file, self.size = open_log(self.path, "ab"), 0
                self.file.write(chunk)
                self.file.flush()
                self.size += len(chunk)
        except (OSError, ValueError) as exc:   # the file gone, or closed by close() after its wait
            log.error("%s: no longer written: %s", self.path, exc)
        finally:
            pipe.close()

    def close(self, timeout: float = 5.0) -> None:
        if self.thread is not None:
            self.thread.join(timeout)
        self.file.close()


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
                group.handler = _GroupLog(command["log"])
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
    _configure(args, args.container)
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
    _tell_ready()
    try:
        while not executor.stopping:
            executor.spin()
            container.run_pending()
    finally:
        container.unload_all()
        executor.close()
        zmq.Context.instance().destroy(linger=1000)
    return 0


# ---- the supervisor's side -------------------------------------------------------------------------


class _Process:
    """One container process; `solo`: it holds one group only (a group whose containers kept dying)."""

    def __init__(self, name: str, proc, log_file, solo: bool = False):
        self.name, self.proc, self.log_file, self.solo = name, proc, log_file, solo
        self.counted = False   # its death counted against its groups (once, however often check() sees it)
        self._unsent = bytearray()       # command lines its pipe has not taken yet
        self._refused_since: float | None = None   # since when the pipe took none of them
        os.set_blocking(proc.stdin.fileno(), False)

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def send(self, command: dict) -> None:
        """Queue a command line and write what the pipe takes now; the rest goes at the next send or
        `flush` (a container that died drops it: check() loads its groups again)."""
        self._unsent += json.dumps(command, default=str).encode() + b"\n"
        self.flush()

    def flush(self) -> None:
        while self._unsent:
            try:
                written = os.write(self.proc.stdin.fileno(), self._unsent)
            except BlockingIOError:
                if self._refused_since is None:
                    self._refused_since = time.monotonic()
                return
            except (OSError, ValueError):   # it died, or its input was closed
                self._unsent.clear()
                break
            del self._unsent[:written]
            self._refused_since = None
        self._refused_since = None

    def hung(self, now: float) -> bool:
        """Its pipe has taken none of its commands for UNREAD_LIMIT_S."""
        return self._refused_since is not None and now - self._refused_since > UNREAD_LIMIT_S


@dataclass
class _Placed:
    """A group placed in a container: where, how its command is made, and the last one sent."""

    proc: _Process
    make: object
    command: dict


class ContainerPool:
    """Groups placed in containers of at most `per_container` groups each: up to `spread`
    containers are started before any takes a second group (one thread each: on a machine of that
    many cores, a few groups do not queue behind each other on one), then the least loaded with room
    takes the next. Commands are written without waiting (a container that reads none for
    UNREAD_LIMIT_S is killed as hung). One that dies is started again and its groups loaded again,
    each from its `make` (called anew: a command may name a new file each time); a group in
    ISOLATE_AFTER containers that died within CRASH_WINDOW_S is loaded alone from then on, and one
    in GIVE_UP_AFTER is not loaded again.

    `bus_file`: the containers' bus; `log_dir`: each container's output (NAME.log); `popen`:
    extra subprocess.Popen arguments (the supervisor's `preexec_fn`, say)."""

    def __init__(self, per_container: int, bus_file, log_dir, *, spread: int = 1, prefix: str = "container",
                 popen: dict | None = None):
        if per_container < 1 or spread < 1:
            raise ValueError(f"groups per container and containers to spread over: expected at least 1, got "
                             f"{per_container} and {spread}")
        self.per_container, self.spread = per_container, spread
        self.bus_file, self.log_dir, self.prefix = str(bus_file), Path(log_dir), prefix
        self.popen = popen or {}
        self.processes: list[_Process] = []
        self._placed: dict[str, _Placed] = {}   # group id -> where it is
        self._retiring: list[_Process] = []     # stopped (left empty), not yet exited
        self._deaths: dict[str, list[float]] = {}   # group id -> when containers it was in died (monotonic)
        self._alone: set[str] = set()           # groups loaded alone from now on
        self._count = 0
        self.restarts = 0

    def load(self, gid: str, make) -> str:
        """Place group `gid` (`make()` -> its load command without "load", e.g. its namespace, nodes and
        ready file) in a container; returns the container's name. Raises what `make` raises (nothing is
        placed then)."""
        if gid in self._placed:
            raise ValueError(f"group {gid!r} is placed already")
        command = make()
        alive = [p for p in self.processes if p.alive and not p.solo]
        room = [p for p in alive if len(self._groups(p)) < self.per_container]
        if gid in self._alone or self._recent_deaths(gid) >= ISOLATE_AFTER:
            self._alone.add(gid)
            proc = self._start(solo=True)
        elif not room or len(alive) < self.spread:
            proc = self._start()
        else:
            proc = min(room, key=lambda p: len(self._groups(p)))   # the least loaded
        self._place(gid, proc, make, command)
        return proc.name

    def unload(self, gid: str) -> None:
        """Take group `gid` out of its container (unknown: nothing); a container left empty stops."""
        placed = self._placed.get(gid)
        if placed is None:
            return
        self._note_death(placed.proc)   # a dead container's groups taken out before check() saw it still count
        del self._placed[gid]
        placed.proc.send({"unload": gid})
        if not self._groups(placed.proc):
            self._retire(placed.proc)

    def running(self, gid: str) -> bool:
        """Whether group `gid` is placed in a container that is alive, and has not said it failed (in
        its ready file: at its load, or at a reload after a node asked to stop)."""
        placed = self._placed.get(gid)
        if placed is None or not placed.proc.alive:
            return False
        ready = placed.command.get("ready_file")
        try:
            return not (ready and Path(ready).read_text().startswith("failed"))
        except OSError:
            return True   # not written yet: loading

    def container_of(self, gid: str) -> str | None:
        placed = self._placed.get(gid)
        return placed.proc.name if placed is not None else None

    def pids(self) -> list[int]:
        return [p.proc.pid for p in self.processes if p.alive]

    def check(self) -> dict[str, str]:
        """Start again each container that died and load its groups again: together in a new one,
        alone (a group in ISOLATE_AFTER dead containers within CRASH_WINDOW_S), or not at all (in
        GIVE_UP_AFTER: its ready file and log say so, and it is no longer placed). Returns what became
        of each of their groups: "again", "alone", "given up", or "failed" (its command could not be
        made again; its ready file and log say why). A container that cannot be started stays
        listed, with the groups it was to take, and is tried again at the next check. Call it
        periodically: it also writes the commands a container's pipe did not take yet, and kills a
        container that read none for UNREAD_LIMIT_S (started again here, as one that died)."""
        outcome: dict[str, str] = {}
        now = time.monotonic()
        for proc in self.processes:
            if proc.alive:
                proc.flush()
                if proc.hung(now):
                    log.error("container %s has read none of its commands for %g s: taken for hung, killed",
                              proc.name, UNREAD_LIMIT_S)
                    proc.proc.kill()
                    proc.proc.wait()
        for proc in [p for p in self.processes if not p.alive]:
            self._note_death(proc)
            groups = self._groups(proc)
            deaths = {gid: self._recent_deaths(gid) for gid in groups}
            for gid in groups:
                if deaths[gid] >= ISOLATE_AFTER:
                    self._alone.add(gid)
            together = [gid for gid in groups if gid not in self._alone]
            try:
                again = self._start() if together else None
            except OSError as exc:
                log.error("container %s died and cannot be started again (%s); trying again soon", proc.name, exc)
                continue
            if groups:
                code = proc.proc.returncode
                how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"
                log.warning("container %s %s with %d group(s): %s", proc.name, how, len(groups),
                            ", ".join(f"{gid} ({deaths[gid]} in {CRASH_WINDOW_S:g} s)" for gid in groups))
            if again is not None:
                self.restarts += 1
            left = []   # groups whose own container could not be started: with the dead one, tried again
            for gid in groups:
                placed = self._placed.pop(gid)
                if deaths[gid] >= GIVE_UP_AFTER:
                    self._give_up(gid, placed.command, f"its process died {deaths[gid]} times in "
                                                       f"{CRASH_WINDOW_S:g} s; not started again")
                    outcome[gid] = "given up"
                    continue
                try:
                    command = placed.make()
                except Exception as exc:  # noqa: BLE001 - the others are loaded again all the same
                    self._give_up(gid, placed.command, f"cannot be loaded again: {exc}")
                    outcome[gid] = "failed"
                    continue
                if gid in together:
                    target = again
                else:
                    try:
                        target = self._start(solo=True)
                    except OSError as exc:
                        log.error("%s: a container of its own cannot be started (%s); trying again soon", gid, exc)
                        self._placed[gid] = placed
                        left.append(gid)
                        continue
                    self.restarts += 1
                    if deaths[gid] == ISOLATE_AFTER:
                        log.warning("%s: loaded alone from now on (its containers died %d times in %g s)", gid,
                                    deaths[gid], CRASH_WINDOW_S)
                self._place(gid, target, placed.make, command)
                outcome[gid] = "again" if target is again else "alone"
            if not left:
                self.processes.remove(proc)
                proc.log_file.close()
        return outcome

    def _note_death(self, proc: _Process) -> None:
        """Count a dead container's death against each group in it, once."""
        if proc.counted or proc.alive:
            return
        proc.counted = True
        now = time.monotonic()
        for gid in self._groups(proc):
            self._deaths[gid] = [t for t in self._deaths.get(gid, []) if now - t < CRASH_WINDOW_S] + [now]

    def _recent_deaths(self, gid: str) -> int:
        now = time.monotonic()
        return sum(1 for t in self._deaths.get(gid, []) if now - t < CRASH_WINDOW_S)

    @staticmethod
    def _give_up(gid: str, command: dict, why: str) -> None:
        """A group not loaded again (out of the pool already): `why` in its ready file and its log."""
        log.error("%s: %s", gid, why)
        for key, mode, text in (("ready_file", "w", f"failed: {why}\n"), ("log", "a", f"{gid}: {why}\n")):
            if command.get(key):
                try:
                    with (open(command[key], mode) if key == "ready_file" else open_log(command[key])) as f:
                        f.write(text)
                except OSError as exc:
                    log.error("%s: cannot write %s: %s", gid, command[key], exc)

    def close(self, timeout: float = 15.0) -> None:
        """Every container told to stop (end of its stdin): unloads its groups; killed after `timeout`
        (those already stopping too)."""
        for proc in self.processes:
            _end_input(proc)
        deadline = time.monotonic() + timeout
        for proc in [*self.processes, *self._retiring]:
            try:
                proc.proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.proc.kill()
                proc.proc.wait()
            proc.log_file.close()
        self.processes.clear()
        self._retiring.clear()
        self._placed.clear()

    def _groups(self, proc: _Process) -> list[str]:
        return sorted(gid for gid, placed in self._placed.items() if placed.proc is proc)

    def _place(self, gid: str, proc: _Process, make, command: dict) -> None:
        self._placed[gid] = _Placed(proc, make, command)
        proc.send({"load": gid, **command})   # a container that just died: check() loads it again

    def _start(self, solo: bool = False) -> _Process:
        self._count += 1
        name = f"{self.prefix}-{self._count}"
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log_file = CappedLog(self.log_dir / f"{name}.log")
        try:
            popen = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.bus", "--container", name, "--bus",
                                      self.bus_file], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, **self.popen)
        except BaseException:
            log_file.close()
            raise
        log_file.follow(popen.stdout)
        proc = _Process(name, popen, log_file, solo)
        self.processes.append(proc)
        return proc

    def _retire(self, proc: _Process) -> None:
        """A container left empty: told to stop, reaped (killed after 15 s) by a thread of its own."""
        _end_input(proc)
        self.processes.remove(proc)
        self._retiring.append(proc)   # close() waits for it too

        def reap():
            try:
                proc.proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.proc.kill()
                proc.proc.wait()
            proc.log_file.close()
            if proc in self._retiring:
                self._retiring.remove(proc)

        threading.Thread(target=reap, daemon=True).start()


def _end_input(proc: _Process) -> None:
    """Close a container's stdin: it unloads what is left and exits."""
    proc.flush()   # what the pipe takes now: at the end of its input the container unloads every group anyway
    try:
        proc.proc.stdin.close()
    except OSError:
        pass

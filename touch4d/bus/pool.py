"""The container pool, a container's supervisor (the parent side of touch4d.bus.container): groups
placed in container processes, their commands written without waiting, a container that dies
started again and its groups loaded again, by the restart policy of touch4d.bus.supervisor.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from touch4d.bus.logfiles import CappedLog, open_log
from touch4d.bus.supervisor import RestartPolicy

log = logging.getLogger("container")

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
        # group id -> the deaths of the containers it was in: loaded alone, or given up
        self.policy = RestartPolicy(window=CRASH_WINDOW_S, isolate_after=ISOLATE_AFTER, give_up_after=GIVE_UP_AFTER)
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
        if self.policy.alone(gid):
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
            verdicts = {gid: self.policy.verdict(gid) for gid in groups}
            together = [gid for gid in groups if not verdicts[gid].alone]
            try:
                again = self._start() if together else None
            except OSError as exc:
                log.error("container %s died and cannot be started again (%s); trying again soon", proc.name, exc)
                continue
            if groups:
                code = proc.proc.returncode
                how = f"was killed by {signal.Signals(-code).name}" if code < 0 else f"exited with {code}"
                log.warning("container %s %s with %d group(s): %s", proc.name, how, len(groups),
                            ", ".join(f"{gid} ({verdicts[gid].deaths} in {CRASH_WINDOW_S:g} s)" for gid in groups))
            if again is not None:
                self.restarts += 1
            left = []   # groups whose own container could not be started: with the dead one, tried again
            for gid in groups:
                placed = self._placed.pop(gid)
                if not verdicts[gid].restart:
                    self._give_up(gid, placed.command, f"its process died {verdicts[gid].deaths} times in "
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
                    if verdicts[gid].deaths == ISOLATE_AFTER:
                        log.warning("%s: loaded alone from now on (its containers died %d times in %g s)", gid,
                                    verdicts[gid].deaths, CRASH_WINDOW_S)
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
        for gid in self._groups(proc):
            self.policy.died(gid)

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

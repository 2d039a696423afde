"""Helpers for tests that need a bus: a broker on free loopback ports, node and launch processes
that are always cleaned up, and waiting without tight timing.

    from touch4d.bus.testing import running_broker, node_process, launch_process, collect, wait_until

    def test_relay():
        with running_broker() as bus:                          # in-process broker, free ports
            with node_process("example_listener", bus, params={"relay_topic": "out"}) as proc:
                node = Node("probe", bus=bus)                   # an in-process node on that bus
                ...
                wait_until(lambda: ..., timeout=10)

    def test_demo():
        with launch_process(["launch/demo.yaml", "--duration", "5"]) as run:   # own broker, free ports
            run.bus                                             # its BusConfig, once nodes started
            run.wait_for_line("talker", timeout=10)             # output lines, as they come
        run.returncode

Every process started here runs in its own process group, which is killed on exit (also when
the test fails); a context manager's exit never takes more than a few seconds.
"""
from __future__ import annotations

import json
import os
import re
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from touch4d.bus.broker import Broker
from touch4d.bus.config import ENV_VAR, BusConfig, CurveKeys
from touch4d.bus.node import Node
from touch4d.bus.startup import READY_FD_ENV

REPO = Path(__file__).resolve().parents[2]


def wait_until(predicate: Callable[[], object], timeout: float = 10.0, interval: float = 0.02,
               spin: Node | None = None):
    """Poll `predicate` until it is true (returns its value) or raise TimeoutError after `timeout` s.
    With `spin`, that node is spun between polls (so its callbacks run)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"condition not met within {timeout} s")
        if spin is not None:
            spin.spin_once(interval)
        else:
            time.sleep(interval)


def free_port() -> int:
    """A TCP port on loopback that nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def running_broker(curve: CurveKeys | None = None, hwm: int = 10000) -> Iterator[BusConfig]:
    """A broker in this process on free loopback ports; yields the BusConfig nodes connect with."""
    broker = Broker(BusConfig(pub_port=0, sub_port=0, hwm=hwm, curve=curve, source="<test broker>"))
    bus = broker.start()
    try:
        yield bus
    finally:
        broker.stop()


def bus_env(bus: BusConfig, **extra: str) -> dict[str, str]:
    """Environment for a child process that should use `bus`."""
    return {**os.environ, ENV_VAR: bus.to_json(), "PYTHONUNBUFFERED": "1", **extra}


class ProcessOutput:
    """The lines a child process writes (stdout and stderr merged), collected by a thread."""

    def __init__(self, proc: subprocess.Popen):
        self.proc = proc
        self.started = False   # node_process: the node said it is started
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for raw in self.proc.stdout:
            with self._cond:
                self.lines.append(raw.decode(errors="replace").rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    @property
    def text(self) -> str:
        with self._cond:
            return "\n".join(self.lines)

    def wait_for_line(self, pattern: str, timeout: float = 10.0) -> str:
        """The first line matching regex `pattern`; TimeoutError (with the output so far) otherwise."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for line in self.lines:
                    if regex.search(line):
                        return line
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no line matching {pattern!r} within {timeout} s; output:\n" + "\n".join(self.lines))
                self._cond.wait(min(left, 0.1))

    def join(self, timeout: float = 5.0) -> None:
        self._thread.join(timeout)

    @property
    def returncode(self) -> int | None:
        return self.proc.returncode

    @property
    def pid(self) -> int:
        return self.proc.pid


def _start(cmd: list[str], env: dict[str, str], pass_fds: tuple[int, ...] = ()) -> ProcessOutput:
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env=env, cwd=REPO, start_new_session=True, pass_fds=pass_fds)
    return ProcessOutput(proc)


def _finish(out: ProcessOutput, stop_signal: int, grace: float) -> None:
    """Signal the process, wait up to `grace` s, then kill its whole process group."""
    proc = out.proc
    if proc.poll() is None:
        try:
            os.kill(proc.pid, stop_signal)
            proc.wait(grace)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # whatever is left of the group, children included
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()
    out.join()


@contextmanager
def node_process(module: str, bus: BusConfig, name: str | None = None, params: dict | None = None,
                 grace: float = 5.0, realtime: bool = False, start_timeout: float = 60.0) -> Iterator[ProcessOutput]:
    """Run node `module` (a name as in launch files, or a module path) as its own process on `bus`;
    yields once the node is started (set up, connected, its subscriptions in force: it says so on
    the pipe the launcher also uses) or has exited, at most `start_timeout` s; SIGTERM then kill on exit."""
    cmd = [sys.executable, "-u", "-m", "touch4d.bus", module, "--name", name or module,
           "--params", json.dumps(params or {}), *(["--realtime"] if realtime else [])]
    ready_r, ready_w = os.pipe()
    try:
        out = _start(cmd, bus_env(bus, **{READY_FD_ENV: str(ready_w)}), pass_fds=(ready_w,))
    finally:
        os.close(ready_w)
    try:
        # A byte when started; end of file when the process exits first (or never, after the timeout).
        readable = select.select([ready_r], [], [], start_timeout)[0]
        out.started = bool(readable) and os.read(ready_r, 1) == b"1"
    finally:
        os.close(ready_r)
    try:
        yield out
    finally:
        _finish(out, signal.SIGTERM, grace)


class LaunchRun(ProcessOutput):
    """A running `touch4d launch`; `bus` is its broker's config once every node has started."""

    def __init__(self, proc: subprocess.Popen, ready_file: Path):
        super().__init__(proc)
        self.ready_file = ready_file

    @property
    def bus(self) -> BusConfig:
        return self.wait_ready()

    def wait_ready(self, timeout: float = 20.0) -> BusConfig:
        wait_until(lambda: self.ready_file.exists() and self.ready_file.stat().st_size > 0 or self.proc.poll() is not None,
                   timeout)
        if not self.ready_file.exists():
            raise RuntimeError(f"launch exited with {self.proc.returncode} before starting its nodes:\n{self.text}")
        return BusConfig.from_json(self.ready_file.read_text())

    def stop(self, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
        """Send `sig` (Ctrl+C by default) and wait for the launcher to exit; returns its exit code."""
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)
        return self.proc.wait(timeout)


@contextmanager
def launch_process(args: list[str], bus_config: str | None = None, grace: float = 5.0,
                   cwd: str | Path | None = None) -> Iterator[LaunchRun]:
    """Run `touch4d launch ARGS` (in `cwd`, default the repository) with a broker on free loopback
    ports (unless `bus_config` names a file); on exit Ctrl+C it, then kill its whole process group."""
    with tempfile.TemporaryDirectory(prefix="touch4d-launch-") as tmp:
        ready = Path(tmp) / "bus.json"
        if bus_config is None:
            bus_config = str(Path(tmp) / "bus.yaml")
            Path(bus_config).write_text("broker: {bind: 127.0.0.1, pub_port: 0, sub_port: 0}\nconnect: 127.0.0.1\n")
        cmd = [sys.executable, "-u", "-m", "touch4d.cli", "launch", *args, "--bus", bus_config,
               "--ready-file", str(ready)]
        env = {k: v for k, v in os.environ.items() if k != ENV_VAR}
        env["PYTHONUNBUFFERED"] = "1"
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                env=env, cwd=cwd or REPO, start_new_session=True)
        run = LaunchRun(proc, ready)
        try:
            yield run
        finally:
            _finish(run, signal.SIGINT, grace)


def collect(node: Node, topic: str, msg_type, latest_only: bool = False) -> list:
    """Subscribe `node` to `topic` and return the list its messages are appended to."""
    received: list = []
    node.create_subscription(topic, msg_type, received.append, latest_only=latest_only)
    return received


def pids_alive(pids) -> list[int]:
    """Those of `pids` that still exist (zombies excluded)."""
    alive = []
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            continue
        if state != "Z":
            alive.append(pid)
    return alive

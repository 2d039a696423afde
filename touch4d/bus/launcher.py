"""`touch4d launch`: the broker plus one process per node (or per `group` of nodes), their output
prefixed, a clean stop.

Children stay in the launcher's process group (Ctrl+C in a terminal reaches them all at once) and
are told to die with the launcher. On Ctrl+C, SIGTERM or the end of `--duration`, every node gets
SIGTERM, has STOP_GRACE seconds to run `on_shutdown` and exit, and is then killed.

Each node tells the launcher when it is built (a byte on a pipe, see touch4d.bus.process). A node
that exits before that failed to start (a bad scene, SteamVR not running...): unless its launch
entry says `respawn`, the whole launch stops and exits non-zero, the node's error the last line.
(Files and ports are checked before, by touch4d.bus.preflight.) While it runs, the launcher reads
the nodes' heartbeats and warns once when two nodes publish a topic another node waits for.
A broker that goes away (killed, or the other machine's with `--no-broker`) stops the launch the
same way, named in the last line: the nodes' shutdown sends the boards NMT STOP.
"""
from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import zmq

from touch4d.bus import names, transport
from touch4d.bus.broker import Broker, BrokerWatch
from touch4d.bus.config import ENV_VAR, BusConfig
from touch4d.bus.launchfile import NodeSpec, group_entries, processes
from touch4d.bus.startup import LAUNCHER_PID_ENV, READY_FD_ENV
from touch4d.bus.supervisor import RestartPolicy
from touch4d.bus.topology import shared_inputs, shared_text
from touch4d.errors import ConfigError
from touch4d.messages import Heartbeat, MessageError, decode
from touch4d.stdio import EXIT_PIPE_CLOSED, silence_stdout

STOP_GRACE = 1.5
BEAT_TIMEOUT = 3.5   # s without a heartbeat after which a node no longer counts as publishing
MAX_RESPAWN_DELAY = 5.0   # s: a node that keeps failing to start waits twice as long each time, up to this
_COLORS = ("36", "33", "35", "32", "34", "31", "96", "93", "95", "92")


@dataclass
class _Child:
    """One process of the launch: one node, or the nodes of a group (touch4d.bus.launchfile.processes)."""

    name: str
    specs: list[NodeSpec]
    proc: subprocess.Popen | None = None
    started: float = 0.0
    buffer: bytes = b""
    last_lines: list[str] = field(default_factory=list)
    restart_at: float | None = None
    failed: bool = False
    ready: bool = False       # the node said it is built
    ready_fd: int | None = None

    @property
    def group(self) -> bool:
        return bool(self.specs[0].group)

    @property
    def respawn(self) -> bool:
        return any(s.respawn for s in self.specs)   # a node that asks to come back brings its group

    @property
    def respawn_delay(self) -> float:
        return max(s.respawn_delay for s in self.specs)

    @property
    def label(self) -> str:
        return f"{'group' if self.group else 'node'} '{self.name}'"

    @property
    def title(self) -> str:
        """How the launcher names it: node 'ROLE' (MODULE), or group 'NAME' (ROLE: MODULE, ...)."""
        if not self.group:
            return f"{self.label} ({self.specs[0].module})"
        return f"{self.label} ({', '.join(f'{s.role}: {s.module}' for s in self.specs)})"


class Launcher:
    """Runs one launch: `run()` returns the exit code (0 after a clean stop)."""

    def __init__(self, nodes: dict[str, NodeSpec], bus: BusConfig, *, start_broker: bool = True,
                 duration: float | None = None, ready_file: str | None = None, out=None,
                 launch_file: str | None = None, bus_file: str | None = None, signals: list[int] | None = None):
        self.bus = bus
        self.start_broker = start_broker
        self.duration = duration
        self.ready_file = ready_file
        self.files = (launch_file, bus_file)   # said once at start: which files this launch runs
        self.out = out or sys.stdout.buffer
        self.children = {name: _Child(name, specs) for name, specs in processes(nodes).items()}
        # A child that `respawn`s: started again after its delay, backing off while it fails to start.
        self._restarts = RestartPolicy(backoff=2.0, max_delay=MAX_RESPAWN_DELAY)
        self.namespace = next((spec.namespace for spec in nodes.values()), "")   # one per launch
        width = max([len(r) for r in self.children] + [6])
        color = self.out is sys.stdout.buffer and sys.stdout.isatty()
        self._prefix = {}
        for i, role in enumerate([*self.children, "launch"]):
            text = f"[{role}]".ljust(width + 2) + " "
            self._prefix[role] = (f"\x1b[{_COLORS[i % len(_COLORS)]}m{text}\x1b[0m" if color else text).encode()
        self._stop_reason: str | None = None
        self._early = signals if signals is not None else []   # SIGINT/SIGTERM that came before run()
        self._start_failure: tuple[str, int] | None = None  # (what to say last, exit code)
        self._output_closed = False
        self._selector = selectors.DefaultSelector()
        self._env: dict[str, str] = {}
        self._broker_lost = lambda: None
        self._broker_gone: str | None = None
        self._watch: zmq.Socket | None = None      # heartbeats: which node publishes what
        self._beats: dict[str, tuple[float, Heartbeat]] = {}
        self._warned_shared: set[tuple[str, tuple[str, ...]]] = set()

    # ---- output ------------------------------------------------------------------------------

    def say(self, text: str) -> None:
        self._emit("launch", [text.encode()])

    def _emit(self, role: str, lines: list[bytes]) -> None:
        prefix = self._prefix[role]
        try:
            self.out.write(b"".join(prefix + line + b"\n" for line in lines))
            self.out.flush()
        except BrokenPipeError:
            # Whoever read the output is gone (`touch4d launch | head`): stop every node cleanly.
            silence_stdout()
            self.out = open(os.devnull, "wb")
            self._output_closed = True
            if self._stop_reason is None:
                self._stop_reason = "its output was closed"

    def _read(self, child: _Child) -> bool:
        """Pass on the complete lines a child has written; False at end of file."""
        try:
            data = os.read(child.proc.stdout.fileno(), 65536)
        except BlockingIOError:
            return True
        except OSError:
            data = b""
        if not data:
            if child.buffer:
                self._emit(child.name, [child.buffer])
                self._remember(child, [child.buffer])
                child.buffer = b""
            return False
        *lines, child.buffer = (child.buffer + data).split(b"\n")
        if lines:
            self._emit(child.name, lines)
            self._remember(child, lines)
        return True

    @staticmethod
    def _remember(child: _Child, lines: list[bytes]) -> None:
        text = [ln.decode(errors="replace").rstrip() for ln in lines]
        child.last_lines = (child.last_lines + [t for t in text if t.strip()])[-5:]

    # ---- processes ---------------------------------------------------------------------------

    def _spawn(self, child: _Child) -> None:
        spec = child.specs[0]
        if child.group:
            cmd = [sys.executable, "-u", "-m", "touch4d.bus", "--group", child.name, "--nodes",
                   json.dumps(group_entries(child.specs), default=str)]
        else:
            cmd = [sys.executable, "-u", "-m", "touch4d.bus", spec.module, "--name", spec.role,
                   "--params", json.dumps(spec.params, default=str), "--params-source", spec.source]
        if any(s.realtime for s in child.specs):
            cmd.append("--realtime")
        if spec.namespace:
            cmd += ["--namespace", spec.namespace]
        ready_r, ready_w = os.pipe()
        try:
            child.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                          stderr=subprocess.STDOUT, env={**self._env, READY_FD_ENV: str(ready_w)},
                                          close_fds=True, pass_fds=(ready_w,))
        except BaseException:
            os.close(ready_r)
            raise
        finally:
            os.close(ready_w)
        os.set_blocking(child.proc.stdout.fileno(), False)
        self._selector.register(child.proc.stdout, selectors.EVENT_READ, child)
        child.ready, child.ready_fd = False, ready_r
        self._selector.register(ready_r, selectors.EVENT_READ, ("ready", child))
        child.started = time.monotonic()
        child.restart_at = None
        child.last_lines = []

    def _read_ready(self, child: _Child) -> None:
        """The node wrote its ready byte, or closed the pipe (exited, ready or not)."""
        try:
            data = os.read(child.ready_fd, 16)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        child.ready = child.ready or bool(data)
        self._close_ready(child)

    def _close_ready(self, child: _Child) -> None:
        if child.ready_fd is not None:
            self._selector.unregister(child.ready_fd)
            os.close(child.ready_fd)
            child.ready_fd = None

    def _reap(self, child: _Child) -> None:
        """Handle a child that exited: report it and plan a restart if its spec asks for one."""
        proc = child.proc
        while self._read(child):
            pass
        if child.ready_fd is not None:
            self._read_ready(child)
        self._selector.unregister(proc.stdout)
        proc.stdout.close()
        child.proc = None
        code = proc.returncode
        if self._stop_reason is not None:
            return
        title = child.title
        what = f"exited with code {code}" if code >= 0 else f"was killed by {signal.Signals(-code).name}"
        failed_start = not child.ready and code != 0
        if failed_start:
            cause = child.last_lines[-1] if child.last_lines else "no output"
            if not child.group:   # a group's cause keeps the name of the node that failed
                cause = cause.removeprefix(f"node {child.name}: ")
            line = f"{title} failed to start: {what}: {cause}"
            self.say(line)
        else:
            self.say(f"{title} {what}")
        if child.respawn:
            delay = self._restarts.died(child.name, started=not failed_start, delay=child.respawn_delay).delay
            child.restart_at = time.monotonic() + delay
            self.say(f"respawning '{child.name}' in {delay:.1f} s")
        elif code != 0:
            child.failed = True
            if failed_start and self._start_failure is None:
                # A stack without one of its nodes is not the stack the user asked for: stop it.
                self._start_failure = (line, code if code > 0 else 1)
                self._stop_reason = f"{child.label} failed to start"

    def _running(self) -> list[_Child]:
        return [c for c in self.children.values() if c.proc is not None]

    # ---- main loop ---------------------------------------------------------------------------

    def run(self) -> int:
        # Ctrl+C from here on only sets the stop reason: one that came while the broker was starting
        # would otherwise leave its sockets open and the interpreter waiting on them at exit.
        wake_r, wake_w = os.pipe()
        os.set_blocking(wake_r, False)
        os.set_blocking(wake_w, False)
        old_fd = signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
        handlers = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        for signum in self._early:      # a stop asked for while the launch was being read
            self._on_signal(signum, None)
        old_chld = signal.signal(signal.SIGCHLD, lambda *_: None)
        self._selector.register(wake_r, selectors.EVENT_READ, None)
        broker = watch = None
        try:
            realtime = any(s.realtime for c in self.children.values() for s in c.specs)  # the loop crosses the broker
            broker = Broker(self.bus, realtime=realtime) if self.start_broker else None
            endpoints = broker.start() if broker else self.bus
            self._env = {**os.environ, ENV_VAR: endpoints.for_clients().to_json(), LAUNCHER_PID_ENV: str(os.getpid()),
                         "PYTHONUNBUFFERED": "1"}
            try:
                watch = BrokerWatch(endpoints.for_clients())   # a broker that dies stops the launch, named
                self._broker_lost = watch.lost
            except ConfigError:
                watch = None   # no client keys on this machine: nothing to watch with
            if self.files[0]:
                self.say(f"launch file {self.files[0]}; bus config {self.files[1] or 'defaults'}"
                         + (f"; every topic under {self.namespace}/" if self.namespace else ""))
            if broker:
                self.say(f"broker: publishers connect to {endpoints.pub_endpoint}, subscribers to "
                         f"{endpoints.sub_endpoint}{' (CURVE)' if endpoints.curve else ''}")
            self._open_watch(endpoints)
            for child in self.children.values():
                if self._stop_reason is not None:
                    break   # stopped while starting: start no more
                self._spawn(child)
            nodes = sum(len(c.specs) for c in self.children.values())
            self.say(f"started {nodes} node(s)"
                     + (f" in {len(self.children)} process(es)" if nodes != len(self.children) else "") + ": "
                     + ", ".join(f"{c.specs[0].role} ({c.specs[0].module})" if not c.group else
                                 f"{c.name} ({', '.join(f'{s.role}: {s.module}' for s in c.specs)})"
                                 for c in self.children.values()))
            if self.ready_file:
                Path(self.ready_file).write_text(endpoints.for_clients().to_json())
            self._loop()
            self._stop_all()
        finally:
            for child in self._running():
                child.proc.kill()
                child.proc.wait()
            for child in self.children.values():
                self._close_ready(child)
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
            signal.signal(signal.SIGCHLD, old_chld)
            signal.set_wakeup_fd(old_fd)
            self._selector.close()
            os.close(wake_r)
            os.close(wake_w)
            if watch is not None:
                watch.close()
            if self._watch is not None:
                self._watch.close(linger=0)
            if broker:
                broker.stop()
        failed = [c.name for c in self.children.values() if c.failed]
        if self._output_closed:
            return EXIT_PIPE_CLOSED
        if self._start_failure is not None:
            line, code = self._start_failure
            self.say(f"stopped: {line}")   # the cause, last, where the user looks
            return code
        if self._broker_gone:
            self.say(f"stopped: {self._broker_gone}")   # the cause, last, where the user looks
            return 1
        if failed:
            self.say(f"stopped; node(s) that failed: {', '.join(failed)}")
            return 1
        self.say("stopped")
        return 0

    def _on_signal(self, signum, frame) -> None:
        if self._stop_reason is None:
            self._stop_reason = signal.Signals(signum).name

    def _loop(self) -> None:
        end = None if self.duration is None else time.monotonic() + self.duration
        while self._stop_reason is None:
            now = time.monotonic()
            if end is not None and now >= end:
                self._stop_reason = f"--duration {self.duration:g} s"
                break
            self._pump(0.2 if end is None else min(0.2, end - now))
            gone = self._broker_lost()
            if gone:
                self._broker_gone = self._stop_reason = gone
                break
            self._check_publishers()
            for child in self.children.values():
                if child.proc is not None and child.proc.poll() is not None:
                    self._reap(child)
                elif child.proc is None and child.restart_at is not None and time.monotonic() >= child.restart_at \
                        and self._stop_reason is None:
                    self._spawn(child)
            if self.children and not self._running() and not any(c.restart_at for c in self.children.values()):
                self._stop_reason = "every node has exited"

    def _open_watch(self, endpoints: BusConfig) -> None:
        """Listen to the nodes' heartbeats (what each publishes) to warn about shared inputs."""
        try:
            self._watch = transport.subscriber(zmq.Context.instance(), endpoints.for_clients(),
                                               topics=[names.heartbeat_key(self.namespace)])
        except ConfigError:
            self._watch = None   # no client keys on this machine: nothing to listen with

    def _check_publishers(self) -> None:
        """Warn once per topic that two nodes publish and a node waits for (touch4d.bus.topology)."""
        if self._watch is None:
            return
        now = time.monotonic()
        while True:
            try:
                frames = self._watch.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            try:
                beat = decode(frames[-1], Heartbeat)
            except MessageError:
                continue
            if names.in_namespace(beat.node, self.namespace):   # another stack's nodes are not ours to judge
                self._beats[beat.node] = (now, beat)
        live = [beat for heard, beat in self._beats.values() if now - heard <= BEAT_TIMEOUT]
        for topic, nodes in shared_inputs(live).items():
            if (topic, tuple(nodes)) not in self._warned_shared:
                self._warned_shared.add((topic, tuple(nodes)))
                self.say(f"warning: {shared_text(topic, nodes)}")

    def _pump(self, timeout: float) -> None:
        for key, _ in self._selector.select(max(timeout, 0)):
            if key.data is None:
                try:
                    os.read(key.fd, 4096)
                except BlockingIOError:
                    pass
            elif isinstance(key.data, tuple):
                self._read_ready(key.data[1])
            elif key.data.proc is not None:
                self._read(key.data)

    def _stop_all(self) -> None:
        self.say(f"stopping ({self._stop_reason})")
        running = self._running()
        for child in running:
            try:
                child.proc.send_signal(signal.SIGTERM)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + STOP_GRACE
        while (running := self._running()) and time.monotonic() < deadline:
            self._pump(min(0.05, max(0.0, deadline - time.monotonic())))
            for child in running:
                if child.proc.poll() is not None:
                    self._reap(child)
        for child in self._running():
            self.say(f"{child.label} did not stop within {STOP_GRACE} s: killing it")
            child.proc.kill()
            child.proc.wait()
            self._reap(child)

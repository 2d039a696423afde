"""Running a participant's session through the full stack: `run_session` starts launch/study.yaml
with the session's overrides and waits for the study node to say it is done; `run_simulation` runs
N simulated participants in turn. The session folder's files: touch4d.study.store.

However a run ends (done, SIGINT, SIGTERM, SIGHUP, an exception), the stack it launched is stopped
(the launcher stops its nodes; the motor node sends zero duty) and whatever is left of its process
group is killed: no node writes on after `touch4d study run` is gone. Killed outright (SIGKILL), the
run stops nothing itself: the kernel then SIGTERMs the launcher (touch4d.bus.startup.die_with_parent),
which stops its nodes as on Ctrl+C. While it runs, the run holds the session folder's lock
(touch4d.study.lock): one writer per folder.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

import msgspec

from .lock import claim_session
from .store import next_segment, session_dir

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
STOP_GRACE_S = 20.0      # the launcher's own grace for its nodes is shorter: then its process group is killed


class Stopped(Exception):
    """The run was told to stop by a signal (a closed terminal, a dropped ssh, Ctrl+C, kill): its stack is
    stopped and the session resumes where it was when run again. `code`: the shell's 128 + signal."""

    def __init__(self, signum: int):
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum
        self.code = 128 + signum


@contextmanager
def stop_on_signals():
    """SIGINT, SIGTERM and SIGHUP raise Stopped in the main thread wherever the run is, once (a second
    signal while the stack stops is ignored). In another thread (tests, tools) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    raised = []

    def handler(signum, frame):
        if not raised:
            raised.append(signum)
            raise Stopped(signum)

    old = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


def stop_stack(proc: subprocess.Popen, grace_s: float = STOP_GRACE_S) -> None:
    """Stop a launched stack: SIGINT to the launcher (it stops its nodes, the motor node zeroes the
    motors), then SIGKILL to its process group for anything left (a node the launcher could not stop,
    or the nodes of a launcher that was itself killed)."""
    if proc.poll() is None:
        try:
            os.kill(proc.pid, signal.SIGINT)
            proc.wait(grace_s)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)    # the launcher leads its own session: its pid is the group's id
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def worst_exit(codes) -> int:
    """The exit status of a run made of parts: 0 only when every part is 0, else the worst (highest;
    a part killed by a signal, negative from subprocess, counts as 128 + signal)."""
    codes = [128 - c if c < 0 else c for c in codes]
    return max(codes, default=0)

# ---- running a session through the full stack ------------------------------------------------------------

STUDY_LAUNCH = "launch/study.yaml"


class SessionOptions(msgspec.Struct, frozen=True, kw_only=True):
    """How `run_session` runs a session (its callbacks aside): one value that run_simulation varies per participant."""
    launch: str = STUDY_LAUNCH         # the launch file that runs the stack
    session: str = "1"                 # the session's name within the participant's folder
    quick: bool = False                # one trial per cell: checks the stack in minutes
    simulate: bool = False             # a simulated observer instead of a person, on a private bus
    seed: int | None = None            # the simulated observer's seed (None: its own)
    order: int | None = None           # the condition order's row (None: the participant's own)
    simulation: dict | None = None     # the settings a simulation records in the manifest
    timeout_s: float | None = None     # stop the stack if the session is not done within this (None: never)
    locked: bool = False               # the caller holds the session folder's lock (else it is claimed here)
    bus: str | None = None             # a bus config file for the launch (not with `simulate`: its bus is private)


def session_overrides(study_path, participant: str, out, options: SessionOptions = SessionOptions(),
                      user: list[str] = ()) -> list[str]:
    """The launch overrides that make launch/study.yaml run `participant`'s session into OUT as
    `options` say (its session, quick, a simulation's observer, seed, order and settings). A
    simulation drops the renderer and the monitor unless the `user` overrides (which follow) name them."""
    o = options
    session, quick, simulate, seed, order, simulation = o.session, o.quick, o.simulate, o.seed, o.order, o.simulation
    directory = session_dir(out, participant)
    text = lambda value: json.dumps(str(value))   # noqa: E731 - a YAML string whatever it looks like
    flag = "true" if quick else "false"
    args = [f"study.study:={text(study_path)}", f"study.participant:={text(participant)}",
            f"study.out:={text(out)}", f"study.session:={text(session)}", f"study.quick:={flag}",
            f"recorder.file:={text(next_segment(directory))}"]
    if order is not None:
        args.append(f"study.order:={int(order)}")
    if simulation is not None:
        args.append(f"study.simulation:={text(json.dumps(simulation, sort_keys=True))}")
    if simulate:
        args += ["tracker:=study_observer", f"tracker.study:={text(study_path)}",
                 f"tracker.participant:={text(participant)}", f"tracker.quick:={flag}", "study.iti_s:=0.05"]
        named = {arg.partition(":=")[0].lstrip("+").partition(".")[0] for arg in user}
        args += [f"{role}:=none" for role in ("renderer", "monitor") if role not in named]
        if seed is not None:
            args.append(f"tracker.seed:={seed}")
        if order is not None:
            args.append(f"tracker.order:={int(order)}")     # the observer plans the same session
        if quick:   # a lighter-trained observer: the run checks the stack, not the observer's accuracy
            args += ["tracker.train_scenes:=4", "tracker.train_positions:=8", "tracker.view_scenes:=8"]
    return args


def run_session(study_path, participant: str, out, overrides: list[str] = (), *,
                options: SessionOptions = SessionOptions(), echo=print, on_ready=None) -> int:
    """Run one participant's session through the full stack (`touch4d launch launch/study.yaml ...`)
    until the study node says it is done; returns the exit status (0: complete; the worst of the
    launch's and the session's). A signal stops it (Stopped, raised after the stack is down; the
    session resumes where it was when run again). `overrides` come last, so they win.
    `options`: the run's settings (SessionOptions). `on_ready(bus)` is called with the stack's
    BusConfig once it runs (tests, tools); `echo` gets the lines for the experimenter."""
    import sys
    import tempfile

    from touch4d.bus.config import ENV_VAR, BusConfig
    from touch4d.bus.node import Node
    from touch4d.bus.startup import PARENT_PID_ENV
    from touch4d.messages import StudyTrial

    o = options
    simulate, timeout_s = o.simulate, o.timeout_s
    directory = session_dir(out, participant)
    args = [o.launch, *session_overrides(study_path, participant, out, o, user=overrides), *overrides]
    with nullcontext() if o.locked else claim_session(directory), tempfile.TemporaryDirectory(prefix="touch4d-study-") as tmp, stop_on_signals():
        ready = Path(tmp) / "bus.json"
        bus_args = []
        if simulate:   # a private bus on free ports: simulations never meet a running stack
            bus_file = Path(tmp) / "bus.yaml"
            bus_file.write_text("broker: {bind: 127.0.0.1, pub_port: 0, sub_port: 0}\nconnect: 127.0.0.1\n")
            bus_args = ["--bus", str(bus_file)]
        else:          # the usual bus (or --bus FILE), so `touch4d topic pub study/command ...` reaches it
            bus_args = ["--bus", str(o.bus)] if o.bus is not None else []
            echo(f"{participant}: pause with the Pause key (F9) or "
                 "touch4d topic pub study/command '{command: pause}'")
        env = {k: v for k, v in os.environ.items() if k != ENV_VAR} if simulate else dict(os.environ)
        env[PARENT_PID_ENV] = str(os.getpid())   # killed outright (SIGKILL), this process still ends its stack
        cmd = [sys.executable, "-m", "touch4d.cli", "launch", *args, *bus_args, "--ready-file", str(ready)]
        watcher = None
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        state = {"done": False, "index": -1}

        def on_trial(msg: StudyTrial) -> None:
            if msg.participant != participant:
                return
            if msg.phase == "done":
                state["done"] = True
            elif msg.phase == "stimulus" and msg.index != state["index"]:
                state["index"] = msg.index
                echo(f"{participant}: trial {msg.index + 1}/{msg.total} {msg.condition} {msg.task} {msg.stimulus}")

        proc = None
        try:
            # its own session: the terminal's Ctrl+C reaches this process alone, which stops the stack in order
            proc = subprocess.Popen(cmd, env=env, start_new_session=True)
            while proc.poll() is None and not (ready.exists() and ready.stat().st_size):
                time.sleep(0.05)
            if proc.poll() is None:
                bus = BusConfig.from_json(ready.read_text())
                if on_ready is not None:
                    on_ready(bus)
                watcher = Node("study-run", bus=bus, heartbeat=False)
                watcher.create_subscription("study/trial", StudyTrial, on_trial, latest_only=True)
                while proc.poll() is None and not state["done"]:
                    watcher.spin_once(0.1)
                    if deadline is not None and time.monotonic() > deadline:
                        echo(f"{participant}: not done within {timeout_s:g} s; stopping (run again to resume)")
                        break
        except (Stopped, KeyboardInterrupt) as exc:
            echo(f"{participant}: {exc if isinstance(exc, Stopped) else 'stopped by SIGINT'}; stopping the stack; "
                 "`touch4d study run` with the same --out resumes the session")
            raise
        finally:
            try:
                if watcher is not None:
                    watcher.shutdown()
            finally:
                if proc is not None:
                    stop_stack(proc)
        code = proc.returncode
        launch_code = 0 if code in (0, -signal.SIGINT) else code
        return worst_exit([launch_code, 0 if state["done"] else 1])


def run_simulation(study_path, participants: int, out, overrides: list[str] = (), *,
                   options: SessionOptions = SessionOptions(), echo=print, on_ready=None) -> int:
    """N simulated participants (P01 ...), one full-stack session each, in turn (`options.seed`, if any, + k
    for the k-th); the worst exit status. A signal stops the run (Stopped): no later participant starts."""
    from .plan import participant_ids

    codes = []
    for k, participant in enumerate(participant_ids(participants)):
        seed = None if options.seed is None else options.seed + k
        codes.append(run_session(study_path, participant, out, overrides, echo=echo, on_ready=on_ready,
                                 options=msgspec.structs.replace(options, simulate=True, seed=seed)))
    return worst_exit(codes)

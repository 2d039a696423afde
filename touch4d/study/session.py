"""Running a participant's session through the full stack: `run_session` starts launch/study.yaml
with the session's overrides and waits for the study node to say it is done; `run_simulation` runs
N simulated participants in turn. The session folder's files: touch4d.study.store."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

from .store import next_segment, session_dir

# ---- running a session through the full stack ------------------------------------------------------------

STUDY_LAUNCH = "launch/study.yaml"


def session_overrides(study_path, participant: str, out, *, session: str = "1", quick: bool = False,
                      simulate: bool = False, seed: int | None = None, user: list[str] = ()) -> list[str]:
    """The launch overrides that make launch/study.yaml run `participant`'s session into OUT. A
    simulation drops the renderer and the monitor unless the `user` overrides (which follow) name them."""
    directory = session_dir(out, participant)
    text = lambda value: json.dumps(str(value))   # noqa: E731 - a YAML string whatever it looks like
    flag = "true" if quick else "false"
    args = [f"study.study:={text(study_path)}", f"study.participant:={text(participant)}",
            f"study.out:={text(out)}", f"study.session:={text(session)}", f"study.quick:={flag}",
            f"recorder.file:={text(next_segment(directory))}"]
    if simulate:
        args += ["tracker:=study_observer", f"tracker.study:={text(study_path)}",
                 f"tracker.participant:={text(participant)}", f"tracker.quick:={flag}", "study.iti_s:=0.05"]
        named = {arg.partition(":=")[0].lstrip("+").partition(".")[0] for arg in user}
        args += [f"{role}:=none" for role in ("renderer", "monitor") if role not in named]
        if seed is not None:
            args.append(f"tracker.seed:={seed}")
        if quick:   # a lighter observer: the run checks the stack, not the observer's accuracy
            args += ["tracker.train_scenes:=4", "tracker.train_positions:=8", "tracker.view_scenes:=8",
                     "tracker.dwell_s:=0.0"]
    return args


def run_session(study_path, participant: str, out, overrides: list[str] = (), *, launch: str = STUDY_LAUNCH,
                session: str = "1", quick: bool = False, simulate: bool = False, seed: int | None = None,
                timeout_s: float | None = None, echo=print, on_ready=None) -> int:
    """Run one participant's session through the full stack (`touch4d launch launch/study.yaml ...`)
    until the study node says it is done; returns the launch's exit code (0: complete). Ctrl+C stops it
    (the session resumes where it was when run again). `overrides` come last, so they win.
    `on_ready(bus)` is called with the stack's BusConfig once it runs (tests, tools)."""
    import signal
    import subprocess
    import sys
    import tempfile

    from touch4d.bus.config import ENV_VAR, BusConfig
    from touch4d.bus.node import Node
    from touch4d.messages import StudyTrial

    directory = session_dir(out, participant)
    directory.mkdir(parents=True, exist_ok=True)
    args = [launch, *session_overrides(study_path, participant, out, session=session, quick=quick,
                                       simulate=simulate, seed=seed, user=overrides), *overrides]
    with tempfile.TemporaryDirectory(prefix="touch4d-study-") as tmp:
        ready = Path(tmp) / "bus.json"
        bus_args = []
        if simulate:   # a private bus on free ports: simulations never meet a running stack
            bus_file = Path(tmp) / "bus.yaml"
            bus_file.write_text("broker: {bind: 127.0.0.1, pub_port: 0, sub_port: 0}\nconnect: 127.0.0.1\n")
            bus_args = ["--bus", str(bus_file)]
        else:          # the usual bus, so `touch4d topic pub study/command '{command: pause}'` reaches it
            echo(f"{participant}: pause with the Pause key (F9) or "
                 "touch4d topic pub study/command '{command: pause}'")
        env = {k: v for k, v in os.environ.items() if k != ENV_VAR} if simulate else dict(os.environ)
        cmd = [sys.executable, "-m", "touch4d.cli", "launch", *args, *bus_args, "--ready-file", str(ready)]
        proc = subprocess.Popen(cmd, env=env, start_new_session=True)
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

        try:
            while proc.poll() is None and not (ready.exists() and ready.stat().st_size):
                time.sleep(0.05)
            if proc.poll() is not None:
                return proc.returncode
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
        except KeyboardInterrupt:
            echo(f"{participant}: stopped; `touch4d study run` with the same --out resumes the session")
        finally:
            if watcher is not None:
                watcher.shutdown()
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGINT)
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
        code = proc.returncode
        return 0 if state["done"] and code in (0, -signal.SIGINT) else (code or 1)


def run_simulation(study_path, participants: int, out, overrides: list[str] = (), *, seed: int | None = None,
                   quick: bool = False, echo=print, **kwargs) -> int:
    """N simulated participants (P01 ...), one full-stack session each, in turn; the worst exit code."""
    from .plan import participant_ids

    worst = 0
    for k, participant in enumerate(participant_ids(participants)):
        code = run_session(study_path, participant, out, overrides, simulate=True, quick=quick,
                           seed=None if seed is None else seed + k, echo=echo, **kwargs)
        worst = worst or code
    return worst

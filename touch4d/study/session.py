"""A participant's session on disk, and running one through the full stack.

Session directory (`OUT/<participant>/`):
- `trials.csv`: one row per answered (or timed-out) trial, columns `COLUMNS`, each row written,
  flushed and fsync'd before the next trial starts, so a crash loses nothing; a restarted study node
  reads it back and resumes at the first trial without a row (`TrialsFile.done`).
- `manifest.json`: software version, study file and its sha256, participant, seeds, condition
  order, glove/calibration/DBC sha256, and one entry per start of the study node (its time and the
  trial it resumed at); replaced atomically.
- `session-NNN.mcap`: the recorder's log of every topic, one per run segment (`touch4d study run`
  started again on the same directory opens the next one).

`TrialMeasures` turns the bus samples of one trial (tactile/motors, hand/pose) into the table's
exploration columns. `run_session` / `run_simulation` start launch/study.yaml and wait for the end.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from touch4d.errors import ConfigError, Touch4dError

from .plan import participant_hash
from . import table
from .table import COLUMNS, _cell

MANIFEST = "manifest.json"
SEGMENT = "session-{:03d}.mcap"


class SessionError(Touch4dError):
    """A session directory that cannot be used (names the file and why)."""


def session_dir(out, participant: str) -> Path:
    """Where a participant's session lives under an output directory."""
    return Path(out) / participant


def sha256_file(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


# ---- trials.csv -------------------------------------------------------------------------------------


class TrialsFile:
    """trials.csv, appended row by row (each row fsync'd). Opening an existing file reads its rows
    back (`rows` by index); a last line cut short by a crash is dropped (that trial is run again)."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rows: dict[int, dict] = {}
        if self.path.exists() and self.path.stat().st_size > 0:
            self._read()
        else:
            self._create()
        self._file = open(self.path, "a", newline="")

    def _create(self) -> None:
        with open(self.path, "w", newline="") as f:
            f.write(_csv_line(COLUMNS))
            f.flush()
            os.fsync(f.fileno())
        _fsync_dir(self.path.parent)

    def _read(self) -> None:
        data = self.path.read_bytes()
        if not data.endswith(b"\n"):   # a row cut short by a crash: not written, so not done
            cut = data.rfind(b"\n") + 1
            with open(self.path, "r+b") as f:
                f.truncate(cut)
                f.flush()
                os.fsync(f.fileno())
            data = data[:cut]
            if not data:            # the header itself was cut short: start the file again
                self._create()
                return
        reader = csv.DictReader(io.StringIO(data.decode()))
        if tuple(reader.fieldnames or ()) != COLUMNS:
            raise ConfigError(self.path, "(header)", "the trials.csv columns " + ",".join(COLUMNS),
                              got=",".join(reader.fieldnames or ()))
        for line, row in enumerate(reader, start=2):
            try:
                index = int(row["index"])
            except (TypeError, ValueError):
                raise ConfigError(self.path, f"line {line}", "an integer index", got=row["index"]) from None
            if index in self.rows:
                raise ConfigError(self.path, f"line {line}", "each trial index once", got=index)
            self.rows[index] = row

    @property
    def done(self) -> set[int]:
        return set(self.rows)

    def write(self, row: dict) -> None:
        """Append one trial's row and fsync it; a trial already written is an error (never repeated)."""
        index = int(row["index"])
        if index in self.rows:
            raise SessionError(f"{self.path}: trial {index} already has a row")
        missing = [c for c in COLUMNS if c not in row]
        if missing:
            raise SessionError(f"{self.path}: row of trial {index} lacks {', '.join(missing)}")
        self._file.write(_csv_line([_cell(row[c]) for c in COLUMNS]))
        self._file.flush()
        os.fsync(self._file.fileno())
        self.rows[index] = {c: _cell(row[c]) for c in COLUMNS}

    def close(self) -> None:
        self._file.close()


def _csv_line(values) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()



def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def trial_row(trial, *, participant: str, session: str, response: str | None, onset: float,
              response_stamp: float | None, measures: "Measures", response_received: float | None = None) -> dict:
    """The table row of a trial run on the bus (table.trial_row with the measures taken on the bus)."""
    return table.trial_row(trial, participant=participant, session=session, response=response, onset=onset,
                           response_stamp=response_stamp, time_touching_s=measures.time_touching_s,
                           mean_intensity=measures.mean_intensity, path_length=measures.path_length,
                           response_received=response_received)


# ---- exploration measures -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Measures:
    time_touching_s: float
    mean_intensity: float
    path_length: float


@dataclass
class TrialMeasures:
    """Bus samples of one trial -> time touching, mean intensity and hand path over [onset, end].

    Both signals are sample-and-hold: a motor command holds until the next one, so the sample before
    the onset counts from the onset on. `threshold`: a motor intensity above it is felt (the glove's
    duty deadband). Path: the sum of the hand's steps between valid poses inside the window."""

    threshold: float
    _motors: list = field(default_factory=list)    # (stamp, any motor > threshold, 30-motor mean)
    _poses: list = field(default_factory=list)     # (stamp, position or None when invalid)

    def reset(self) -> None:
        """Keep only the latest sample of each signal (it holds into the next trial's window)."""
        self._motors = self._motors[-1:]
        self._poses = self._poses[-1:]

    def add_motors(self, stamp: float, intensity: np.ndarray) -> None:
        intensity = np.nan_to_num(np.asarray(intensity, dtype=float))
        mean = float(intensity.mean()) if intensity.size else 0.0
        self._motors.append((stamp, bool((intensity > self.threshold).any()), mean))

    def add_pose(self, stamp: float, position, valid: bool) -> None:
        self._poses.append((stamp, np.asarray(position, dtype=float).copy() if valid else None))

    def measure(self, onset: float, end: float) -> Measures:
        touching = integral = 0.0
        samples = sorted(self._motors, key=lambda s: s[0])
        for k, (t, on, mean) in enumerate(samples):
            t_next = samples[k + 1][0] if k + 1 < len(samples) else end
            a, b = max(t, onset), min(t_next, end)
            if b > a:
                touching += (b - a) * on
                integral += (b - a) * mean
        span = end - onset
        path = 0.0
        previous = None
        for t, position in sorted(self._poses, key=lambda s: s[0]):
            if t > end:
                break
            if t < onset:
                previous = position      # where the hand was at the onset
                continue
            if position is not None and previous is not None:
                path += float(np.linalg.norm(position - previous))
            previous = position
        return Measures(touching, integral / span if span > 0 else 0.0, path)


# ---- manifest ---------------------------------------------------------------------------------------


def software_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("touch4d")
    except PackageNotFoundError:
        return "unknown"


def read_manifest(directory) -> dict:
    path = Path(directory) / MANIFEST
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(path, "(file)", "a readable manifest (JSON)", got=str(exc)) from None


def write_manifest(directory, manifest: dict) -> None:
    """Replace manifest.json atomically (written beside it, fsync'd, renamed)."""
    path = Path(directory) / MANIFEST
    tmp = path.with_suffix(".json.tmp")
    with open(tmp, "w") as f:
        json.dump(manifest, f, indent=2, sort_keys=False)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def start_manifest(directory, *, study, study_path, participant: str, session: str, condition_order: list[str],
                   trials: int, glove_path, calibration_path, dbc_text: str, resumed_at: int,
                   quick: bool = False) -> dict:
    """The manifest with this start of the study node added (`starts`); the first start also records
    what the session is (study, hashes, order, seeds), a later one checks it is the same study."""
    manifest = read_manifest(directory)
    study_hash = sha256_file(study_path)
    where = Path(directory) / MANIFEST
    if manifest and manifest.get("study_sha256") != study_hash:
        raise SessionError(f"{where}: this session ran study file sha256 "
                           f"{manifest.get('study_sha256')}, {study_path} is now {study_hash}: use a new --out")
    for key, value in (("participant", participant), ("quick", quick)):
        if manifest and manifest.get(key) != value:
            raise SessionError(f"{where}: this session ran with {key} {manifest.get(key)!r}, not {value!r}: "
                               "resume it as it was, or use a new --out")
    if not manifest:
        manifest = {
            "software": "touch4d", "version": software_version(), "study": study.name,
            "study_file": str(study_path), "study_sha256": study_hash, "participant": participant,
            "session": session, "study_seed": int(study.seed),
            "seed": [int(study.seed), participant_hash(participant)],   # the plan's SeedSequence entropy
            "condition_order": list(condition_order),
            "trials": trials, "quick": quick,
            "glove_file": str(glove_path), "glove_sha256": sha256_file(glove_path),
            "calibration_file": str(calibration_path), "calibration_sha256": sha256_file(calibration_path),
            "dbc_sha256": sha256_text(dbc_text), "starts": [],
        }
    manifest["starts"].append({"time": time.time(), "iso": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                               "resumed_at": resumed_at, "pid": os.getpid()})
    write_manifest(directory, manifest)
    return manifest


def next_segment(directory) -> Path:
    """The next run segment's log: session-001.mcap, then session-002.mcap, ..."""
    directory = Path(directory)
    n = 1
    while (directory / SEGMENT.format(n)).exists():
        n += 1
    return directory / SEGMENT.format(n)


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

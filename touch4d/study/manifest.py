"""A session's manifest.json: software version, study file and its sha256, participant, seeds,
condition order, glove/calibration/DBC sha256, and one entry per start of the study node (its time,
the trial it resumed at, its process); replaced atomically."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from pathlib import Path

from touch4d.atomic import write_atomic
from touch4d.errors import ConfigError

from .plan import participant_hash
from .lock import LOCK, WRITER
from .store import SessionError

MANIFEST = "manifest.json"
REPORT = "report.html"           # touch4d study analyze's default report, in the output folder


def sha256_file(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()



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
    """Replace manifest.json atomically (touch4d.atomic: written beside it, fsync'd, renamed)."""
    write_atomic(Path(directory) / MANIFEST, json.dumps(manifest, indent=2, sort_keys=False) + "\n")


def update_manifest(directory, fields: dict) -> None:
    """Keys added to (or replaced in) a session's manifest: what a served participant's device and
    recruitment platform said (`device`, `platform`), for `study analyze --by device.browser`."""
    manifest = read_manifest(directory)
    manifest.update(fields)
    write_manifest(directory, manifest)


def start_manifest(directory, *, study, study_path, participant: str, session: str, condition_order: list[str],
                   trials: int, glove_path, calibration_path, dbc_text: str, resumed_at: int,
                   quick: bool = False, simulation: dict | None = None) -> dict:
    """The manifest with this start of the study node added (`starts`); the first start also records
    what the session is (study, hashes, order, seeds, the simulation's settings or None for a
    participant), a later one checks it is the same session."""
    manifest = read_manifest(directory)
    study_hash = sha256_file(study_path)
    where = Path(directory) / MANIFEST
    if manifest and manifest.get("study_sha256") != study_hash:
        raise SessionError(f"{where}: this session ran study file sha256 "
                           f"{manifest.get('study_sha256')}, {study_path} is now {study_hash}: use a new --out")
    for key, value in (("participant", participant), ("quick", quick), ("condition_order", list(condition_order)),
                       ("simulation", simulation)):
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
            "trials": trials, "quick": quick, "simulation": simulation,
            "glove_file": str(glove_path), "glove_sha256": sha256_file(glove_path),
            "calibration_file": str(calibration_path), "calibration_sha256": sha256_file(calibration_path),
            "dbc_sha256": sha256_text(dbc_text), "starts": [],
        }
    manifest["starts"].append({"time": time.time(), "iso": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                               "resumed_at": resumed_at, "pid": os.getpid()})
    write_manifest(directory, manifest)
    return manifest


# ---- what a run may write into an output folder ---------------------------------------------------------


def run_settings(manifest: dict) -> dict:
    """What must agree for sessions to be analysed as one study: the study (name and sha256), `quick`,
    and the simulation's settings (None: a participant's session)."""
    return {"study": manifest.get("study"), "study_sha256": manifest.get("study_sha256"),
            "quick": bool(manifest.get("quick", False)), "simulation": manifest.get("simulation")}


def prepare_out(out, participants: list[str], settings: dict, *, overwrite: bool = False, echo=print) -> None:
    """Check an output folder before a run writes `participants`' sessions with `settings`
    (`run_settings`' keys). A session folder there that ran otherwise is refused (SessionError naming
    it and what differs), unless it is one this run writes and `overwrite` is given: it is then
    emptied. An old report.html is removed (it describes other data)."""
    out = Path(out)
    conflicts, replace = [], []
    for path in sorted(out.glob(f"*/{MANIFEST}")):
        differ = _differences(run_settings(read_manifest(path.parent)), settings)
        if not differ:
            continue
        what = ", ".join(f"{k} {_short(a)} (this run: {_short(b)})" for k, a, b in differ)
        (replace if overwrite and path.parent.name in participants else conflicts).append((path.parent, what))
    if conflicts:
        ours = all(folder.name in participants for folder, _ in conflicts)
        raise SessionError(f"{out} holds sessions run otherwise than this run: "
                           + "; ".join(f"{folder} ({what})" for folder, what in conflicts)
                           + ("; use a new --out, or --overwrite to replace them" if ours else
                              "; use a new --out (analysed together they would mix two studies)"))
    for folder, what in replace:
        for item in folder.iterdir():
            if item.name not in (LOCK, WRITER):
                shutil.rmtree(item) if item.is_dir() else item.unlink()
        echo(f"{folder}: replaced (--overwrite; it ran with {what})")
    report = out / REPORT
    if report.exists():
        report.unlink()
        echo(f"{report}: removed (it described the sessions before this run; touch4d study analyze {out} "
             "writes a new one)")


def check_one_study(tables) -> None:
    """Sessions analysed together must have run alike: a SessionError naming each trials.csv whose
    manifest's `run_settings` differ from the first's (a table without a manifest is not checked)."""
    first, odd = None, []
    for table in tables:
        folder = Path(table).parent
        if not (folder / MANIFEST).exists():
            continue
        settings = run_settings(read_manifest(folder))
        if first is None:
            first = (folder, settings)
            continue
        differ = _differences(first[1], settings)
        if differ:
            odd.append(f"{folder} (" + ", ".join(f"{k} {_short(b)} where {first[0].name} has {_short(a)}"
                                                 for k, a, b in differ) + ")")
    if odd:
        raise SessionError(f"these sessions ran otherwise than {first[0]}: " + "; ".join(odd)
                           + "; analysed together they would mix two studies: analyse them apart")


def _differences(theirs: dict, ours: dict, prefix: str = "") -> list[tuple[str, object, object]]:
    """(key, theirs, ours) for each setting that differs, a dict's keys one by one (simulation.noise)."""
    out = []
    for key in dict.fromkeys([*ours, *theirs]):
        a, b = theirs.get(key), ours.get(key)
        if isinstance(a, dict) and isinstance(b, dict) and a.get("mode") != b.get("mode"):
            out.append((f"{prefix}{key}.mode", a.get("mode"), b.get("mode")))   # another kind: its mode says it
        elif isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            out.append((prefix + key, a, b))
    return out


def _short(value) -> str:
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= 80 else text[:77] + "..."

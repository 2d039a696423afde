"""A study's output folder as a Psych-DS dataset (`touch4d study export DIR --psych-ds OUT`), so that
others can read its data without touch4d.

The dataset (Psych-DS 1.5.0):

- `dataset_description.json`: schema.org `Dataset` (JSON-LD): name, description, `variableMeasured`
  (every column of every data file, a `PropertyValue` each, with its unit), and in `isBasedOn` the
  study file (its sha256 as `identifier`) and the touch4d version(s) that ran the sessions.
- `data/study-S_subject-P_session-N_data.csv`: one per participant and session, the rows of its
  trials.csv as they were (same columns and cells); keys from Psych-DS's vocabulary (study, subject,
  session), values reduced to the letters and digits the file-name grammar allows.
- `data/primary_data/<session folder>/`: each session's manifest.json (without a recruitment
  platform's ids and the browser's user agent: `shareable`) and MCAP logs, unchanged:
  the first recorded form of the data belongs under data/ (Psych-DS's raw-data principle), and
  primary_data is the spec's folder for primary data of any file type. `.psychds-ignore` keeps
  validators from reporting these files as unchecked.
- `README.md`: what the files are, which columns identify a row, which data file is whose.

The plan (`plan_export`: every file's path and content) is made before anything is written; the
dataset is written into a folder beside OUT and renamed into place, so OUT is whole or absent.
"""
from __future__ import annotations

import csv
import errno
import io
import json
import os
import re
import secrets
import shutil
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from touch4d.atomic import fsync_dir, write_atomic
from touch4d.errors import ConfigError, Touch4dError

from .lock import claim_session
from .manifest import MANIFEST, check_one_study, read_manifest
from .store import LEGACY_COLUMNS, _complete
from .table import COLUMNS, find_tables

SCHEMA_VERSION = "Psych-DS 1.5.0"
DESCRIPTION = "dataset_description.json"
README = "README.md"
IGNORE = ".psychds-ignore"
DATA = "data"
PRIMARY = "data/primary_data"
RECORDS = ("manifest.json", "*.mcap")           # what of a session folder is copied beside its data file
KEYWORD_VALUE = re.compile(r"[A-Za-z0-9]+")
ROW_KEY = ("participant", "session", "block", "trial")

# Each trials.csv column: what it holds, and its unit (None: none). The one description of the columns.
COLUMN_DESCRIPTIONS: dict[str, tuple[str, str | None]] = {
    "participant": ("participant id (as in the session folder's name)", None),
    "session": ("session label within the participant", None),
    "block": ("block number within the session, from 0 (one condition per block)", None),
    "trial": ("trial number within its block, from 0", None),
    "index": ("trial number within the session's plan, from 0", None),
    "practice": ("1: a practice trial (left out of the analysis), 0: a measured trial", None),
    "task": ("task id from the study file", None),
    "kind": ("the task's kind: front-element, look-alikes or tilt", None),
    "condition": ("what the participant had: visual (objects drawn, motors off), touch (motors, nothing drawn), "
                  "visual+touch; suffixed by the view (slice, both) where the study varies it", None),
    "stimulus": ("stimulus name", None),
    "level": ("stimulus level: the tilt in degrees for tilt tasks, empty otherwise", "degree"),
    "transform": ("the random 4D rotation applied to the stimulus, as JSON [[plane, angle in radians], ...]", None),
    "answer": ("the correct answer", None),
    "response": ("the answer given; empty when the trial timed out", None),
    "correct": ("1: the answer given is the correct answer, 0 otherwise (a timed-out trial is 0)", None),
    "rt_s": ("answer time from stimulus onset; empty when the trial timed out", "s"),
    "timed_out": ("1: no answer within the trial's time limit", None),
    "time_touching_s": ("time any motor was driven above the glove's touch threshold", "s"),
    "mean_intensity": ("mean motor intensity over the trial, 0..1 of full drive", None),
    "path_length": ("length of the hand's path in the trial, in scene units", None),
    "onset_stamp": ("stimulus onset on the session's clock", "s"),
    "response_stamp": ("when the answer was given, on the session's clock; empty when timed out", "s"),
    "seed": ("the trial's random seed (its jitter and the simulated observer's draws)", None),
    "response_received": ("when the answer reached touch4d, on its clock (a page's answers); empty if unknown", "s"),
    "clock_suspect": ("1: the answering page's clock claimed more than the answer's arrival allows; rt_s is not "
                      "to be trusted", None),
}


class ExportError(Touch4dError):
    """A study folder that cannot be exported as asked, or an OUT that may not be written (says which)."""


@dataclass
class Session:
    """One session folder as read: its trials.csv's header and rows (cells as written), its manifest,
    the records copied beside it (manifest, logs) and its path relative to the study folder."""

    table: Path
    relative: PurePosixPath
    header: tuple[str, ...]
    rows: list[list[str]]
    manifest: dict
    records: list[Path] = field(default_factory=list)


# ---- pure: names, tables, metadata ----------------------------------------------------------------------


def keyword_value(text: str, what: str, where) -> str:
    """`text` as a Psych-DS keyword value: its letters and digits only (the file-name grammar's
    [a-zA-Z0-9]+); ExportError naming `where` and `what` when none is left."""
    value = "".join(KEYWORD_VALUE.findall(str(text)))
    if not value:
        raise ExportError(f"{where}: {what} {text!r} has no letter or digit to name a Psych-DS data file by "
                          "(keyword values are letters and digits)")
    return value


def data_file_name(study: str, participant: str, session: str) -> str:
    """`study-S_subject-P_session-N_data.csv` (each value already a keyword value)."""
    return f"study-{study}_subject-{participant}_session-{session}_data.csv"


def split_sessions(session: Session) -> dict[tuple[str, str], list[list[str]]]:
    """A table's rows by (participant, session), in file order; a table without rows is its manifest's
    (or its folder's) participant's, session 1 unless the manifest says."""
    p, s = session.header.index("participant"), session.header.index("session")
    out: dict[tuple[str, str], list[list[str]]] = {}
    for row in session.rows:
        out.setdefault((row[p], row[s]), []).append(row)
    if not out:
        who = session.manifest.get("participant") or session.table.parent.name
        out[(str(who), str(session.manifest.get("session") or "1"))] = []
    return out


def csv_text(header, rows) -> str:
    """Header and rows as CSV text, as trials.csv is written (`\\n` line ends, quoted where needed)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buf.getvalue()


def variables(columns) -> list[dict]:
    """`variableMeasured`: a schema.org PropertyValue per column, described and with its unit where it has one."""
    out = []
    for name in columns:
        text, unit = COLUMN_DESCRIPTIONS.get(name, ("a trials.csv column", None))
        out.append({"@type": "PropertyValue", "name": name, "description": text, **({"unitText": unit} if unit else {})})
    return out


def description(study: str, manifests: list[dict], columns, participants: list[str], sessions: int) -> dict:
    """The dataset_description.json of a study's sessions (schema.org Dataset, JSON-LD)."""
    digests = sorted({str(m.get("study_sha256")) for m in manifests if m.get("study_sha256")})
    files = sorted({Path(str(m["study_file"])).name for m in manifests if m.get("study_file")})
    versions = sorted({str(m.get("version")) for m in manifests if m.get("version")})
    modes = sorted({_mode(m) for m in manifests})
    based_on = [{"@type": "CreativeWork", "name": f"touch4d study file {', '.join(files) or study}",
                 "identifier": {"@type": "PropertyValue", "propertyID": "sha256", "value": d}} for d in digests]
    based_on += [{"@type": "SoftwareApplication", "name": "touch4d", "softwareVersion": v} for v in versions]
    return {
        "@context": "https://schema.org",
        "@type": "Dataset",
        "name": f"touch4d study {study}",
        "description": (f"Trials of the touch4d study '{study}' ({', '.join(modes)}): {len(participants)} participants "
                        f"({', '.join(participants)}), {sessions} session(s), one row per trial, in data/ (one file per "
                        "participant and session). Each trial asked what a 4D object is, seen on a 3D screen, felt "
                        "with a vibrotactile glove, or both; a row is identified by participant, session, block and "
                        "trial. Each session's manifest.json (software version, study, glove and calibration by "
                        "sha256, seeds, condition order) and MCAP logs of every topic are in data/primary_data/."),
        "schemaVersion": SCHEMA_VERSION,
        "dateCreated": time.strftime("%Y-%m-%d"),
        "keywords": ["touch4d", "haptics", "vibrotactile", "4D objects", "psychophysics", f"study {study}"],
        "measurementTechnique": ", ".join(modes),
        "isBasedOn": based_on,
        "variableMeasured": variables(columns),
    }


def _mode(manifest: dict) -> str:
    """How a session ran, in words: a participant's, or simulated (offline or through the stack)."""
    simulation = manifest.get("simulation")
    if not simulation:
        return "participants through the touch4d stack"
    mode = simulation.get("mode") if isinstance(simulation, dict) else None
    return f"simulated participants (model observers, {mode or 'simulation'})"


def readme(study: str, files: list[tuple[str, str, str, str]]) -> str:
    """README.md: the layout, the row key, and each data file's participant, session and records."""
    lines = [f"# touch4d study {study}", "",
             "Exported by `touch4d study export --psych-ds` as a Psych-DS dataset (`dataset_description.json` "
             "describes every column).", "",
             "- `data/*_data.csv`: one file per participant and session, the rows of its `trials.csv` unchanged.",
             f"- `{PRIMARY}/<session folder>/`: the session's `manifest.json` and MCAP logs (`*.mcap`, every topic "
             "recorded), unchanged; listed in `.psychds-ignore` since Psych-DS does not check such files.", "",
             f"Each row is identified by {', '.join(ROW_KEY)}. Keyword values in file names keep only the letters and "
             "digits of an id; the `participant` column holds it whole.", "",
             "| data file | participant | session | records |", "|---|---|---|---|"]
    lines += [f"| `data/{name}` | {p} | {s} | `{records}` |" for name, p, s, records in files]
    return "\n".join(lines) + "\n"


# ---- reading a study folder -----------------------------------------------------------------------------


def read_session(table: Path, root: Path) -> Session:
    """A session folder's trials.csv (whole lines only: a row a crash cut short was never written),
    manifest and records; ConfigError naming the file and what was expected."""
    try:
        text = _complete(table.read_bytes()).decode("utf-8")
    except OSError as exc:
        raise ConfigError(table, "(file)", "a readable trials.csv", got=exc.strerror or str(exc)) from None
    except UnicodeDecodeError:
        raise ConfigError(table, "(file)", "a UTF-8 trials.csv") from None
    try:
        lines = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise ConfigError(table, "(file)", "a CSV table", got=str(exc)) from None
    header = tuple(lines[0]) if lines else ()
    if header not in (COLUMNS, LEGACY_COLUMNS):
        raise ConfigError(table, "(header)", "the trials.csv columns " + ",".join(COLUMNS), got=",".join(header))
    for number, row in enumerate(lines[1:], start=2):
        if len(row) != len(header):
            raise ConfigError(table, f"line {number}", f"{len(header)} fields, one per column", got=len(row))
    folder = table.parent
    if not (folder / MANIFEST).is_file():
        raise ConfigError(folder / MANIFEST, "(file)", "the session's manifest (the study's name, sha256 and the "
                          "software version come from it)", got="no such file")
    manifest = read_manifest(folder)
    if not isinstance(manifest, dict) or not manifest.get("study"):
        raise ConfigError(folder / MANIFEST, "study", "the name of the study the session ran")
    relative = PurePosixPath(folder.relative_to(root).as_posix()) if folder != root else PurePosixPath(folder.name)
    records = sorted({p for pattern in RECORDS for p in folder.glob(pattern) if p.is_file() and not p.is_symlink()})
    return Session(table, relative, header, lines[1:], manifest, records)


def read_study(where) -> list[Session]:
    """Every session at or below `where` (a study's output folder, a session folder or a trials.csv),
    sessions of one study run alike (manifest.check_one_study)."""
    where = Path(where)
    tables = find_tables(where)
    root = where if where.is_dir() else where.parent
    sessions = [read_session(t, root) for t in tables]
    check_one_study(tables)
    return sessions


# What of a manifest could name a participant to someone who shares the dataset: the recruitment
# platform's ids (PROLIFIC_PID and others: touch4d.study.recruitment) and the browser's user agent.
PERSONAL = (("platform",), ("device", "user_agent"))


def shareable(manifest: dict) -> dict:
    """A manifest without what could identify its participant (PERSONAL), the rest as recorded."""
    out = json.loads(json.dumps(manifest))
    for path in PERSONAL:
        holder = out
        for key in path[:-1]:
            holder = holder.get(key) if isinstance(holder, dict) else None
        if isinstance(holder, dict):
            holder.pop(path[-1], None)
    return out


# ---- the plan of the dataset ----------------------------------------------------------------------------


def plan_export(sessions: list[Session]) -> dict[str, str | Path]:
    """Every file of the dataset: its path under OUT -> its text, or the Path of a file copied unchanged."""
    study = str(sessions[0].manifest["study"])
    study_value = keyword_value(study, "the study's name", sessions[0].table.parent / MANIFEST)
    files: dict[str, str | Path] = {}
    named: dict[str, tuple[str, str, Path]] = {}
    index, columns = [], list(dict.fromkeys(c for s in sessions for c in s.header))
    for session in sessions:
        for (participant, label), rows in split_sessions(session).items():
            name = data_file_name(study_value, keyword_value(participant, "participant", session.table),
                                  keyword_value(label, "session", session.table))
            if name in named:
                other = named[name]
                raise ExportError(f"{session.table} and {other[2]}: participant {participant!r} session {label!r} and "
                                  f"participant {other[0]!r} session {other[1]!r} would both be data/{name} (ids must "
                                  "differ in their letters and digits, and a session be in one trials.csv)")
            named[name] = (participant, label, session.table)
            files[f"{DATA}/{name}"] = csv_text(session.header, rows)
            index.append((name, participant, label, f"{PRIMARY}/{session.relative}/"))
        for record in session.records:
            files[f"{PRIMARY}/{session.relative}/{record.name}"] = (
                json.dumps(shareable(session.manifest), indent=2) + "\n" if record.name == MANIFEST else record)
    participants = sorted({p for p, _, _ in named.values()})
    files[DESCRIPTION] = json.dumps(description(study, [s.manifest for s in sessions], columns, participants,
                                                len(named)), indent=2) + "\n"
    files[README] = readme(study, sorted(index))
    files[IGNORE] = f"# not checked by Psych-DS: each session's manifest and MCAP logs, kept as recorded\n{PRIMARY}/\n"
    return files


# ---- writing it -----------------------------------------------------------------------------------------


def check_out(out: Path, sources: list[Path], *, force: bool) -> None:
    """OUT may be written: new, or an empty folder, or (with `force`) an earlier export; never a folder
    holding the study's own sessions. ExportError naming OUT and what was expected."""
    resolved = out.resolve()
    for source in sources:
        if resolved == source.resolve() or resolved in source.resolve().parents:
            raise ExportError(f"{out}: expected a folder outside the study's sessions (it holds {source})")
    if not out.exists():
        return
    if not out.is_dir() or out.is_symlink():
        raise ExportError(f"{out}: expected a new or empty folder for the dataset, found a file")
    entries = list(out.iterdir())
    if not entries:
        return
    if not force:
        raise ExportError(f"{out}: expected a new or empty folder for the dataset, it holds {len(entries)} "
                          "entries (--force replaces an earlier export)")
    if not (out / DESCRIPTION).is_file():
        raise ExportError(f"{out}: --force replaces only an earlier export (a folder with {DESCRIPTION}); "
                          "this one has none: choose another --psych-ds folder")


def write_dataset(files: dict[str, str | Path], out, *, force: bool = False, sources: list[Path] = ()) -> None:
    """Write `files` (plan_export's) as the folder `out`: staged beside it, each text file written
    atomically and each record copied and flushed, then renamed into place (an earlier export
    replaced only with `force`)."""
    out = Path(out)
    check_out(out, list(sources), force=force)
    out.parent.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(6)
    stage = out.parent / f".{out.name}.{token}.partial"
    old = out.parent / f".{out.name}.{token}.old"
    try:
        for relative, content in sorted(files.items()):
            path = stage / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(content, Path):
                _copy(content, path)
            else:
                write_atomic(path, content)
        if out.exists():
            if any(out.iterdir()):
                out.rename(old)
            else:
                out.rmdir()
        stage.rename(out)
        fsync_dir(out.parent)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        if old.exists() and not out.exists():
            old.rename(out)               # put the earlier export back
        raise
    shutil.rmtree(old, ignore_errors=True)


def _copy(source: Path, target: Path) -> None:
    """A record copied whole and flushed to disk (its bytes unchanged)."""
    try:
        with open(source, "rb") as src, open(target, "xb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
            dst.flush()
            os.fsync(dst.fileno())
    except OSError as exc:
        raise ExportError(f"{source}: cannot copy it into the dataset ({exc.strerror or exc})") from None


def hold_sessions(where, stack: ExitStack) -> None:
    """Claim every session folder at or below `where` for the export (a run's lock, touch4d.study.lock;
    no study node writing: a SessionError naming a folder still being written), so no row or log is
    added while it is read and copied. A folder this process may not write (a read-only archive) is
    read unclaimed."""
    for table in find_tables(where):
        try:
            stack.enter_context(claim_session(table.parent))
        except PermissionError:
            continue
        except OSError as exc:
            if exc.errno != errno.EROFS:
                raise ExportError(f"{table.parent}: cannot claim the session folder for the export "
                                  f"({exc.strerror or exc})") from None


def export_psychds(where, out, *, force: bool = False) -> dict:
    """Export the study at `where` as a Psych-DS dataset in `out`, its session folders claimed meanwhile;
    returns what was written (data files, records, participants)."""
    where = Path(where)
    with ExitStack() as stack:
        hold_sessions(where, stack)
        sessions = read_study(where)
        files = plan_export(sessions)
        write_dataset(files, out, force=force, sources=[s.table.parent for s in sessions])
    data = sorted(k for k in files if k.startswith(f"{DATA}/") and k.endswith("_data.csv"))
    return {"out": str(out), "data_files": data, "records": sorted(k for k in files if k.startswith(PRIMARY)),
            "participants": sorted({r[0] for s in sessions for r in split_sessions(s)})}

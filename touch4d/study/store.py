"""A participant's session folder on disk (`OUT/<participant>/`) and its trials.csv.

- `trials.csv`: one row per answered (or timed-out) trial, columns `table.COLUMNS`, each row written,
  flushed and fsync'd before the next trial starts, so a crash loses nothing; a restarted study node
  reads it back and resumes at the first trial without a row (`TrialsFile.done`).
- `manifest.json`: what the session is (touch4d.study.manifest).
- `session-NNN.mcap`: the recorder's log of every topic, one per run segment (`next_segment`).
- `.lock`, `.writer`: held by the run and the study node writing the folder (touch4d.study.lock).
"""
from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path

from touch4d.atomic import fsync_dir
from touch4d.errors import ConfigError, Touch4dError

from .table import ARRIVAL_COLUMNS, COLUMNS, TRIALS, _cell

# A session begun before the arrival columns existed resumes in its own columns (read back empty).
LEGACY_COLUMNS = tuple(c for c in COLUMNS if c not in ARRIVAL_COLUMNS)

SEGMENT = "session-{:03d}.mcap"
# A participant id is also a folder name, a bus namespace and part of a link: nothing that could climb
# out of OUT (`..`, `/`) or need quoting.
PARTICIPANT_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}\Z")
PARTICIPANT_ID_RULE = "a participant id: 1-32 letters, digits, _ or -, beginning with a letter or digit"


class SessionError(Touch4dError):
    """A session directory that cannot be used (names the file and why)."""


def check_participant_id(participant) -> str:
    """`participant` when it is fit to be a folder under OUT, else ValueError saying what is expected."""
    if not isinstance(participant, str) or not PARTICIPANT_ID.match(participant):
        raise ValueError(f"{PARTICIPANT_ID_RULE}, got {participant!r}")
    return participant


def session_dir(out, participant: str) -> Path:
    """Where a participant's session lives under an output directory (never outside it: the id is
    checked, SessionError naming it otherwise)."""
    try:
        return Path(out) / check_participant_id(participant)
    except ValueError as exc:
        raise SessionError(f"{out}: {exc}") from None


# ---- trials.csv -------------------------------------------------------------------------------------


def _complete(data: bytes) -> bytes:
    """trials.csv's bytes up to its last whole line (a row cut short by a crash was not written)."""
    return data if data.endswith(b"\n") else data[:data.rfind(b"\n") + 1]


def read_rows(directory) -> tuple[list[str], list[dict]]:
    """A session folder's trials.csv, read only: its header and its whole rows (none without one)."""
    try:
        data = _complete((Path(directory) / TRIALS).read_bytes())
    except OSError:
        return [], []
    reader = csv.DictReader(io.StringIO(data.decode(errors="replace")))
    rows = list(reader)
    return list(reader.fieldnames or []), rows


def rows_written(directory) -> int:
    """How many trials of a session folder have their row, read only (a server showing progress while
    the study node writes): its trials.csv's whole rows, 0 without one."""
    return len(read_rows(directory)[1])


class TrialsFile:
    """trials.csv, appended row by row (each row fsync'd). Opening an existing file reads its rows
    back (`rows` by index); a last line cut short by a crash is dropped (that trial is run again)."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rows: dict[int, dict] = {}
        self.columns = COLUMNS          # the file's own: COLUMNS, or LEGACY_COLUMNS for an older session
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
        fsync_dir(self.path.parent)

    def _read(self) -> None:
        data = self.path.read_bytes()
        if _complete(data) != data:   # a row cut short by a crash: not written, so not done
            data = _complete(data)
            with open(self.path, "r+b") as f:
                f.truncate(len(data))
                f.flush()
                os.fsync(f.fileno())
            if not data:            # the header itself was cut short: start the file again
                self._create()
                return
        reader = csv.DictReader(io.StringIO(data.decode()))
        header = tuple(reader.fieldnames or ())
        if header == LEGACY_COLUMNS:
            self.columns = LEGACY_COLUMNS
        elif header != COLUMNS:
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
        self._file.write(_csv_line([_cell(row[c]) for c in self.columns]))
        self._file.flush()
        os.fsync(self._file.fileno())
        self.rows[index] = {c: _cell(row[c]) for c in self.columns}

    def close(self) -> None:
        self._file.close()


def _csv_line(values) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()



def next_segment(directory) -> Path:
    """The next run segment's log: session-001.mcap, then session-002.mcap, ..."""
    directory = Path(directory)
    n = 1
    while (directory / SEGMENT.format(n)).exists():
        n += 1
    return directory / SEGMENT.format(n)

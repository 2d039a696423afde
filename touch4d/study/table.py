"""trials.csv, the tidy table of a study: one row per trial, the same columns whoever writes it (a
session through the full stack, or the offline simulation), read back for the analysis.

A study's output is a folder of session folders (`OUT/P01/trials.csv`, ...); `find_tables` accepts
that folder, one session folder, or a trials.csv itself.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from touch4d.errors import ConfigError

# When an answer reached touch4d (a page's: its arrival at the WebXR node, on this machine's clock),
# beside its stamp (when it was given: a page's own clock, mapped); `clock_suspect` 1: the two differ
# by more than an answer takes to arrive, so the page's clock claimed too much and `rt_s` is not to
# be trusted. Tables written before these columns existed are read with them empty.
ARRIVAL_COLUMNS = ("response_received", "clock_suspect")
MAX_ANSWER_DELAY_S = 1.0
COLUMNS = ("participant", "session", "block", "trial", "index", "practice", "task", "kind", "condition", "stimulus",
           "level", "transform", "answer", "response", "correct", "rt_s", "timed_out", "time_touching_s",
           "mean_intensity", "path_length", "onset_stamp", "response_stamp", "seed", *ARRIVAL_COLUMNS)
TRIALS = "trials.csv"


def write_rows(path, rows: list[dict]) -> None:
    """Write a whole trials.csv (header and rows, columns in order)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow([_cell(row[c]) for c in COLUMNS])
    path.write_text(buf.getvalue())


def _cell(value) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return "" if value is None else str(value)


def find_tables(where) -> list[Path]:
    """Every trials.csv at or below `where` (a folder of sessions, a session, or a trials.csv), sorted."""
    where = Path(where)
    if where.is_file():
        return [where]
    if not where.is_dir():
        raise ConfigError("command line", "DIR", "a folder of session folders, a session folder or a trials.csv",
                          detail=f"{where}: no such file or folder")
    found = sorted(where.rglob(TRIALS))
    if not found:
        raise ConfigError("command line", "DIR", f"a folder with at least one {TRIALS} (in it or below it)",
                          detail=f"{where}: none in it or below it")
    return found


def read_trials(where):
    """The trials of every table at or below `where` as one pandas DataFrame (typed columns; `source`
    names the file of each row). A table without the columns is a ConfigError naming it."""
    import pandas as pd

    frames = []
    for path in find_tables(where):
        try:
            frame = pd.read_csv(path, dtype={"participant": str, "session": str, "response": str, "answer": str,
                                             "stimulus": str, "task": str, "condition": str},
                                keep_default_na=False, na_values={"level": [""], "rt_s": [""],
                                                                  "response_stamp": [""], "response_received": [""]})
        except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
            raise ConfigError(path, "(file)", "a trials.csv table", got=str(exc).splitlines()[0]) from None
        for name, empty in zip(ARRIVAL_COLUMNS, ("", 0)):
            if name not in frame.columns:
                frame[name] = empty
        missing = [c for c in COLUMNS if c not in frame.columns]
        if missing:
            raise ConfigError(path, "(header)", f"the trials.csv columns {', '.join(COLUMNS)}",
                              got=f"missing {', '.join(missing)}")
        for name in ("practice", "correct", "timed_out", "clock_suspect"):
            flags = pd.to_numeric(frame[name], errors="coerce")
            bad = ~flags.isin([0, 1])
            if bad.any():
                line = int(bad.to_numpy().nonzero()[0][0]) + 2
                raise ConfigError(path, f"line {line}, column {name}", "0 or 1", got=frame[name][bad].iloc[0])
            frame[name] = flags.astype(bool)
        for name in ("level", "rt_s", "time_touching_s", "mean_intensity", "path_length", "response_received"):
            frame[name] = pd.to_numeric(frame[name], errors="coerce")    # empty: not measured (NaN)
        frame["source"] = str(path)
        frames.append(frame)
    data = pd.concat(frames, ignore_index=True)
    _refuse_repeats(data)
    return data


TRIAL_KEY = ("participant", "session", "block", "trial")     # one row per trial of a session


def _refuse_repeats(data) -> None:
    """A trial written twice (two writers on one session, or one participant's session in two tables)
    would be counted twice: a ConfigError naming the repeated trials and their files."""
    repeated = data[data.duplicated(list(TRIAL_KEY), keep=False)]
    if repeated.empty:
        return
    groups = repeated.groupby(list(TRIAL_KEY), sort=True)["source"]
    named = [f"participant {p} session {s} block {b} trial {t} ({len(files)}x: {', '.join(sorted(set(files)))})"
             for (p, s, b, t), files in groups]
    more = f" and {len(named) - 5} more" if len(named) > 5 else ""
    raise ConfigError(repeated["source"].iloc[0], "(rows)", "each (participant, session, block, trial) once",
                      got=f"{len(named)} trial(s) more than once", detail="; ".join(named[:5]) + more,
                      hint="two writers on one session folder, or one session in two tables: keep one of each")


def trial_row(trial, *, participant: str, session: str, response: str | None, onset: float,
              response_stamp: float | None, time_touching_s: float, mean_intensity: float,
              path_length: float, response_received: float | None = None) -> dict:
    """The table row of a planned trial (touch4d.study.plan.Trial) and what happened in it: the one
    place a row is made, for sessions on the bus and offline simulations alike. `response_received`:
    when the answer reached touch4d, if known (see ARRIVAL_COLUMNS)."""
    timed_out = response is None
    received = None if timed_out or not response_received else float(response_received)
    return {
        "participant": participant, "session": session, "block": trial.block, "trial": trial.trial,
        "index": trial.index, "practice": bool(trial.practice), "task": trial.task, "kind": trial.kind,
        "condition": trial.condition, "stimulus": trial.stimulus, "level": float(trial.level),
        "transform": json.dumps([[p, float(d)] for p, d in trial.transform]), "answer": trial.answer,
        "response": "" if timed_out else response, "correct": (not timed_out) and response == trial.answer,
        "rt_s": math.nan if timed_out else response_stamp - onset, "timed_out": timed_out,
        "time_touching_s": time_touching_s, "mean_intensity": mean_intensity, "path_length": path_length,
        "onset_stamp": onset, "response_stamp": math.nan if response_stamp is None else response_stamp,
        "seed": int(trial.seed),
        "response_received": math.nan if received is None else received,
        "clock_suspect": received is not None and abs(received - response_stamp) > MAX_ANSWER_DELAY_S,
    }

"""An independent checker of Psych-DS datasets (specification 1.5.0), written from the spec's rules
and not from touch4d's exporter, for the tests: `check(root)` -> (errors, warnings), each a
(code, path, message) with the spec's error codes.

Rules checked (the spec's schema_model/versions/1.5.0):
- dataset_description.json in the root: UTF-8 JSON object, JSON-LD with the schema.org @context,
  @type (or type) Dataset, and the required name, description and variableMeasured
  (rules/compiled_metadata.yaml; errors MissingDatasetType, IncorrectDatasetType, JsonKeyRequired).
- a data/ folder with at least one data file (rules/files/common/core.yaml, MISSING_DATAFILE).
- every .csv under data/ (less what .psychds-ignore lists) named by the keyword grammar
  `([a-z]+-[a-zA-Z0-9]+)(_[a-z]+-[a-zA-Z0-9]+)*_data\\.csv` (FILENAME_KEYWORD_FORMATTING_ERROR);
  keys outside the official vocabulary warned (FILENAME_UNOFFICIAL_KEYWORD_WARNING).
- CSV rules (objects/extensions.yaml, rules/errors.yaml): UTF-8, a header, no repeated header,
  every row as long as the header, no empty line, quotes closed, row_id unique.
- the compiled metadata of each data file (dataset_description.json, then each file_metadata.json
  from data/ down, then its sidecar; a key replaced whole) lists every column in variableMeasured
  (CSV_COLUMN_MISSING_FROM_METADATA); every variable names a column of some data file
  (VARIABLE_MISSING_FROM_CSV_COLUMNS).
"""
from __future__ import annotations

import csv
import fnmatch
import io
import json
import re
from pathlib import Path

FILE_NAME = re.compile(r"([a-z]+-[a-zA-Z0-9]+)(_[a-z]+-[a-zA-Z0-9]+)*_data\.csv")
OFFICIAL_KEYS = {"study", "site", "subject", "session", "task", "condition", "trial", "stimulus", "description"}
SCHEMA_ORG = {"http://schema.org", "https://schema.org", "http://schema.org/", "https://schema.org/"}
DATASET_TYPES = {"Dataset", "https://schema.org/Dataset", "http://schema.org/Dataset"}
REQUIRED = ("name", "description", "variableMeasured")


def check(root) -> tuple[list[tuple[str, str, str]], list[tuple[str, str, str]]]:
    """The errors and warnings of the dataset at `root`."""
    root = Path(root)
    errors, warnings = [], []
    top = _description(root, errors)
    data = root / "data"
    if not data.is_dir():
        errors.append(("MISSING_DATA_DIRECTORY", "data", "no data/ folder"))
        return errors, warnings
    ignored = _ignore_patterns(root)
    columns_seen: set[str] = set()
    valid = 0
    for path in sorted(data.rglob("*.csv")):
        relative = path.relative_to(root).as_posix()
        if _ignored(relative, ignored):
            continue
        if not FILE_NAME.fullmatch(path.name):
            errors.append(("FILENAME_KEYWORD_FORMATTING_ERROR", relative, f"{path.name} breaks the keyword grammar"))
            continue
        keys = [pair.split("-", 1)[0] for pair in path.name[:-len("_data.csv")].split("_")]
        for key in keys:
            if key not in OFFICIAL_KEYS:
                warnings.append(("FILENAME_UNOFFICIAL_KEYWORD_WARNING", relative, f"keyword {key!r}"))
        header = _csv(path, relative, errors)
        if header is None:
            continue
        valid += 1
        columns_seen.update(header)
        meta = _compiled(root, path, top)
        names = _variable_names(meta.get("variableMeasured"))
        missing = [c for c in header if c not in names]
        if missing:
            errors.append(("CSV_COLUMN_MISSING_FROM_METADATA", relative, "not in variableMeasured: " + ", ".join(missing)))
    if not valid:
        errors.append(("MISSING_DATAFILE", "data", "no valid data file under data/"))
    extra = [v for v in _variable_names(top.get("variableMeasured")) if v not in columns_seen]
    if top and valid and extra:
        errors.append(("VARIABLE_MISSING_FROM_CSV_COLUMNS", "dataset_description.json", ", ".join(extra)))
    return errors, warnings


def _description(root: Path, errors: list) -> dict:
    """dataset_description.json, checked; {} when it cannot be read."""
    path = root / "dataset_description.json"
    if not path.is_file():
        errors.append(("MISSING_DATASET_DESCRIPTION", path.name, "no dataset_description.json in the root"))
        return {}
    try:
        top = json.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError:
        errors.append(("JSON_ENCODING_ERROR", path.name, "not UTF-8"))
        return {}
    except ValueError as exc:
        errors.append(("JSON_INVALID", path.name, str(exc)))
        return {}
    if not isinstance(top, dict):
        errors.append(("INVALID_JSON_FORMATTING", path.name, "not a JSON object"))
        return {}
    context = top.get("@context")
    contexts = context if isinstance(context, list) else [context]
    if not any(isinstance(c, str) and c in SCHEMA_ORG for c in contexts):
        errors.append(("INVALID_JSONLD_FORMATTING", path.name, f"@context {context!r} is not schema.org"))
    kind = top.get("@type", top.get("type"))
    if kind is None:
        errors.append(("MISSING_DATASET_TYPE", path.name, "no @type"))
    elif kind not in DATASET_TYPES:
        errors.append(("INCORRECT_DATASET_TYPE", path.name, f"@type {kind!r}"))
    for key in REQUIRED:
        value = top.get(key, top.get(f"https://schema.org/{key}"))
        if value in (None, "", []):
            errors.append(("JSON_KEY_REQUIRED", path.name, f"no {key}"))
    variables = top.get("variableMeasured")
    if variables is not None and not isinstance(variables, list):
        errors.append(("INVALID_JSON_FORMATTING", path.name, "variableMeasured is not a list"))
    return top


def _variable_names(variables) -> list[str]:
    """The column names a variableMeasured lists: strings, or PropertyValue objects' names."""
    if not isinstance(variables, list):
        return []
    return [v if isinstance(v, str) else v.get("name") for v in variables
            if isinstance(v, str) or (isinstance(v, dict) and isinstance(v.get("name"), str))]


def _csv(path: Path, relative: str, errors: list) -> list[str] | None:
    """A data file's header, its CSV rules checked; None when it breaks one."""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        errors.append(("CSV_FORMATTING_ERROR", relative, "not UTF-8"))
        return None
    lines = io.StringIO(text, newline=None).read().split("\n")     # \r\n and \r end lines too
    if not lines or not lines[0].strip():
        errors.append(("CSV_HEADER_MISSING", relative, "no header"))
        return None
    try:
        rows = list(csv.reader(io.StringIO(text, newline=None), strict=True))
    except csv.Error as exc:
        errors.append(("CSV_FORMATTING_ERROR", relative, str(exc)))
        return None
    if text.count('"') % 2:
        errors.append(("CSV_FORMATTING_ERROR", relative, "a quote left open"))
        return None
    header = rows[0]
    if len(set(header)) != len(header):
        errors.append(("CSV_HEADER_REPEATED", relative, ", ".join(sorted({h for h in header if header.count(h) > 1}))))
        return None
    for number, row in enumerate(rows[1:], start=2):
        if not row:
            errors.append(("CSV_FORMATTING_ERROR", relative, f"line {number} is empty"))
            return None
        if len(row) != len(header):
            errors.append(("CSV_HEADER_LENGTH_MISMATCH", relative, f"line {number}: {len(row)} fields, "
                                                                    f"{len(header)} columns"))
            return None
    if "row_id" in header:
        ids = [row[header.index("row_id")] for row in rows[1:]]
        if len(set(ids)) != len(ids):
            errors.append(("ROWID_VALUES_NOT_UNIQUE", relative, "row_id repeats"))
    return header


def _compiled(root: Path, path: Path, top: dict) -> dict:
    """A data file's metadata by inheritance: the root's, each file_metadata.json from data/ down to its
    folder, then its sidecar (same name, .json); each key replaced whole."""
    meta = dict(top)
    folder = root / "data"
    chain = [folder, *[folder / Path(*path.parent.relative_to(folder).parts[:i + 1])
                       for i in range(len(path.parent.relative_to(folder).parts))]]
    for layer in [d / "file_metadata.json" for d in chain] + [path.with_suffix(".json")]:
        if layer.is_file():
            try:
                meta.update(json.loads(layer.read_text()))
            except ValueError:
                pass
    return meta


def _ignore_patterns(root: Path) -> list[str]:
    path = root / ".psychds-ignore"
    if not path.is_file():
        return []
    return [line.strip() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


def _ignored(relative: str, patterns: list[str]) -> bool:
    """Whether a path matches a .psychds-ignore line (gitignore-like: a trailing / names a folder, a
    pattern with a / is anchored at the root, one without matches a name anywhere)."""
    for pattern in patterns:
        anchored = pattern.strip("/")
        if pattern.endswith("/"):
            if relative.startswith(anchored + "/") if "/" in anchored else anchored in relative.split("/")[:-1]:
                return True
        elif "/" in anchored:
            if fnmatch.fnmatch(relative, anchored):
                return True
        elif any(fnmatch.fnmatch(part, anchored) for part in relative.split("/")):
            return True
    return False

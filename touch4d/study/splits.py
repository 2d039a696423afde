"""A study's results split by a field of its sessions' manifests (`touch4d study analyze DIR --by
FIELD`): each session's manifest.json says how it ran (the software version, the glove by its
sha256, the condition order, what a served participant's browser could do); the trials of the sessions that agree on the
field are analysed together, one group per value, as `analysis.analyze` analyses the whole study.

FIELD is a dotted path into the manifest (`version`, `condition_order`, `device.browser`), `manifest.` before
it optional; a session whose manifest lacks it forms the group `(missing)`.
"""
from __future__ import annotations

import json
from pathlib import Path

from touch4d.errors import ConfigError

from .analysis import analyze
from .manifest import MANIFEST, read_manifest

MISSING = "(missing)"
PREFIX = "manifest."
_ABSENT = object()


def field_path(field: str) -> list[str]:
    """FIELD's keys: `manifest.device.browser` -> ['device', 'browser']; ConfigError when one is empty."""
    keys = (field[len(PREFIX):] if field.startswith(PREFIX) else field).split(".")
    if not field or not all(keys):
        raise ConfigError("command line", "--by", "a manifest field, dotted (version, glove_sha256, "
                          "manifest.device.browser)", got=field)
    return keys


def manifest_value(manifest: dict, keys: list[str]):
    """The value at `keys` in a manifest, or _ABSENT (a list is indexed by a number key)."""
    value = manifest
    for key in keys:
        if isinstance(value, dict) and key in value:
            value = value[key]
        elif isinstance(value, list) and key.isdigit() and int(key) < len(value):
            value = value[int(key)]
        else:
            return _ABSENT
    return value


def label(value) -> str:
    """A group's name: a string as it is, anything else as JSON (true, 0.2, {"a": 1}), absent as (missing)."""
    if value is _ABSENT:
        return MISSING
    return value if isinstance(value, str) else json.dumps(value, sort_keys=True)


def groups_of(data, field: str) -> dict[str, list[str]]:
    """The tables (`source` of the rows) of each value of `field`, values in first-seen order; ConfigError
    naming the field when no session's manifest has it."""
    keys = field_path(field)
    groups: dict[str, list[str]] = {}
    seen = set()
    for source in dict.fromkeys(data["source"]):
        manifest = read_manifest(Path(source).parent)
        seen.update(manifest)
        groups.setdefault(label(manifest_value(manifest, keys)), []).append(source)
    if set(groups) == {MISSING}:
        raise ConfigError("command line", "--by", f"a field of the sessions' {MANIFEST} (they have: "
                          f"{', '.join(sorted(seen)) or 'no manifest'})", got=field)
    return groups


def analyze_by(data, field: str, **options) -> dict:
    """`analyze`'s result for each group of sessions that agree on `field` (options as `analyze` takes
    them): {"field", "groups": [{"value", "participants", "sessions", "trials", "result"}]}."""
    out = []
    for value, sources in groups_of(data, field).items():
        rows = data[data["source"].isin(sources)].reset_index(drop=True)
        group = {"value": value, "participants": sorted(map(str, rows["participant"].unique())),
                 "sessions": sorted(sources), "trials": int(len(rows))}
        group["result"] = analyze(rows, **options) if len(rows) else None
        out.append(group)
    return {"field": field, "groups": out}

"""Recruiting by one open link (`touch4d study serve --open-link`): which participant id the next
visitor gets, and which participant a recruitment platform's id (Prolific's PROLIFIC_PID, ...) already
has. Pure but for `Recruits`, the file that keeps the link's key and the platform ids (OUT/recruits.json).

Counterbalancing: a numbered id Pn takes row (n - 1) % rows of the order table (touch4d.study.plan), so
the next visitor gets the lowest free Pn whose row is the least filled by the participants who hold a
row: those done, and those under way (joined, or just given a link) whose last trial (or join, or link)
is recent. A place abandoned (no trial within `leave_after_s`, or a link never joined within
`pending_s`) holds no row: its row goes to the next visitor.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping

from touch4d.atomic import write_atomic
from touch4d.tokens import check_token, new_token

from .store import check_participant_id

FILE = "recruits.json"
PLATFORM_PARAMS = ("PROLIFIC_PID", "STUDY_ID", "SESSION_ID")   # what Prolific appends to a study's URL
IDENTITY = "PROLIFIC_PID"           # the one that names a person (the others name the study and the try)
MAX_PARAM_CHARS = 128               # a platform's id is short; a longer one is refused
PENDING_S = 600.0                   # a visitor given a link holds its row this long before joining
UNDER_WAY = ("invited", "starting", "running", "paused")


@dataclass(frozen=True)
class Place:
    """A participant as the assignment sees it: its state (touch4d.study.participation's words), and
    when it last moved (a trial's row, its join, its link made; None: never by the open link)."""

    participant: str
    state: str
    since: float | None = None


def holds_row(place: Place, now: float, leave_after_s: float, pending_s: float = PENDING_S) -> bool:
    """Whether `place` fills its counterbalancing row: done, or under way and not abandoned."""
    if place.state == "done":
        return True
    if place.state not in UNDER_WAY or place.since is None:
        return False
    return now - place.since <= (pending_s if place.state == "invited" else leave_after_s)


def rows_filled(rows: int, places: Iterable[Place], row_of: Callable[[str], int], now: float,
                leave_after_s: float, pending_s: float = PENDING_S) -> list[int]:
    """How many participants hold each row (from 0) of an order table of `rows` rows."""
    filled = [0] * rows
    for place in places:
        if holds_row(place, now, leave_after_s, pending_s):
            filled[row_of(place.participant)] += 1
    return filled


def numbered_id(n: int) -> str:
    """P01, P02, ..., P100: the id that takes row (n - 1) % rows."""
    return f"P{n:02d}"


def next_participant(filled: list[int], taken: Iterable[str]) -> tuple[str, int]:
    """The id for the next visitor and its row (from 0): the least filled row (the first of equals),
    the lowest numbered id of that row not `taken` (with a folder or a link)."""
    if not filled:
        raise ValueError("an order table of at least one row")
    taken = {t.upper() for t in taken}
    rows = len(filled)
    row = min(range(rows), key=lambda r: (filled[r], r))
    n = row + 1
    while numbered_id(n) in taken:
        n += rows
    return numbered_id(n), row


def platform_params(query: Mapping[str, str], names: Iterable[str]) -> dict[str, str]:
    """The platform's parameters among `names` present in `query`, each printable and at most
    MAX_PARAM_CHARS long (else ValueError naming it): kept in the manifest, never in a file's name."""
    kept = {}
    for name in names:
        value = query.get(name)
        if value is None:
            continue
        if not value or len(value) > MAX_PARAM_CHARS or not value.isprintable():
            raise ValueError(f"{name}: expected 1-{MAX_PARAM_CHARS} printable characters, got {value[:40]!r}")
        kept[name] = value
    return kept


def identity(params: Mapping[str, str], id_params: Iterable[str] = ()) -> str | None:
    """Who the platform says the visitor is: `PROLIFIC_PID=...`, else the first of `id_params` given
    (`workerId=...`); None when it says nothing (every such visit is a new participant)."""
    for name in (IDENTITY, *id_params):
        if name in params:
            return f"{name}={params[name]}"
    return None


class Recruits:
    """OUT/recruits.json: the open link's key (None: closed) and each platform identity's participant
    and parameters; written whole (touch4d.atomic), readable by its owner only."""

    def __init__(self, out: Path):
        self.path = Path(out) / FILE
        self.key: str | None = None
        self.platform: dict[str, dict] = {}     # identity -> {"participant": id, "params": {...}}
        self._read()

    def _read(self) -> None:
        try:
            data = json.loads(self.path.read_text())
        except FileNotFoundError:
            return
        except (OSError, ValueError) as exc:
            raise ValueError(f"{self.path}: expected the open link's JSON ({exc})") from None
        key, platform = (data.get("key"), data.get("platform", {})) if isinstance(data, dict) else (0, 0)
        if not (key is None or (isinstance(key, str) and check_token(key) is None)) or not isinstance(platform, dict) \
                or not all(isinstance(v, dict) and isinstance(v.get("participant"), str)
                           and isinstance(v.get("params"), dict) for v in platform.values()):
            raise ValueError(f"{self.path}: expected {{\"key\": a token or null, \"platform\": {{identity: "
                             "{\"participant\": id, \"params\": {...}}}}}")
        self.key, self.platform = key, platform

    def _save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(self.path, json.dumps({"key": self.key, "platform": self.platform}, indent=1, sort_keys=True)
                     + "\n", mode=0o600)

    def open(self) -> str:
        """The open link's key (made now if it has none)."""
        if self.key is None:
            self.key = new_token()
            self._save()
        return self.key

    def close(self) -> None:
        """The open link revoked: its key refused from now on (a new --open-link start makes another)."""
        self.key = None
        self._save()

    def participant_of(self, who: str | None) -> str | None:
        entry = self.platform.get(who) if who is not None else None
        return None if entry is None else entry["participant"]

    def params_of(self, participant: str) -> dict[str, str] | None:
        """The platform's parameters of `participant`'s first visit (None: not from a platform)."""
        for entry in self.platform.values():
            if entry["participant"] == participant:
                return dict(entry["params"])
        return None

    def remember(self, who: str, participant: str, params: Mapping[str, str]) -> None:
        self.platform[who] = {"participant": check_participant_id(participant), "params": dict(params)}
        self._save()

    def forget(self, participant: str) -> None:
        """`participant`'s platform identity freed (its device failed the check: it may try another)."""
        gone = [who for who, entry in self.platform.items() if entry["participant"] == participant]
        for who in gone:
            del self.platform[who]
        if gone:
            self._save()

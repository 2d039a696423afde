"""A served study's links (`touch4d study invite`, `touch4d study serve`): one secret token per
participant id, and one for the experimenter, kept in OUT/invites.json (readable by its owner only,
written whole), so links outlive a server that is restarted and can be made while it runs.
"""
from __future__ import annotations

import json
from pathlib import Path

from touch4d.atomic import write_atomic
from touch4d.study.store import PARTICIPANT_ID_RULE, check_participant_id

from .access import check_token, new_token

EXPERIMENTER = "experimenter"
FILE = "invites.json"


def check_participant(participant: str) -> str:
    """A participant id fit for a link, a namespace and a folder (touch4d.study.store's rule) and not the
    experimenter's, or ValueError saying what is expected."""
    if participant == EXPERIMENTER:
        raise ValueError(f"{PARTICIPANT_ID_RULE} (not '{EXPERIMENTER}'), got {participant!r}")
    return check_participant_id(participant)


class Invites:
    """OUT/invites.json: {holder: token}."""

    def __init__(self, out: Path):
        self.path = Path(out) / FILE

    def signature(self) -> tuple | None:
        """What changes whenever the file is written (it is replaced whole): read it again only then."""
        try:
            st = self.path.stat()
        except OSError:
            return None
        return st.st_ino, st.st_mtime_ns, st.st_size

    def load(self) -> dict[str, str]:
        """The tokens (a file that cannot be read as such: none, and a ValueError says why)."""
        try:
            data = json.loads(self.path.read_text())
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{self.path}: expected a JSON object of participant ids and tokens ({exc})") from None
        if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) and check_token(v) is None
                                                 for k, v in data.items()):
            raise ValueError(f"{self.path}: expected a JSON object of participant ids and tokens")
        return data

    def issue(self, holder: str, keep: bool = False) -> str:
        """`holder`'s token: a new one (its old link stops working), or with `keep` the one it has."""
        if holder != EXPERIMENTER:
            check_participant(holder)
        tokens = self.load()
        if keep and holder in tokens:
            return tokens[holder]
        tokens[holder] = new_token()
        self._save(tokens)
        return tokens[holder]

    def revoke(self, holder: str) -> bool:
        tokens = self.load()
        if tokens.pop(holder, None) is None:
            return False
        self._save(tokens)
        return True

    def _save(self, tokens: dict[str, str]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(self.path, json.dumps(tokens, indent=1, sort_keys=True) + "\n", mode=0o600)

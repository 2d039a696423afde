"""Errors for bad input: each names where the problem is and what was expected."""
from __future__ import annotations

import reprlib

# What an error shows of a wrong value, bounded: a YAML alias bomb (nested lists of aliases, 9^9
# items once expanded) would otherwise take minutes and gigabytes to repr before being cut.
_SHOWN = reprlib.Repr()
_SHOWN.maxlevel, _SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlong = 6, 200, 200, 200
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = _SHOWN.maxset = _SHOWN.maxfrozenset = _SHOWN.maxdeque = 12


class Touch4dError(Exception):
    """Base of every error touch4d reports to a user (printed without a traceback)."""


class ConfigError(Touch4dError, ValueError):
    """A config, scene, glove or launch file is wrong: names the file, the key and what was expected."""

    def __init__(self, file, key: str, expected: str, got=None, *, hint: str | None = None,
                 detail: str | None = None):
        self.file = str(file) if file is not None else "<input>"
        self.key = key
        self.expected = expected
        self.got = got
        self.hint = hint
        self.detail = detail
        where = key if key.startswith("line ") else f"key '{key}'"   # a YAML syntax error has no key
        text = f"{self.file}: {where}: expected {expected}"
        if got is not None:
            shown = _SHOWN.repr(got)
            text += f", got {shown[:80] + '...' if len(shown) > 80 else shown}"
        if detail:
            text += f": {detail}"          # whole: a YAML problem or a reason is never cut
        if hint:
            text += f" ({hint})"
        super().__init__(text)


class Unavailable(Touch4dError):
    """Something a node needs is not there: a package, a device, a service (says which)."""

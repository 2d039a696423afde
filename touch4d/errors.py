"""Errors for bad input: each names where the problem is and what was expected."""
from __future__ import annotations


class Touch4dError(Exception):
    """Base of every error touch4d reports to a user (printed without a traceback)."""


class ConfigError(Touch4dError, ValueError):
    """A config, scene, glove or launch file is wrong: names the file, the key and what was expected."""

    def __init__(self, file, key: str, expected: str, got=None):
        self.file = str(file) if file is not None else "<input>"
        self.key = key
        self.expected = expected
        self.got = got
        text = f"{self.file}: key '{key}': expected {expected}"
        if got is not None:
            shown = repr(got)
            text += f", got {shown[:80] + '...' if len(shown) > 80 else shown}"
        super().__init__(text)


class Unavailable(Touch4dError):
    """Something a node needs is not there: a package, a device, a service (says which)."""

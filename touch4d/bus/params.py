"""Node parameters, declared once on the node class: type, default, bounds, documentation.

The launcher checks a launch file's parameters against these declarations before it starts any
process, and the node checks them again when it starts (it may be run without the launcher), with
the same function, so both say the same thing:

    class ScriptedTracker(Node):
        PARAMS = {
            "rate": Param(90.0, "poses per second", unit="Hz", above=0, max=1000),
            "path": Param("demo", "a path name of the paths file"),
            "paths": Param("config/paths.yaml", "the paths file", path=True),
        }
"""
from __future__ import annotations

import typing
from dataclasses import dataclass
from functools import cached_property
from typing import Annotated, Any, Callable

import msgspec

from touch4d import schema

_TYPES = (bool, int, float, str, list, dict)
_TYPE_TEXT = {bool: "true or false", int: "an integer", float: "a number", str: "a string", list: "a list",
              dict: "a mapping"}
_PLURAL = {bool: "booleans", int: "integers", float: "finite numbers", str: "strings", list: "lists", dict: "mappings"}
_ITEMS = {bool: bool, int: int, float: schema.Finite, str: str, list: list, dict: dict}


@dataclass(frozen=True)
class Param:
    """One parameter: its default (whose type is the parameter's unless `type` says otherwise) and checks.

    `above`/`min`/`max` bound numbers (exclusive/inclusive/inclusive), `choices` lists the allowed
    values, `items` and `length` constrain lists, `path` marks a file and says what it is ("glove
    file"): the node gets it found by touch4d.configfile.resolve_path (the current directory, the
    launch file's folder, the packaged defaults) as a Path. A default of None makes the parameter
    optional (null allowed). `port` marks a TCP port the node serves on; `touch4d launch` checks
    paths and ports before it starts any node (touch4d.bus.preflight).
    """

    default: Any
    doc: str = ""
    type: type | None = None
    unit: str = ""
    choices: tuple = ()
    above: float | None = None
    min: float | None = None
    max: float | None = None
    items: type | None = None
    length: int | None = None
    path: bool | str = False
    finite: bool = True
    port: bool = False   # a TCP port the node serves on (on its `host` parameter, if any): the launcher checks it is free

    def __post_init__(self):
        kind = self.kind
        if kind not in _TYPES:
            raise TypeError(f"Param type must be one of {[t.__name__ for t in _TYPES]}, got {kind!r}")

    @property
    def kind(self) -> type:
        """The parameter's type: `type` if given, else that of the default."""
        if self.type is not None:
            return self.type
        if self.default is None:
            raise TypeError("a Param whose default is None needs type=")
        return type(self.default)

    @property
    def path_what(self) -> str:
        """What the file is, for messages ("glove file")."""
        return self.path if isinstance(self.path, str) else "file"

    def describe(self) -> str:
        """What a valid value is, in words (used in error messages and `touch4d node info`)."""
        kind = self.kind
        if self.choices:
            text = "one of " + ", ".join(str(c) for c in self.choices)
        elif kind is list and (self.items or self.length):
            what = _PLURAL[self.items] if self.items else "values"
            text = f"a list of {self.length} {what}" if self.length else f"a list of {what}"
        elif self.path:
            text = f"a {self.path_what} path"
        else:
            text = _TYPE_TEXT[kind]
            if kind is float and self.finite:
                text = "a finite number"
        bounds = []
        if self.above is not None:
            bounds.append(f"> {self.above:g}")
        if self.min is not None:
            bounds.append(f">= {self.min:g}")
        if self.max is not None:
            bounds.append(f"<= {self.max:g}")
        if bounds:
            text += " " + " and ".join(bounds)
        if self.unit:
            text += f" ({self.unit})"
        if self.default is None:
            text += ", or null"
        return text

    @cached_property
    def annotation(self):
        """The parameter as a msgspec type: what `check` converts a value to (touch4d.schema's layer)."""
        kind = self.kind
        bounds = {}
        if kind in (int, float):
            bounds = {k: v for k, v in (("gt", self.above), ("ge", self.min), ("le", self.max)) if v is not None}
            if kind is float and self.finite:
                if "gt" not in bounds:
                    bounds.setdefault("ge", -schema.FINITE_MAX)
                bounds.setdefault("le", schema.FINITE_MAX)
        elif kind is list and self.length is not None:
            bounds = {"min_length": self.length, "max_length": self.length}
        base = list[_ITEMS[self.items]] if kind is list and self.items is not None else kind
        annotation = Annotated[base, msgspec.Meta(**bounds)] if bounds else base
        return typing.Optional[annotation] if self.default is None else annotation

    def check(self, value) -> Any:
        """`value` converted to the parameter's type (an int for a float parameter becomes a float);
        raises schema.Invalid (a ValueError) whose text is describe() when it is not valid."""
        if isinstance(value, (list, dict)) and not _small(value):
            # A parameter goes to its node as JSON on the command line: a YAML alias bomb (lists of
            # aliases, billions of values once expanded) would take minutes here and then fail there.
            raise schema.Invalid(f"{self.describe()} of at most {MAX_VALUES} values in all", value)
        try:
            value = msgspec.convert(schema.plain(value), self.annotation, strict=True)
        except msgspec.ValidationError:
            raise schema.Invalid(self.describe(), value) from None
        if self.choices and value not in self.choices:
            raise schema.Invalid(self.describe(), value, choices=self.choices)
        return value

    def to_dict(self) -> dict:
        """The declaration as plain data (for `touch4d node info --json`)."""
        return {"type": self.kind.__name__, "default": self.default, "doc": self.doc, "valid": self.describe()}


MAX_VALUES = 100_000   # values in a list or mapping parameter, nested ones included


def _small(value, limit: int = MAX_VALUES) -> bool:
    """Whether `value` holds at most `limit` values, nested ones counted as often as they appear
    (a walk that stops at the limit, so a structure that repeats itself costs no more)."""
    stack, seen = [value], 0
    while stack:
        item = stack.pop()
        seen += 1
        if seen > limit:
            return False
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return True


def suggest(name: str, choices) -> str:
    """' (did you mean 'x'?)' for the closest of `choices`, or ''."""
    hint = schema.did_you_mean(str(name), choices)
    return f" ({hint})" if hint else ""


def check_params(declared: dict[str, Param], given: dict, error: Callable[[str, str, Any], Exception],
                 owner: str) -> dict:
    """Every declared parameter's value: `given`'s, checked, or the default. `error(name, expected,
    got)` builds the exception for an undeclared name or a bad value; `owner` names the node in it."""
    for name in given:
        if name not in declared:
            known = ", ".join(sorted(declared)) or "none"
            raise error(name, f"a parameter of {owner} (one of: {known}){suggest(name, declared)}", name)
    values = {}
    for name, param in declared.items():
        if name not in given:
            values[name] = param.default
            continue
        try:
            values[name] = param.check(given[name])
        except schema.Invalid as exc:
            hint = f" ({exc.hint})" if exc.hint else ""
            raise error(name, f"{exc} for parameter '{name}' of {owner}{hint}", given[name]) from None
    return values

"""One schema layer for every file a user writes: YAML read with whole syntax errors, then
converted to declared types (msgspec Structs) with one error naming file, key path, expected and got.

Declare a file's shape once as `msgspec.Struct` classes (`forbid_unknown_fields=True` so a typo is
caught, `Annotated[float, msgspec.Meta(gt=0)]` for ranges) and call `load(path, Type)` or
`convert(data, Type, file)`. Every mistake is a `ConfigError(file, "objects[0].size", expected,
got)`; an unknown key suggests the nearest declared one (`did you mean 'position'?`); a YAML syntax
error names line and column and the whole problem. Checks no type can express (a unit
quaternion, a known shape name) raise `ConfigError` from the Struct's `__post_init__` or the
caller, with `fail(...)`.
"""
from __future__ import annotations

import difflib
import re
import typing
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import yaml

from touch4d.errors import ConfigError

T = TypeVar("T")

_AT = re.compile(r" - at `\$(?P<path>[^`]*)`$")
_UNKNOWN = re.compile(r"^Object contains unknown field `(?P<name>[^`]*)`")
_MISSING = re.compile(r"^Object missing required field `(?P<name>[^`]*)`")
_EXPECTED = re.compile(r"^Expected (?P<expected>.+?)(?:, got `(?P<got>[^`]*)`|, got (?P<count>\d+))?$")
# msgspec's words for YAML's kinds of value, as a user of a YAML file knows them
_WORDS = {"object": "a mapping", "array": "a list", "str": "a string", "float": "a number", "int": "an integer",
          "bool": "true or false", "null": "nothing (null)"}


def read_text(path, what: str = "file") -> str:
    """The text of `path`; an unreadable file is a ConfigError naming it."""
    path = Path(path)
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise ConfigError(path, "(file)", f"a readable {what} (UTF-8 text)", got=str(exc)) from None
    except OSError as exc:
        raise ConfigError(path, "(file)", f"a readable {what}", got=exc.strerror or str(exc)) from None


def parse_yaml(text: str, file=None) -> Any:
    """`text` parsed as YAML; a syntax error is a ConfigError with line, column and the whole problem."""
    try:
        return yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "(file)"
        problem = " ".join(p for p in (exc.context, exc.problem) if p)
        line = text.splitlines()[mark.line] if mark is not None and mark.line < len(text.splitlines()) else ""
        if "\t" in line and "tab" not in problem:
            problem += " (a tab: YAML indents with spaces only)"
        raise ConfigError(file, where, "valid YAML", got=None, detail=problem or str(exc)) from None
    except yaml.YAMLError as exc:
        raise ConfigError(file, "(file)", "valid YAML", detail=str(exc)) from None


def read_yaml(path, what: str = "file") -> Any:
    """The parsed contents of the YAML file `path` (ConfigError naming it on any problem)."""
    return parse_yaml(read_text(path, what), Path(path))


def load(path, type_: type[T], what: str = "file") -> T:
    """The YAML file `path` read and converted to `type_` (see `convert`)."""
    return convert(read_yaml(path, what), type_, Path(path))


def convert(data: Any, type_: type[T], file=None, key: str = "") -> T:
    """`data` (as YAML or JSON gives it) as `type_`; a mismatch is a ConfigError naming the key path
    below `key`, what was expected and what was there, with a did-you-mean for an unknown key."""
    try:
        return msgspec.convert(data, type_, strict=True)
    except msgspec.ValidationError as exc:
        raise _config_error(str(exc), data, type_, file, key) from None


def fail(file, key: str, expected: str, got=None, choices=None) -> typing.NoReturn:
    """Raise the ConfigError of a check no type expresses; `choices` adds a did-you-mean for `got`."""
    raise ConfigError(file, key, expected, got=got, hint=did_you_mean(got, choices) if choices else None)


def did_you_mean(word, choices) -> str | None:
    """`did you mean 'x'?` for the nearest of `choices` to `word`, or None."""
    if not isinstance(word, str):
        return None
    near = difflib.get_close_matches(word, [str(c) for c in choices], n=1, cutoff=0.6)
    return f"did you mean '{near[0]}'?" if near else None


def join(key: str, part: str) -> str:
    """`key` extended by `part` (a field name or `[3]`), as keys are shown in errors."""
    if not key:
        return part.lstrip(".")
    return key + part if part.startswith("[") else f"{key}.{part}"


def struct_fields(type_) -> tuple[str, ...]:
    """The field names (as written in files) of a Struct type, else ()."""
    info = _struct(type_)
    return tuple(f.encode_name for f in msgspec.inspect.type_info(info).fields) if info else ()


def describe(type_) -> str:
    """A short human description of an annotation, for messages."""
    return str(msgspec.inspect.type_info(type_).__class__.__name__).removesuffix("Type").lower()


# ---- msgspec's error text -> ConfigError ------------------------------------------------------------


def _config_error(text: str, data, type_, file, prefix: str) -> ConfigError:
    path = ""
    at = _AT.search(text)
    if at:
        path = at.group("path")
        text = text[: at.start()]
    parts = re.findall(r"\.([^.\[\]]+)|\[(\d+)\]", path)
    steps: list[str | int] = [name if name else int(index) for name, index in parts]
    key = prefix
    for step in steps:
        key = join(key, f"[{step}]" if isinstance(step, int) else step)
    value, found = _follow(data, steps)
    unknown = _UNKNOWN.match(text)
    if unknown:
        name = unknown.group("name")
        allowed = struct_fields(_type_at(type_, steps))
        expected = f"one of the keys {', '.join(allowed)}" if allowed else "no such key"
        return ConfigError(file, join(key, name), expected, got=None, hint=did_you_mean(name, allowed))
    missing = _MISSING.match(text)
    if missing:
        return ConfigError(file, join(key, missing.group("name")), "a value (the key is required)")
    if text.startswith("Invalid enum value"):       # a Literal: name the allowed values
        allowed = _literal_values(_type_at(type_, steps))
        if allowed:
            return ConfigError(file, key or "(top level)", f"one of {', '.join(map(str, allowed))}",
                               got=value if found else None, hint=did_you_mean(value, allowed))
    expected = _EXPECTED.match(text)
    if expected:
        what = re.sub(r"`(\w+)`", lambda m: _WORDS.get(m.group(1), m.group(1)), expected.group("expected"))
        what = what.replace("`", "")
        if expected.group("count") is not None:
            what += f" (not {expected.group('count')})"
        if expected.group("got") is not None and not found:
            return ConfigError(file, key or "(top level)", what, got=expected.group("got"))
        return ConfigError(file, key or "(top level)", what, got=value if found else None)
    return ConfigError(file, key or "(top level)", text.replace("`", ""), got=value if found else None)


def _follow(data, steps):
    for step in steps:
        try:
            data = data[step]
        except (KeyError, IndexError, TypeError):
            return None, False
    return data, True


def _literal_values(type_) -> tuple:
    """The values of a Literal annotation (through Optional, Annotated), else ()."""
    origin = typing.get_origin(type_)
    if origin is typing.Literal:
        return typing.get_args(type_)
    if origin is typing.Annotated or origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        return tuple(v for arg in typing.get_args(type_) for v in _literal_values(arg))
    return ()


def _struct(type_):
    """The Struct class inside an annotation (through Optional, Annotated), else None."""
    origin = typing.get_origin(type_)
    if origin is typing.Annotated:
        return _struct(typing.get_args(type_)[0])
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        for arg in typing.get_args(type_):
            found = _struct(arg)
            if found is not None:
                return found
        return None
    if isinstance(type_, type) and issubclass(type_, msgspec.Struct):
        return type_
    return None


def _type_at(type_, steps):
    """The annotation reached from `type_` by following `steps` (field names and indices)."""
    for step in steps:
        origin = typing.get_origin(type_)
        if origin is typing.Annotated:
            type_ = typing.get_args(type_)[0]
            origin = typing.get_origin(type_)
        if isinstance(step, int):
            args = typing.get_args(type_)
            type_ = args[0] if args else Any
            continue
        struct = _struct(type_)
        if struct is not None:
            hints = typing.get_type_hints(struct, include_extras=True)
            by_name = {f.encode_name: f.name for f in msgspec.inspect.type_info(struct).fields}
            type_ = hints.get(by_name.get(step, step), Any)
        elif origin is dict:
            args = typing.get_args(type_)
            type_ = args[1] if len(args) == 2 else Any
        else:
            return Any
    return type_

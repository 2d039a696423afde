"""One schema layer for every file a user writes: YAML read with whole syntax errors, then
converted to declared types (msgspec Structs) with one error naming file, key path, expected and got.

Declare a file's shape once as `msgspec.Struct` classes (`forbid_unknown_fields=True` so a typo is
caught; `Finite`, `Positive`, `NonNegative`, `Fraction` or `Annotated[..., msgspec.Meta(...)]` for
ranges, with `description=` saying what a valid value is in the user's words; defaults on the
fields, the one place they live) and call `load(path, Type)` or `convert(data, Type, file)`.
Every mistake is a `ConfigError(file, "objects[0].size", expected, got)`; an unknown key, a
Literal value or a tag suggests the nearest declared one (`did you mean 'position'?`); a YAML
syntax error names line and column and the whole problem. Checks no type can express (a unit
quaternion, two keys that must agree) raise `Invalid` from the Struct's `__post_init__` (the error
gets the Struct's key path) or call `fail(...)` after conversion.

(msgspec 0.22: a constrained int inside a union, `Annotated[int, Meta(ge=2)] | tuple[...]`, crashes
the garbage collector; constrain the union as a whole or check in `__post_init__`.)
"""
from __future__ import annotations

import difflib
import re
import sys
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import numpy as np
import yaml

from touch4d.errors import ConfigError, Touch4dError

T = TypeVar("T")

# Numbers as files mean them: finite (YAML's .nan and .inf are refused where a size or a position is
# expected), with the usual ranges. The bound FINITE_MAX is shown as "finite" in errors.
FINITE_MAX = sys.float_info.max
Finite = Annotated[float, msgspec.Meta(ge=-FINITE_MAX, le=FINITE_MAX, description="a finite number")]
Positive = Annotated[float, msgspec.Meta(gt=0, le=FINITE_MAX, description="a finite number > 0")]
NonNegative = Annotated[float, msgspec.Meta(ge=0, le=FINITE_MAX, description="a finite number >= 0")]
Fraction = Annotated[float, msgspec.Meta(ge=0, le=1, description="a number in 0..1")]

_ENUM = re.compile(r"^Invalid (?:enum )?value (?P<got>.+)$")
_AT = re.compile(r" - at `\$(?P<path>[^`]*)`$")
_AT_KEY = re.compile(r" - at `key` in `\$(?P<path>[^`]*)`$")
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
    data = plain(data)
    try:
        return msgspec.convert(data, type_, strict=True)
    except msgspec.ValidationError as exc:
        raise error_of(exc, data, type_, file, key) from None


def plain(value, _memo: dict | None = None) -> Any:
    """`value` with numpy scalars and arrays (which a caller may pass for numbers and lists) as the
    Python numbers and lists a YAML file gives. Shared parts (YAML aliases) are converted once, so
    an alias bomb (9^9 items once expanded) costs what its text costs."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    if not isinstance(value, (dict, list, tuple)):
        return value
    memo = {} if _memo is None else _memo
    if id(value) not in memo:
        if isinstance(value, dict):
            memo[id(value)] = {k: plain(v, memo) for k, v in value.items()}
        else:
            memo[id(value)] = [plain(v, memo) for v in value]
    return memo[id(value)]


class Invalid(Touch4dError, ValueError):
    """Raised by a Struct's `__post_init__` for a check no type expresses (a unit quaternion, two
    keys that must agree): `convert` turns it into a ConfigError at the Struct's key path extended
    by `key`. `choices` adds a did-you-mean for `got`."""

    def __init__(self, expected: str, got=None, key: str = "", *, hint: str | None = None, choices=None):
        super().__init__(expected)
        self.expected, self.got, self.key = expected, got, key
        self.hint = hint if hint is not None else (did_you_mean(got, choices) if choices else None)


def error_of(exc: msgspec.ValidationError, data, type_, file=None, key: str = "") -> ConfigError:
    """The ConfigError for msgspec's ValidationError `exc` raised converting (or decoding) `data` to
    `type_`: key path, expected and got in the words of a YAML or JSON file."""
    text = str(exc)
    cause = exc.__cause__
    if isinstance(cause, Invalid):
        at = _AT.search(text)
        where = _walk(data, type_, at.group("path") if at else "", key)[0]
        if cause.key:
            where = join(where, cause.key)
        return ConfigError(file, where or "(top level)", cause.expected, got=cause.got, hint=cause.hint)
    if isinstance(cause, ConfigError):
        return cause
    return _config_error(text, data, type_, file, key)


def fail(file, key: str, expected: str, got=None, choices=None) -> typing.NoReturn:
    """Raise the ConfigError of a check no type expresses; `choices` adds a did-you-mean for `got`."""
    raise ConfigError(file, key, expected, got=got, hint=did_you_mean(got, choices) if choices else None)


def to_builtins(value) -> Any:
    """A Struct (or anything holding Structs) as plain dicts and lists."""
    return msgspec.to_builtins(value)


def did_you_mean(word, choices) -> str | None:
    """`did you mean 'x'?` for the nearest of `choices` to `word`, or None."""
    if not isinstance(word, str):
        return None
    names = [str(c) for c in choices]
    near = difflib.get_close_matches(word, names, n=1, cutoff=0.6)
    if not near:                     # a short name with two letters swapped (di -> id)
        near = [n for n in names if sorted(n) == sorted(word) and n != word][:1]
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


# ---- msgspec's error text -> ConfigError ------------------------------------------------------------


def _config_error(text: str, data, type_, file, prefix: str) -> ConfigError:
    path = ""
    at_key = _AT_KEY.search(text)
    at = at_key or _AT.search(text)
    if at:
        path = at.group("path")
        text = text[: at.start()]
    key, value, found, type_ = _walk(data, type_, path, prefix)
    if at_key:                              # a mapping's key that is not a name
        bad = next((k for k in value if not isinstance(k, str)), None) if found and isinstance(value, dict) else None
        return ConfigError(file, join(key, str(bad)) if bad is not None else key or "(top level)",
                           "a key that is a name (text)", got=bad)
    if _strip_optional(type_) is not type_ and found and value is not None and not at_key:
        try:                                # Optional[X] given a value: say what X says (not "or null")
            msgspec.convert(value, _strip_optional(type_), strict=True)
        except msgspec.ValidationError as inner:
            if inner.__cause__ is None and not _AT.search(str(inner)):
                return _config_error(str(inner), value, _strip_optional(type_), file, key)
    described = _description(type_)
    unknown = _UNKNOWN.match(text)
    if unknown:
        name = unknown.group("name")
        allowed = _keys(type_, value if found else None)
        expected = f"one of the keys {', '.join(allowed)}" if allowed else "no such key"
        return ConfigError(file, join(key, name), expected, got=None, hint=did_you_mean(name, allowed))
    missing = _MISSING.match(text)
    if missing:
        name = missing.group("name")
        if found and isinstance(value, dict):   # a required key misspelt: name the misspelling
            allowed = _keys(type_, value)
            for given in value:
                if isinstance(given, str) and given not in allowed and did_you_mean(given, [name]):
                    return ConfigError(file, join(key, given), f"one of the keys {', '.join(allowed)}",
                                       hint=did_you_mean(given, [name]))
        field = _walk({}, type_, f".{name}", "")[3]
        choices = _choices(field)
        what = _description(field) or _fixed_tuple(field) or (f"one of {', '.join(map(str, choices))}" if choices
                                                              else "a value")
        return ConfigError(file, join(key, name), f"{what} (the key is required)")
    enum = _ENUM.match(text)
    if enum:
        choices = _choices(type_)
        got = value if found else enum.group("got")
        if described:
            return ConfigError(file, key or "(top level)", described, got=got, hint=did_you_mean(got, choices))
        what = f"one of {', '.join(map(str, choices))}" if choices else "one of the allowed values"
        return ConfigError(file, key or "(top level)", what, got=got, hint=did_you_mean(got, choices))
    if text == "Number out of range":
        return ConfigError(file, key or "(top level)", "a finite number", got=value if found else None)
    expected = _EXPECTED.match(text)
    if described:
        return ConfigError(file, key or "(top level)", described, got=value if found else None)
    if expected and _fixed_tuple(type_) and "length" in text:
        return ConfigError(file, key or "(top level)", _fixed_tuple(type_), got=value if found else None)
    if expected:
        what = _finite_words(expected.group("expected"))
        what = re.sub(r"`([\w |]+)`", lambda m: " | ".join(_WORDS.get(w, w) for w in m.group(1).split(" | ")), what)
        what = re.sub(r"(\d)\.0\b", r"\1", what.replace("`", "")).replace(" | ", " or ")
        if expected.group("count") is not None:
            what += f" (not {expected.group('count')})"
        if expected.group("got") is not None and not found:
            return ConfigError(file, key or "(top level)", what, got=expected.group("got"))
        return ConfigError(file, key or "(top level)", what, got=value if found else None)
    return ConfigError(file, key or "(top level)", text.replace("`", ""), got=value if found else None)


def _finite_words(text: str) -> str:
    """msgspec's `float` >= -1.79e308 (the bound of Finite) as "a finite number"."""
    bound = repr(FINITE_MAX)
    if bound not in text:
        return text
    text = re.sub(rf"\s*(?:and\s*)?[<>]=\s*-?{re.escape(bound)}", "", text)
    text = re.sub(r"`float`,?", "a finite number", text, count=1)
    return text.replace(" ,", ",").strip()


def _strip_optional(type_):
    """`X` for `X | None`, else `type_`."""
    origin = typing.get_origin(type_)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        members = [a for a in typing.get_args(type_) if a is not type(None)]
        if len(members) == 1:
            return members[0]
    return type_


def _description(type_) -> str | None:
    """The `msgspec.Meta(description=...)` of an annotation: what a valid value is, in a user's words."""
    if _strip_optional(type_) is not type_:
        return _description(_strip_optional(type_))
    if typing.get_origin(type_) is typing.Annotated:
        for meta in typing.get_args(type_)[1:]:
            if isinstance(meta, msgspec.Meta) and meta.description:
                return meta.description
        return _description(typing.get_args(type_)[0])
    return None


def _fixed_tuple(type_) -> str | None:
    """"a list of 4 numbers" for tuple[float, float, float, float] (through Annotated), else None."""
    type_ = _bare(type_)
    args = typing.get_args(type_)
    if typing.get_origin(type_) is not tuple or not args or args[-1] is Ellipsis:
        return None
    kinds = {_bare(a) for a in args}
    if kinds <= {float, int}:
        return f"a list of {len(args)} numbers"
    names = ", ".join(_WORDS.get({float: "float", int: "int", str: "str", bool: "bool"}.get(_bare(a), ""), "a value")
                      for a in args)
    return f"a list of {len(args)}: {names}"


def _choices(type_) -> tuple:
    """The values of a Literal annotation (through Annotated and Optional), else ()."""
    origin = typing.get_origin(type_)
    if origin is typing.Literal:
        return typing.get_args(type_)
    if origin is typing.Annotated or origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        for arg in typing.get_args(type_):
            found = _choices(arg)
            if found:
                return found
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


def _walk(data, type_, path: str, key: str):
    """Follow msgspec's error path (`.name`, `[3]`, `[...]` for a mapping's key, which msgspec does
    not name) through `data` and `type_` together: (key as shown, value there, whether the value was
    found, annotation there)."""
    found = True
    for name, index in re.findall(r"\.([^.\[\]]+)|\[(\d+|\.\.\.)\]", path):
        type_ = _bare(type_)
        if index == "...":                  # the first entry of the mapping whose value does not convert
            args = typing.get_args(type_)
            inner = args[1] if len(args) == 2 else Any
            bad = None
            if found and isinstance(data, dict):
                for k, v in data.items():
                    try:
                        msgspec.convert(v, inner, strict=True)
                    except msgspec.ValidationError:
                        bad = k
                        break
            if bad is None:                 # a key of the wrong kind
                keys = args[0] if len(args) == 2 else Any
                for k in data if found and isinstance(data, dict) else ():
                    try:
                        msgspec.convert(k, keys, strict=True)
                    except msgspec.ValidationError:
                        return join(key, str(k)), k, True, keys
                return join(key, "[...]"), None, False, inner
            key, data, type_ = join(key, str(bad)), data[bad], inner
            continue
        if index:
            step = int(index)
            args = typing.get_args(type_)
            type_ = (args[step] if step < len(args) and args[-1] is not Ellipsis and typing.get_origin(type_) is tuple
                     else args[0] if args else Any)
            key = join(key, f"[{step}]")
        else:
            step = name
            struct = _struct(type_)
            tagged = _tagged(type_)
            if tagged:                      # a union told apart by a tag field (kind: sweep)
                tag_field = tagged[0].__struct_config__.tag_field
                if step == tag_field:
                    type_ = Literal[tuple(m.__struct_config__.tag for m in tagged)]
                    struct = None
                else:
                    tag = data.get(tag_field) if found and isinstance(data, dict) else None
                    struct = next((m for m in tagged if m.__struct_config__.tag == tag), tagged[0])
            if struct is not None:
                hints = typing.get_type_hints(struct, include_extras=True)
                by_name = {f.encode_name: f.name for f in msgspec.inspect.type_info(struct).fields}
                type_ = hints.get(by_name.get(step, step), Any)
            elif not (tagged and step == tag_field):
                type_ = Any
            key = join(key, step)
        if found:
            try:
                data = data[step]
            except (KeyError, IndexError, TypeError):
                data, found = None, False
    return key, data, found, type_


def _keys(type_, value) -> tuple[str, ...]:
    """The keys a mapping of `type_` may hold: a Struct's fields; for a tagged union, the tag field
    and the fields of the member `value` names (else of the first)."""
    tagged = _tagged(type_)
    if not tagged:
        return struct_fields(type_)
    tag_field = tagged[0].__struct_config__.tag_field
    tag = value.get(tag_field) if isinstance(value, dict) else None
    member = next((m for m in tagged if m.__struct_config__.tag == tag), tagged[0])
    return (tag_field, *struct_fields(member))


def _tagged(type_) -> list:
    """The members of a union of tagged Structs (`tag_field=`), else []."""
    type_ = _bare(type_)
    origin = typing.get_origin(type_)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        members = [a for a in typing.get_args(type_) if isinstance(a, type) and issubclass(a, msgspec.Struct)]
        if members and all(m.__struct_config__.tag_field for m in members):
            return members
    return []


def _bare(type_):
    """`type_` without Annotated, and the non-None member of an Optional."""
    while True:
        origin = typing.get_origin(type_)
        if origin is typing.Annotated:
            type_ = typing.get_args(type_)[0]
        elif origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
            members = [a for a in typing.get_args(type_) if a is not type(None)]
            if len(members) != 1:
                return type_
            type_ = members[0]
        else:
            return type_

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
import functools
import math
import re
import sys
import types
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


def read_text(path, what: str = "file") -> str:
    """The text of `path`; an unreadable file is a ConfigError naming it."""
    path = Path(path)
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise ConfigError(path, "(file)", f"a readable {what} (UTF-8 text)", got=str(exc)) from None
    except OSError as exc:
        raise ConfigError(path, "(file)", f"a readable {what}", got=exc.strerror or str(exc)) from None


# libyaml's loader where PyYAML was built with it (ten times the pure-Python one's speed: a served
# study parses each trial's scene), the same safe subset of YAML
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def parse_yaml(text: str, file=None) -> Any:
    """`text` parsed as YAML; a syntax error is a ConfigError with line, column and the whole problem."""
    try:
        return yaml.load(text, Loader=SAFE_LOADER)
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
    found = _mismatch(data, type_, file, key)
    if found is not None:
        return found
    cause = exc.__cause__                   # every part converts (`data` is not what msgspec was given)
    if isinstance(cause, ConfigError):
        return cause
    return ConfigError(file, key or "(top level)", "a valid value", detail=str(cause or exc))


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


def join(key: str, part) -> str:
    """`key` extended by `part` (a field name or `[3]`), as keys are shown in errors; a YAML key that
    is not text (`1:`, or a bare `?`, null) is shown as Python writes it."""
    part = str(part)
    if not key:
        return part.lstrip(".")
    return key + part if part.startswith("[") else f"{key}.{part}"


def struct_fields(type_) -> tuple[str, ...]:
    """The field names (as written in files) of a Struct type, else ()."""
    info = _struct(type_)
    return tuple(f.encode_name for f in msgspec.inspect.type_info(info).fields) if info else ()


# ---- what is wrong, found from the declared type ----------------------------------------------------


def _mismatch(value, type_, file, key: str) -> ConfigError | None:
    """The ConfigError for the first place where `value` does not convert to `type_` (an error named
    at `key` or below it), found by walking the value and the annotation together and converting
    each part on its own; None if it converts. msgspec's words are never read: only whether a part
    converts, and the declared type says what was expected."""
    try:
        msgspec.convert(value, type_, strict=True)
        return None
    except msgspec.ValidationError as exc:
        own = exc.__cause__                 # a Struct's own check (__post_init__), once its fields convert
    bare = _bare(type_)
    tagged = _tagged(type_)
    if value is not None and _strip_optional(type_) is not type_ and not tagged:
        return _mismatch(value, _strip_optional(type_), file, key)   # Optional[X] given a value: what X says
    if typing.get_origin(bare) in (typing.Union, types.UnionType) and not tagged:
        members = [a for a in typing.get_args(bare) if _is_kind(value, _bare(a))]
        if len(members) == 1:               # the one member of the value's kind (a list: the list's) says what
            return _mismatch(value, members[0], file, key)
    struct = _struct(bare) if not tagged else None
    if (tagged or struct is not None) and isinstance(value, dict):
        bad = next((k for k in value if not isinstance(k, str)), None)
        if bad is not None:
            return ConfigError(file, join(key, str(bad)), "a key that is a name (text)", got=bad)
        if tagged:
            tag_field = tagged[0].__struct_config__.tag_field
            tags = [m.__struct_config__.tag for m in tagged]
            if tag_field not in value:
                return ConfigError(file, join(key, tag_field), f"{_expected(Literal[tuple(tags)], None)} "
                                   "(the key is required)")
            if value[tag_field] not in tags:
                return _leaf(value[tag_field], Literal[tuple(tags)], file, join(key, tag_field))
            struct = next(m for m in tagged if m.__struct_config__.tag == value[tag_field])
        return _struct_mismatch(value, struct, own, file, key, tagged)
    origin, args = typing.get_origin(bare), typing.get_args(bare)
    if origin in (list, tuple, set, frozenset) and isinstance(value, list):
        fixed = origin is tuple and args and args[-1] is not Ellipsis
        if fixed and len(value) != len(args):
            return ConfigError(file, key or "(top level)", _expected(type_, value), got=value)
        for i, item in enumerate(value):
            found = _mismatch(item, args[i] if fixed else args[0] if args else Any, file, join(key, f"[{i}]"))
            if found is not None:
                return found
    elif origin is dict and isinstance(value, dict):
        keys, values = args if len(args) == 2 else (Any, Any)
        for k, v in value.items():
            if _mismatch(k, keys, file, key) is not None:
                return ConfigError(file, join(key, str(k)), "a key that is a name (text)" if keys is str
                                   else _expected(keys, k), got=k)
        for k, v in value.items():
            found = _mismatch(v, values, file, join(key, str(k)))
            if found is not None:
                return found
    return _leaf(value, type_, file, key)


def _struct_mismatch(value: dict, struct, own, file, key: str, tagged) -> ConfigError:
    """The first unknown key, missing key or field that does not convert of a mapping for `struct`;
    else the Struct's own check (`own`, raised by its __post_init__) at `key`."""
    allowed = (tagged[0].__struct_config__.tag_field, *struct_fields(struct)) if tagged else struct_fields(struct)
    cls = typing.get_origin(struct) or struct           # a generic Struct's class (`Study[X]`: Study)
    if cls.__struct_config__.forbid_unknown_fields:
        for name in value:
            if name not in allowed:
                return _unknown_key(value, name, allowed, struct, tagged, file, key)
    hints = _hints(struct)
    info = msgspec.inspect.type_info(struct).fields
    for f in info:
        if f.required and f.encode_name not in value:
            for given in value:              # a required key misspelt: name the misspelling
                if given not in allowed and did_you_mean(given, [f.encode_name]):
                    return ConfigError(file, join(key, given), f"one of the keys {', '.join(allowed)}",
                                       hint=did_you_mean(given, [f.encode_name]))
            field = hints.get(f.name, Any)
            choices = _choices(field)
            what = _description(field) or _fixed_tuple(field) or (f"one of {', '.join(map(str, choices))}" if choices
                                                                  else "a value")
            return ConfigError(file, join(key, f.encode_name), f"{what} (the key is required)")
    by_name = {f.encode_name: f.name for f in info}
    for name, item in value.items():
        if name in by_name:
            found = _mismatch(item, hints.get(by_name[name], Any), file, join(key, name))
            if found is not None:
                return found
    if isinstance(own, Invalid):
        return ConfigError(file, join(key, own.key) if own.key else key or "(top level)", own.expected,
                           got=own.got, hint=own.hint)
    if isinstance(own, ConfigError):
        return own
    return ConfigError(file, key or "(top level)", "a valid value", got=value,
                       detail=str(own) if own is not None else None)


def _unknown_key(value: dict, name, allowed, struct, tagged, file, key: str) -> ConfigError:
    """The ConfigError of a key `struct` does not declare; in a tagged union (`kind: tilt`) it says which
    tag the mapping has, and which others take the key if some do (`scene` is a key of kind tilt)."""
    if not tagged:
        return ConfigError(file, join(key, name), f"one of the keys {', '.join(allowed)}" if allowed
                           else "no such key", hint=did_you_mean(name, allowed))
    tag_field, tag = struct.__struct_config__.tag_field, struct.__struct_config__.tag
    others = [m.__struct_config__.tag for m in tagged if m is not struct and name in struct_fields(m)]
    if others:
        return ConfigError(file, join(key, name), f"no {name} for {tag_field} {tag} ({name} is a key of "
                           f"{tag_field} {' and '.join(map(str, others))})", got=value[name])
    return ConfigError(file, join(key, name), f"one of the keys of {tag_field} {tag}: {', '.join(allowed)}",
                       hint=did_you_mean(name, allowed))


def _hints(struct) -> dict:
    """The field annotations of a Struct class; of a generic one given its parameters (`Study[X]`), with
    each type variable replaced by its argument."""
    cls = typing.get_origin(struct) or struct
    hints = typing.get_type_hints(cls, include_extras=True)
    given = dict(zip(getattr(cls, "__parameters__", ()), typing.get_args(struct)))
    if not given:
        return hints
    return {name: given.get(hint, hint) if isinstance(hint, typing.TypeVar)
            else hint[tuple(given[p] for p in hint.__parameters__)] if getattr(hint, "__parameters__", ()) else hint
            for name, hint in hints.items()}


def _leaf(value, type_, file, key: str) -> ConfigError:
    """The ConfigError for `value` that is not a `type_` at `key`, in the words of a YAML file."""
    choices = _choices(type_)
    hint = did_you_mean(value, choices) if choices else None
    return ConfigError(file, key or "(top level)", _expected(type_, value), got=value, hint=hint)


_KINDS = {float: "a number", int: "an integer", str: "a string", bool: "true or false", list: "a list",
          tuple: "a list", set: "a list", frozenset: "a list", dict: "a mapping", type(None): "nothing (null)"}
_BOUNDS = (("ge", ">=", lambda v, b: v >= b), ("gt", ">", lambda v, b: v > b), ("le", "<=", lambda v, b: v <= b),
           ("lt", "<", lambda v, b: v < b))


def _expected(type_, value) -> str:
    """What a value of `type_` is, in a user's words: the description its Meta gives, else its choices,
    its kind and the constraint `value` breaks ("a number > 0", "a list of length >= 1")."""
    described = _description(type_)
    if described:
        return described
    choices = _choices(type_)
    if choices:
        return f"one of {', '.join(map(str, choices))}"
    fixed = _fixed_tuple(type_)
    if fixed:
        return fixed
    bare = _bare(type_)
    origin = typing.get_origin(bare)
    if origin is typing.Union or origin is types.UnionType:
        return " or ".join(dict.fromkeys(_expected(a, value) for a in typing.get_args(bare)))
    kind = _KINDS.get(origin or bare) or ("a mapping" if _struct(bare) is not None else "a value")
    numeric = bare in (int, float)
    if not _is_kind(value, bare):
        return kind
    rule = _constraints(type_)
    for name, op, holds in _BOUNDS:
        bound = getattr(rule, name, None)
        if bound is None or not numeric:
            continue
        if abs(bound) == FINITE_MAX:         # the bound of Finite: what it means, not its digits
            if not math.isfinite(value):
                return "a finite number" if bare is float else kind
            continue
        if not holds(value, bound):
            return f"{kind} {op} {_number(bound)}"
    multiple_of, pattern = getattr(rule, "multiple_of", None), getattr(rule, "pattern", None)
    min_length, max_length = getattr(rule, "min_length", None), getattr(rule, "max_length", None)
    if numeric and multiple_of is not None and value % multiple_of:
        return f"{kind} that's a multiple of {_number(multiple_of)}"
    n = len(value) if isinstance(value, (str, list, dict)) else None
    if n is not None and min_length is not None and n < min_length:
        return f"{kind} of length >= {min_length}"
    if n is not None and max_length is not None and n > max_length:
        return f"{kind} of length <= {max_length}"
    if isinstance(value, str) and pattern is not None and not re.search(pattern, value):
        return f"{kind} matching regex '{pattern}'"
    if isinstance(value, int) and not isinstance(value, bool) and numeric:
        return "a finite number"             # an integer too large for the machine's numbers
    return kind


def _is_kind(value, bare) -> bool:
    """Whether `value` is of the plain kind `bare` as msgspec converts strictly (an int is a number)."""
    if bare is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if bare is int:
        return isinstance(value, int) and not isinstance(value, bool)
    origin = typing.get_origin(bare) or bare
    if origin in (list, tuple, set, frozenset):
        return isinstance(value, list)
    if origin is dict or _struct(bare) is not None:
        return isinstance(value, dict)
    return isinstance(origin, type) and isinstance(value, origin)


@functools.lru_cache(maxsize=512)
def _inspected(type_):
    """msgspec's own reading of an annotation (msgspec.inspect.type_info): the constraints and description
    of nested Annotated merged into one node, as msgspec applies them."""
    return msgspec.inspect.type_info(type_)


def _info(type_):
    """`_inspected(type_)`, also for an annotation that cannot be a cache key; None for one msgspec cannot
    read (no file's value is declared so)."""
    try:
        return _inspected(type_)
    except TypeError:                        # unhashable (a Meta holding a list): read afresh
        try:
            return msgspec.inspect.type_info(type_)
        except TypeError:
            return None


def _constraints(type_):
    """The node of msgspec.inspect that holds what a value of `type_` (through Optional) must meet: its
    bounds (gt, ge, lt, le, multiple_of), lengths (min_length, max_length) and pattern, those it has."""
    node = _info(_strip_optional(type_))
    return node.type if isinstance(node, msgspec.inspect.Metadata) else node


def _number(x) -> str:
    """A bound as a file would write it: 0 for 0.0, 0.5 for 0.5."""
    return re.sub(r"(\d)\.0\b", r"\1", repr(x))


def _strip_optional(type_):
    """`X` for `X | None`, else `type_`."""
    origin = typing.get_origin(type_)
    if origin is typing.Union or origin is types.UnionType:
        members = [a for a in typing.get_args(type_) if a is not type(None)]
        if len(members) == 1:
            return members[0]
    return type_


def _description(type_) -> str | None:
    """The `msgspec.Meta(description=...)` of an annotation (through Optional): what a valid value is, in a
    user's words."""
    node = _info(_strip_optional(type_))
    if isinstance(node, msgspec.inspect.Metadata):
        return (node.extra_json_schema or {}).get("description") or None
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
    names = ", ".join(_KINDS.get(_bare(a), "a value") for a in args)
    return f"a list of {len(args)}: {names}"


def _choices(type_) -> tuple:
    """The values of a Literal annotation (through Annotated and Optional), else (); in the order declared
    (msgspec.inspect sorts them), the order a user reads in the file's documentation."""
    origin = typing.get_origin(type_)
    if origin is typing.Literal:
        return typing.get_args(type_)
    if origin is typing.Annotated or origin is typing.Union or origin is types.UnionType:
        for arg in typing.get_args(type_):
            found = _choices(arg)
            if found:
                return found
    return ()


def _struct(type_):
    """The Struct class inside an annotation (through Optional, Annotated), else None."""
    return _find(_info(type_), lambda node: node.cls if isinstance(node, msgspec.inspect.StructType) else None)


def _find(node, pick):
    """The first thing `pick` finds in a msgspec.inspect node, looking through Metadata (Annotated) and
    into every member of a union, else what `pick` says of nothing (its falsy answer)."""
    if isinstance(node, msgspec.inspect.Metadata):
        return _find(node.type, pick)
    if isinstance(node, msgspec.inspect.UnionType):
        for member in node.types:
            found = _find(member, pick)
            if found:
                return found
    return pick(node)


def _tagged(type_) -> list:
    """The members of a union of tagged Structs (`tag_field=`), else []."""
    node = _info(_bare(type_))
    if isinstance(node, msgspec.inspect.UnionType):
        members = [t.cls for t in node.types if isinstance(t, msgspec.inspect.StructType)]
        if members and all(m.__struct_config__.tag_field for m in members):
            return members
    return []


def _bare(type_):
    """`type_` without Annotated, and the non-None member of an Optional."""
    while True:
        origin = typing.get_origin(type_)
        if origin is typing.Annotated:
            type_ = typing.get_args(type_)[0]
        elif origin is typing.Union or origin is types.UnionType:
            members = [a for a in typing.get_args(type_) if a is not type(None)]
            if len(members) != 1:
                return type_
            type_ = members[0]
        else:
            return type_

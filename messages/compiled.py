"""Per-class fast paths of the messages, generated from their field declarations.

Like `dataclasses` writes each class's `__init__`, this writes, once per message class, straight-line
code for the hot operations: coercing the fields of a new message, validating, encoding, publishing
(validate, fill the header and encode in one pass) and decoding. No loop over fields, no call per
field for the common kinds; decoding checks the plain fields in C, through a msgspec struct made from
the declarations (floats finite, strings among their choices, lists of strings, string keys), and
takes arrays as views into the payload (small fixed-shape ones, a pose's, as copies: quicker).

Each fast path accepts only what the reference code of base.py (the kinds' `check` and `coerce`,
`Message.from_dict`, `validate`, `to_dict` and `stamp_for_publish`) accepts unchanged; for anything
else (a value to coerce, a bad field, a subclass that overrides the reference) it declines and the
reference code runs. So behaviour and error texts are base.py's, whatever the speed.
"""
from __future__ import annotations

import itertools
import math
import sys
import time
from typing import Annotated, Any, Callable, Literal, NamedTuple

import msgspec
import numpy as np

from . import base
from .codec import NDARRAY_EXT, _array_prefix, _ext_hook, _header, array_parts, encode_plain, unpack


class FastPaths(NamedTuple):
    """One message class's generated code (see the module doc for what declining means)."""

    coerce: Callable        # coerce(msg): every field coerced, as __post_init__ must (raises MessageError)
    validate: Callable      # validate(msg) -> True, or False to run the reference validate
    encode: Callable        # encode(msg) -> payload bytes, or None to encode the reference way
    publish: Callable       # publish(msg, seq) -> payload of msg validated and stamped (see base.py's
                            #   `stamp_for_publish`; the header written once the payload is made), or
                            #   None (or raises) with the header untouched: the reference then runs
    from_dict: Callable     # from_dict(map without "type") -> message, or None (or raises) for the reference
    decode: Callable        # decode(payload) -> message of this class, or None (or raises) for the reference


_SMALL_ARRAY = 512   # bytes: a fixed-shape array up to this size is copied, not viewed (quicker)
_ANY_STR = itertools.repeat(str)   # map(isinstance, values, _ANY_STR): a C loop over the values
_FINITE = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]  # rejects NaN, inf


def _surely_finite(arr: np.ndarray) -> bool:
    """True only if every value is finite (a finite sum proves it); False may be a false alarm."""
    total = sum(arr.ravel().tolist()) if arr.size <= 64 else arr.sum()
    return total - total == 0


def _map_header(count: int) -> bytes:
    if count <= 15:
        return bytes((0x80 | count,))
    return b"\xde" + count.to_bytes(2, "big")


def _fixed_array(kind) -> tuple[np.dtype, tuple[int, ...]] | None:
    """(dtype, shape) of an Array kind whose every dimension is fixed; None otherwise."""
    if type(kind) is base.Array and all(isinstance(n, int) for n in kind.shape):
        return kind.dtype, tuple(kind.shape)
    return None


class _Source:
    """Generated code and the constants it names."""

    def __init__(self):
        self.names: dict[str, object] = {}

    def const(self, value) -> str:
        for name, known in self.names.items():
            if known is value:
                return name
        name = f"_c{len(self.names)}"
        self.names[name] = value
        return name


# -- per kind: expressions in `v`, true only when the reference returns `v` itself ------------------

def check_test(kind: base.Kind, src: _Source, shape_known: bool = False) -> str | None:
    """An expression true only for values `kind.check` returns unchanged; None: call `check`.
    `shape_known`: the value is already an array of the kind's dtype and shape (only finiteness left)."""
    k = type(kind)
    if k is base.Float:
        return "v.__class__ is float" + (" and v - v == 0.0" if kind.finite else "")
    if k is base.Int:
        return "v.__class__ is int"
    if k is base.Bool:
        return "v.__class__ is bool"
    if k is base.Str:
        if kind.choices is None:
            return "v.__class__ is str"
        return f"v.__class__ is str and v in {src.const(frozenset(kind.choices))}"
    if k is base.StrList:
        return f"v.__class__ is list and all(map(isinstance, v, {src.const(_ANY_STR)}))"
    if k is base.Map:
        return f"v.__class__ is dict and all(map(isinstance, v, {src.const(_ANY_STR)}))"
    if k is base.Array:
        if any(not isinstance(n, int) and n is not None for n in kind.shape):
            return None
        test = []
        if not shape_known:
            test = [f"v.__class__ is {src.const(np.ndarray)}", f"v.dtype.kind in {kind._kinds!r}"]
            if None in kind.shape:
                test += [f"len(v.shape) == {len(kind.shape)}"]
                test += [f"v.shape[{i}] == {n}" for i, n in enumerate(kind.shape) if n is not None]
            else:
                test += [f"v.shape == {src.const(tuple(kind.shape))}"]
        if kind._check_finite and len(kind.shape) == 1 and kind.shape[0] is not None and kind.shape[0] <= 16:
            test.append("(s := sum(v.tolist())) - s == 0.0")    # _surely_finite, inline
        elif kind._check_finite:
            test.append(f"{src.const(_surely_finite)}(v)")
        return " and ".join(test) or "True"
    return None


def coerce_test(kind: base.Kind, src: _Source) -> str | None:
    """'' when `kind.coerce` never changes a value; an expression true only when it returns `v`
    itself; None: always call `coerce` (the list and map kinds copy their value)."""
    k = type(kind)
    if k.coerce is base.Kind.coerce:
        return ""
    if k is base.Float:
        return "v.__class__ is float"
    if k is base.Int:
        return "v.__class__ is int"
    if k is base.Array:
        dtype = kind.dtype
        same = f"v.dtype.kind == {dtype.kind!r}" if dtype.kind in "fiu" else f"v.dtype == {src.const(dtype)}"
        return f"v.__class__ is {src.const(np.ndarray)} and {same}"
    return None


def wire_type(kind: base.Kind):
    """The msgspec type that checks a field of this kind while decoding, in C (Any: left to `check`).

    Each accepts exactly what `kind.check` accepts and returns unchanged, or converts as it does
    (an integer for a Float); arrays stay raw (msgspec.Raw, a view into the payload)."""
    k = type(kind)
    if k is base.Float:
        return _FINITE if kind.finite else float
    if k is base.Int:
        return int
    if k is base.Bool:
        return bool
    if k is base.Str:
        return str if kind.choices is None else Literal[tuple(kind.choices)] if kind.choices else Any
    if k is base.StrList:
        return list[str]
    if k is base.IntList:
        return list[int]
    if k is base.Map:
        return dict[str, Any]
    if k is base.Array:
        return msgspec.Raw
    return Any


# -- the generated functions --------------------------------------------------------------------------

def _coerce_field(cls, name: str, kind: base.Kind, value):
    try:
        return kind.coerce(value)
    except (TypeError, ValueError) as exc:
        raise base.MessageError(f"{cls.TYPE}.{name}: {exc}") from None


def _gen_coerce(cls, fields, src: _Source) -> list[str]:
    lines = ["def coerce(msg):", "    d = msg.__dict__"]
    slow = src.const(_coerce_field)
    klass = src.const(cls)
    for f in fields:
        kind = f.metadata["kind"]
        test = coerce_test(kind, src)
        if test == "":
            continue
        call = f"d[{f.name!r}] = {slow}({klass}, {f.name!r}, {src.const(kind)}, v)"
        lines.append(f"    v = d[{f.name!r}]")
        lines.append(f"    if not ({test}): {call}" if test is not None else f"    {call}")
    return lines


def _gen_checks(fields, src: _Source, fail: str, store: bool) -> list[str]:
    """Each field of `d` checked: inline where the kind has a test (`fail` when it is false), else
    by its `check` (raising), whose result is stored back when `store`."""
    lines = []
    for f in fields:
        kind = f.metadata["kind"]
        test = check_test(kind, src)
        lines.append(f"    v = d[{f.name!r}]")
        if test is not None:
            lines.append(f"    if not ({test}): {fail}")
        else:
            lines.append(f"    {f'd[{f.name!r}] = ' if store else ''}{src.const(kind.check)}(v)")
    return lines


def _gen_validate(fields, src: _Source) -> list[str]:
    return (["def validate(msg):", "    d = msg.__dict__"] + _gen_checks(fields, src, "return False", store=False)
            + ["    msg.check()", "    return True"])


def _gen_from_dict(cls, fields, src: _Source) -> list[str]:
    absent = [f"    if {f.name!r} not in d: d[{f.name!r}] = {src.const(f.metadata['kind'].default)}()"
              for f in fields if f.metadata.get("optional")]   # an optional field left out: its default
    return (["def from_dict(d):"] + absent + [f"    if len(d) != {len(fields)}: return None"]
            + _gen_checks(fields, src, "return None", store=True)
            + [f"    msg = {src.const(object.__new__)}({src.const(cls)})", "    msg.__dict__ = d",
               "    msg.check()", "    return msg"])


def _small_fixed(kind) -> tuple[np.dtype, tuple[int, ...]] | None:
    """(dtype, shape) of a fixed array kind of at most _SMALL_ARRAY bytes (copied, not viewed)."""
    fixed = _fixed_array(kind)
    return fixed if fixed is not None and math.prod(fixed[1]) * fixed[0].itemsize <= _SMALL_ARRAY else None


def _gen_decode(cls, fields, src: _Source) -> list[str]:
    """msgspec decodes the payload into a struct made from the declarations, checking the plain
    fields; arrays (raw) become views into the payload, small fixed ones arrays over their own copy
    (msgspec's Ext: quicker than a view's checks); the other kinds run their `check`."""
    def typ(kind):
        return msgspec.msgpack.Ext if _small_fixed(kind) else wire_type(kind)

    wire = msgspec.defstruct(
        f"{cls.__name__}Wire",
        [(f.name, typ(f.metadata["kind"]), f.metadata["kind"].default()) if f.metadata.get("optional")
         else (f.name, typ(f.metadata["kind"])) for f in fields],
        tag_field="type", tag=cls.TYPE, forbid_unknown_fields=True, kw_only=True)
    decoder = msgspec.msgpack.Decoder(wire, ext_hook=_ext_hook)
    as_dict, wire_decode = src.const(msgspec.structs.asdict), src.const(decoder.decode)
    lines = ["def decode(payload):", f"    d = {as_dict}({wire_decode}(payload))"]
    for f in fields:
        kind = f.metadata["kind"]
        fixed = _fixed_array(kind)
        if typ(kind) is msgspec.msgpack.Ext:   # the usual dtype and shape: known from the ext's start
            header = _header(fixed[0].str, fixed[1])
            size = len(header) + math.prod(fixed[1]) * fixed[0].itemsize
            lines.append(f"    v = d[{f.name!r}]")
            lines.append(f"    if v.code == {NDARRAY_EXT} and len(b := v.data) == {size} "
                         f"and b.startswith({src.const(header)}):")
            lines.append(f"        v = {src.const(np.frombuffer)}(b, {src.const(fixed[0])}, "
                         f"{math.prod(fixed[1])}, {len(header)})")
            if len(fixed[1]) != 1:
                lines.append(f"        v = v.reshape({src.const(fixed[1])})")
            lines.append(f"        if not ({check_test(kind, src, shape_known=True)}): return None")
            lines.append("    else:")
            lines.append(f"        v = {src.const(_ext_hook)}(v.code, {src.const(memoryview)}(v.data))")
            lines.append(f"        if not ({check_test(kind, src)}): return None")
            lines.append(f"    d[{f.name!r}] = v")
        elif typ(kind) is msgspec.Raw:
            lines.append(f"    v = {src.const(unpack)}(d[{f.name!r}])")
            lines.append(f"    if not ({check_test(kind, src)}): return None")
            lines.append(f"    d[{f.name!r}] = v")
        elif typ(kind) is Any:
            lines.append(f"    d[{f.name!r}] = {src.const(kind.check)}(d[{f.name!r}])")
    lines += [f"    msg = {src.const(object.__new__)}({src.const(cls)})", "    msg.__dict__ = d",
              "    msg.check()", "    return msg"]
    return lines


def _array_lines(i: int, f, src: _Source) -> list[str]:
    """Lines that set `p{i}, r{i}` (ext prefix, bytes) of array field `f`, or `return None` for a
    value that is no array."""
    kind = f.metadata["kind"]
    nd = src.const(np.ndarray)
    lines = [f"    a{i} = d[{f.name!r}]"]
    fixed = _fixed_array(kind)
    if fixed is not None:   # the usual dtype and shape: a constant prefix
        # A small array's bytes are copied (tobytes: C order, whatever the strides); a larger one's
        # memory goes into the payload as it is (a view), which must then be C-contiguous.
        small = _small_fixed(kind) is not None
        test = (f"a{i}.__class__ is {nd} and a{i}.dtype is {src.const(fixed[0])} and "
                f"a{i}.shape == {src.const(fixed[1])}" + ("" if small else f" and a{i}.flags.c_contiguous"))
        lines.append(f"    if {test}:")
        data = "tobytes()" if small else "data"
        lines.append(f"        p{i}, r{i} = {src.const(_array_prefix(*fixed))}, a{i}.{data}")
        lines.append(f"    elif a{i}.__class__ is {nd}: p{i}, r{i} = {src.const(array_parts)}(a{i})")
    else:
        lines.append(f"    if a{i}.__class__ is {nd}: p{i}, r{i} = {src.const(array_parts)}(a{i})")
    lines.append("    else: return None")
    return lines


def _split(fields):
    arrays = [f for f in fields if type(f.metadata["kind"]) is base.Array]
    return [f for f in fields if f not in arrays], arrays


def _payload_lines(cls, fields, src: _Source, values: dict[str, str] | None = None) -> list[str]:
    """Lines that set `payload`: the plain fields through msgspec's encoder, then the arrays (see
    `_array_lines`) appended as ext values (the map's header counts both). `values`: expressions
    to encode for some fields instead of their values in `d`."""
    values = values or {}
    plain, arrays = _split(fields)
    lead = next((i for i, f in enumerate(plain) if f.metadata.get("optional")), len(plain))
    value = {f.name: values.get(f.name, f"d[{f.name!r}]") for f in fields}
    items = ", ".join([f"'type': {cls.TYPE!r}"] + [f"{f.name!r}: {value[f.name]}" for f in plain[:lead]])
    lines = [line for i, f in enumerate(arrays) for line in _array_lines(i, f, src)] + [f"    h = {{{items}}}"]
    for f in plain[lead:]:   # in declaration order; an optional field left out at its default (to_dict's rule)
        if f.metadata.get("optional"):
            lines.append(f"    if {value[f.name]} != {src.const(f.metadata['kind'].default())}: "
                         f"h[{f.name!r}] = {value[f.name]}")
        else:
            lines.append(f"    h[{f.name!r}] = {value[f.name]}")
    if not arrays:
        return lines + [f"    payload = {src.const(encode_plain)}(h)"]
    lines.append(f"    head = {src.const(encode_plain)}(h)")
    # The map's header counts the arrays too: msgspec's (1 byte up to 15 entries, else 3) replaced,
    # by a table lookup (bytes((n,)) costs more than the rest of the join).
    headers = src.const(tuple(_map_header(n) for n in range(len(fields) + 2)))
    skip = "1" if len(plain) + 1 <= 15 else "1 if len(h) <= 15 else 3"
    pieces = [f"{headers}[len(h) + {len(arrays)}]", f"head[{skip}:]"]
    for i, f in enumerate(arrays):
        pieces += [src.const(encode_plain(f.name)), f"p{i}", f"r{i}"]
    return lines + [f"    payload = b''.join(({', '.join(pieces)}))"]


def _gen_encode(cls, fields, src: _Source) -> list[str]:
    """Each array's bytes copied once, into the payload (small fixed ones: once more, see
    `_SMALL_ARRAY`)."""
    return ["def encode(msg):", "    d = msg.__dict__"] + _payload_lines(cls, fields, src) + ["    return payload"]


def _gen_publish(cls, fields, src: _Source) -> list[str]:
    """validate, then stamp_for_publish, then encode, in one function. The header's new values are
    written into the message only once the payload is made: a failure anywhere (a check, the
    class's `check`, a value the encoder refuses) leaves the message as it was."""
    header = {"stamp": "stamp", "source_stamp": "source", "seq": "seq"}
    return (["def publish(msg, seq):", "    d = msg.__dict__"]
            + _gen_checks(fields, src, "return None", store=False)
            + ["    msg.check()",   # before the fields are read for encoding: it may change them
               f"    stamp = d['stamp'] or {src.const(time.time)}()",
               "    source = d['source_stamp'] or stamp"]
            + _payload_lines(cls, fields, src, header)
            + ["    d['stamp'], d['source_stamp'], d['seq'] = stamp, source, seq", "    return payload"])


def _decline(*_args):
    return None


def compile_class(cls) -> FastPaths:
    """The fast paths of one message class (the reference for whatever the class overrides)."""
    fields = cls._fields()
    if any("__slots__" in c.__dict__ for c in cls.__mro__[:-1]) or any(f.name == "type" for f in fields):
        return FastPaths(coerce=_reference_coerce(cls), validate=lambda msg: False, encode=_decline,
                         publish=_decline, from_dict=_decline, decode=_decline)
    src = _Source()
    code = (_gen_coerce(cls, fields, src) + _gen_validate(fields, src) + _gen_from_dict(cls, fields, src)
            + _gen_decode(cls, fields, src) + _gen_encode(cls, fields, src) + _gen_publish(cls, fields, src))
    namespace = dict(src.names)
    exec(compile("\n".join(code), f"<fast paths of {cls.__name__}>", "exec"), namespace)  # noqa: S102
    reference_decode = cls.from_dict.__func__ is base.Message.from_dict.__func__
    reference_encode = cls.to_dict is base.Message.to_dict
    # publish stands for validate + stamp_for_publish + encode: only where none is overridden
    reference_publish = reference_encode and all(
        getattr(cls, name) is getattr(base.Message, name) for name in ("validate", "stamp_for_publish", "encode")
    ) and cls.__setattr__ is object.__setattr__
    return FastPaths(
        coerce=namespace["coerce"],
        validate=namespace["validate"],
        encode=namespace["encode"] if reference_encode else _decline,
        publish=namespace["publish"] if reference_publish else _decline,
        from_dict=namespace["from_dict"] if reference_decode else _decline,
        decode=namespace["decode"] if reference_decode else _decline,
    )


def _reference_coerce(cls):
    def coerce(msg):
        for f in cls._fields():
            object.__setattr__(msg, f.name, _coerce_field(cls, f.name, f.metadata["kind"], getattr(msg, f.name)))
    return coerce

"""Messages as msgspec Structs: each type declared once, as a class of typed, documented fields.

    class HandPose(Message):
        position: Array(3) = doc("hand origin in screen units")
        orientation: Array(4) = doc("unit quaternion (x, y, z, w)", default=IDENTITY)
        valid: bool = doc("false while tracking is lost")

        def check(self):            # rules across fields, on publish and on decode
            ...

A field's type says what it holds: `Float` (finite) or `float`, `int`, `bool`, `str`, `Literal[...]`,
`list[str]`, `list[int]`, `Map`, `Array(shape..., dtype=, finite=)` (a numpy array), `list[Array(...)]`
or `Records(...)` (a list of maps, e.g. a scene's objects). Every field may be left out when a
message is made (it then holds its `default`, or its type's zero); on the wire every field is
present but an `optional` one, which is left out while it holds its default (`recorded_stamp`).

One code path: msgspec's C encoder and decoder do the msgpack (arrays: messages/codec.py) and check
the plain fields of a payload; the arrays, records and the class's `check()` are checked in Python,
by the same functions when publishing and when decoding. Anything wrong is a MessageError naming
the type and the field.
"""
import itertools
import math
import re
import sys
import time
import typing
from typing import Annotated, Any, Callable, ClassVar, Literal, NamedTuple

import msgspec
import numpy as np

from touch4d.errors import Touch4dError

from .codec import CodecError, _ext_hook, encode_plain, unpack
from .header import DOCS as HEADER_DOCS
from .header import Finite, Header

__all__ = ["Message", "MessageError", "TYPES", "Float", "Map", "Array", "Records", "array_schema", "doc", "encode",
           "decode", "decoder"]


class MessageError(Touch4dError, ValueError):
    """A payload or message that is not a valid message; the text names the type, the field and the problem."""


Float = Finite                 # a finite number (NaN and infinities refused); `float` takes them
Map = dict[str, Any]           # a map with string keys and plain values (numbers, strings, lists, maps)


# ---- field types that msgspec checks only in part: arrays and records ------------------------------


class ArraySpec:
    """A numpy array field: dtype kind ('f' float, 'i' int, 'b' bool) and shape (None: any length)."""

    def __init__(self, shape: tuple[int | None, ...], dtype: str, finite: bool):
        self.shape, self.dtype, self.finite = shape, np.dtype(dtype), finite
        self.kinds = "iu" if self.dtype.kind in "iu" else self.dtype.kind
        self.check_finite = finite and self.dtype.kind == "f"
        self.text = "x".join("N" if n is None else str(n) for n in shape) or "scalar"
        self.fixed = {i: n for i, n in enumerate(shape) if n is not None}   # the lengths that are given
        self.check = self._checker()

    def _checker(self) -> Callable[[Any], None]:
        """check(value): raises ValueError unless `value` is such an array (a closure: this runs per message)."""
        want, ndim, kinds, finite, ndarray = self.shape, len(self.shape), self.kinds, self.check_finite, np.ndarray
        fixed, dot, isfinite = tuple(self.fixed.items()), np.dot, math.isfinite

        def check(value) -> None:
            if value.__class__ is not ndarray and not isinstance(value, ndarray):
                raise ValueError(f"expected a numpy array, got {type(value).__name__}")
            if value.dtype.kind not in kinds:
                raise ValueError(f"expected dtype kind '{self.dtype.kind}' ({self.dtype}), got {value.dtype}")
            shape = value.shape
            if shape != want:
                if len(shape) != ndim:
                    raise ValueError(f"expected shape {self.text}, got {'x'.join(map(str, shape)) or 'scalar'}")
                for i, n in fixed:
                    if shape[i] != n:
                        raise ValueError(f"expected shape {self.text}, got {'x'.join(map(str, shape))}")
            if finite:
                # A finite sum (of squares) proves every value finite; only a non-finite one needs the look.
                if value.size <= 16:   # poses, quaternions: plain floats are quicker than numpy
                    total = sum(value.tolist() if value.ndim == 1 else value.ravel().tolist())
                else:
                    flat = value.reshape(-1)
                    total = dot(flat, flat)
                if not isfinite(total) and not np.isfinite(value).all():
                    raise ValueError("expected finite values, got NaN or infinity")

        def check_vector(value) -> None:   # a pose's vectors, the usual case at one look
            if not (value.__class__ is ndarray and value.shape == want and value.dtype.kind in kinds
                    and isfinite(sum(value.tolist()))):
                check(value)   # the whole rule: says what is wrong, if anything
        return check_vector if finite and ndim == 1 and want[0] is not None and want[0] <= 16 else check

    def coerce(self, value) -> np.ndarray:
        if value.__class__ is np.ndarray and value.dtype.kind == self.dtype.kind:
            return value
        arr = np.asarray(value)
        if arr.dtype != self.dtype and not (arr.dtype.kind == self.dtype.kind and arr.dtype.kind in "fiu"):
            arr = arr.astype(self.dtype)   # float32 stays float32; a list of ints becomes float64
        return arr

    def zero(self) -> np.ndarray:
        return np.zeros([n or 0 for n in self.shape], dtype=self.dtype)

    def schema(self) -> dict:
        return array_schema(len(self.shape), self.dtype, self.shape)


def Array(*shape: int | None, dtype: str = "f8", finite: bool = True):  # noqa: N802 - read as a type
    """A numpy array field: `Array(3)` a 3-vector, `Array(None, 3)` N x 3, `finite=False` lets NaN in."""
    return Annotated[np.ndarray, ArraySpec(shape, dtype, finite)]


class RecordsSpec:
    """A list of maps, each with typed keys (some optional); other keys are let through."""

    def __init__(self, fields: dict[str, Any], optional: tuple[str, ...]):
        self.fields, self.optional = fields, optional
        self.checks = {key: _checker(tp) for key, tp in fields.items()}
        self.coerces = {key: c for key, tp in fields.items() if (c := _coercer(tp)) is not None}

    def check(self, value) -> None:
        if not isinstance(value, list):
            raise ValueError(f"expected a list, got {type(value).__name__}")
        for index, item in enumerate(value):
            if not isinstance(item, dict):
                raise ValueError(f"[{index}]: expected a map, got {type(item).__name__}")
            for key, check in self.checks.items():
                if key not in item:
                    if key in self.optional:
                        continue
                    raise ValueError(f"[{index}].{key}: missing")
                try:
                    check(item[key])
                except ValueError as exc:
                    raise ValueError(f"[{index}].{key}{_sep(exc)}{exc}") from None

    def coerce(self, value) -> list:
        return [{k: self.coerces[k](v) if k in self.coerces else v for k, v in dict(item).items()}
                for item in value]

    def schema(self) -> dict:
        props = {name: _schema(t) for name, t in self.fields.items()}
        required = [name for name in self.fields if name not in self.optional]
        return {"type": "array", "items": {"type": "object", "properties": props, "required": required}}


def Records(*, optional: tuple[str, ...] = (), **fields):  # noqa: N802 - read as a type
    """A list of maps whose keys have these types, e.g. `Records(name=str, size=Float, optional=("size",))`."""
    return Annotated[list[dict[str, Any]], RecordsSpec(fields, optional)]


# ---- per type: check (publishing, and what msgspec leaves), coerce and zero (making a message) -----


def _spec(tp):
    """The ArraySpec or RecordsSpec of an annotated type, or None."""
    if typing.get_origin(tp) is Annotated:
        return next((m for m in tp.__metadata__ if isinstance(m, (ArraySpec, RecordsSpec))), None)
    return None


_FIELD_PATH = re.compile(r"[A-Za-z_]\w*(\[\d+\])*(\.\w+(\[\d+\])*)*: ")


def _sep(exc: Exception) -> str:
    return "" if str(exc).startswith("[") else ": "   # list items read as objects[2].size: ...


def _checker(tp) -> Callable[[Any], None]:
    """A function raising ValueError (saying what was expected) for a value not of type `tp`: what
    publishing checks, as msgspec does when decoding."""
    spec = _spec(tp)
    if spec is not None:
        return spec.check
    if tp is Finite or tp is float:
        finite = tp is Finite

        def check_float(v):
            if v.__class__ is not float and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise ValueError(f"expected a number, got {type(v).__name__}")
            if finite and v - v != 0:
                raise ValueError(f"expected a finite number, got {v}")
        return check_float
    if tp is int:
        def check_int(v):
            if v.__class__ is not int:
                raise ValueError(f"expected an integer, got {type(v).__name__}")
        return check_int
    if tp is bool:
        def check_bool(v):
            if v.__class__ is not bool:
                raise ValueError(f"expected true or false, got {type(v).__name__}")
        return check_bool
    if tp is str:
        def check_str(v):
            if not isinstance(v, str):
                raise ValueError(f"expected a string, got {type(v).__name__}")
        return check_str
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        choices = frozenset(args)

        def check_choice(v):
            if v.__class__ is not str or v not in choices:
                raise ValueError(f"expected one of {', '.join(args)}, got {v!r}")
        return check_choice
    if origin is list and args[0] in (str, int):
        items, what = itertools.repeat(args[0]), "strings" if args[0] is str else "integers"
        bools = itertools.repeat(bool)

        def check_list(v):   # map(isinstance, ...): a loop in C (a list of names is checked per message)
            if (v.__class__ is not list or not all(map(isinstance, v, items))
                    or (what == "integers" and any(map(isinstance, v, bools)))):
                raise ValueError(f"expected a list of {what}")
        return check_list
    if origin is list:
        check_item = _checker(args[0])

        def check_items(v):
            if not isinstance(v, list):
                raise ValueError(f"expected a list, got {type(v).__name__}")
            for index, x in enumerate(v):
                try:
                    check_item(x)
                except ValueError as exc:
                    raise ValueError(f"[{index}]: {exc}") from None
        return check_items
    if origin is dict:
        def check_map(v):
            if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
                raise ValueError("expected a map with string keys")
        return check_map
    raise TypeError(f"a message field cannot be of type {tp!r}")


def _coercer(tp) -> Callable[[Any], Any] | None:
    """What making a message does to a value given for a field of type `tp` (None: nothing): a list
    becomes an array, an int a float."""
    spec = _spec(tp)
    if spec is not None:
        return spec.coerce
    if tp is Finite or tp is float:
        return lambda v: v if v.__class__ is float else float(v)
    if tp is int:
        return lambda v: v if v.__class__ is int else int(v)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is list and args[0] is int:
        return lambda v: [int(x) for x in v]
    if origin is list and _spec(args[0]) is not None:
        item = _spec(args[0]).coerce
        return lambda v: [item(x) for x in v]
    if origin is list:
        return list
    if origin is dict:
        return dict
    return None


def _zero(tp) -> Callable[[], Any] | Any:
    """A field's value when a message is made without it: a value, or a function making a fresh one."""
    spec = _spec(tp)
    if isinstance(spec, ArraySpec):
        return spec.zero
    if isinstance(spec, RecordsSpec):
        return list
    if tp is Finite or tp is float:
        return 0.0
    origin = typing.get_origin(tp)
    if origin is Literal:
        return typing.get_args(tp)[0]
    if origin in (list, dict):
        return origin
    return {int: 0, bool: False, str: ""}[tp]


def array_schema(ndim: int, dtype, shape=None) -> dict:
    """The JSON schema of an array as logs write it: nested arrays `ndim` deep (`shape`'s lengths where given);
    floats may be null in JSON, where the value is NaN or infinite."""
    kind = {"b": "boolean", "i": "integer", "u": "integer"}.get(np.dtype(dtype).kind, "number")
    item: dict = {"type": ["number", "null"]} if kind == "number" else {"type": kind}
    for depth in reversed(range(ndim)):
        item = {"type": "array", "items": item}
        if shape is not None and shape[depth] is not None:
            item["minItems"] = item["maxItems"] = shape[depth]
    return item


def _schema(tp) -> dict:
    """The JSON schema of a field's value as a log's JSON export writes it (touch4d.log.schema): `Float` a
    number, `float` a number or null (NaN and infinities), arrays nested lists."""
    spec = _spec(tp)
    if spec is not None:
        return spec.schema()
    if tp is Finite:
        return {"type": "number"}
    if tp is float:
        return {"type": ["number", "null"]}
    if tp in (bool, int, str):
        return {"type": {bool: "boolean", int: "integer", str: "string"}[tp]}
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return {"type": "string", "enum": list(args)}
    if origin is list:
        return {"type": "array", "items": _schema(args[0])}
    if origin is dict:
        return {"type": "object"}
    return {}


def _usual(fields) -> tuple[Callable[[Any], bool], tuple]:
    """(usual(msg), rest): `usual` answers in one expression, compiled once per class as dataclasses
    writes an __init__, whether every field it covers holds the usual value of its type (a float,
    an int, a bool, a string, a choice, a small numpy vector of its shape and kind; all finite that
    must be); `rest` ((name, check) pairs) are the fields it leaves to their own checks. A no says
    nothing: the fields' checks, which say what is wrong, then look one by one."""
    env: dict[str, Any] = {"ndarray": np.ndarray, "isfinite": math.isfinite}
    loads, terms, finite, rest = [], [], [], []
    for k, (name, tp) in enumerate(fields):
        v, spec, origin = f"v{k}", _spec(tp), typing.get_origin(tp)
        if tp is Finite or tp is float:
            terms.append(f"{v}.__class__ is float")
            if tp is Finite:
                finite.append(v)
        elif tp in (int, bool, str):
            terms.append(f"{v}.__class__ is {tp.__name__}")
        elif origin is Literal and all(isinstance(a, str) for a in typing.get_args(tp)):
            env[f"c{k}"] = frozenset(typing.get_args(tp))
            terms.append(f"{v}.__class__ is str and {v} in c{k}")
        elif (isinstance(spec, ArraySpec) and len(spec.shape) == 1 and spec.shape[0] is not None
              and spec.shape[0] <= 16):
            env[f"s{k}"], env[f"k{k}"] = spec.shape, spec.kinds
            terms.append(f"{v}.__class__ is ndarray and {v}.shape == s{k} and {v}.dtype.kind in k{k}")
            if spec.check_finite:
                finite.append(f"sum({v}.tolist())")
        else:
            rest.append((name, _checker(tp)))
            continue
        loads.append(f"    {v} = msg.{name}\n")
    # a finite sum proves every term finite (a sum too large for a float says no: then each is looked at)
    terms.append(f"isfinite({' + '.join(finite)})" if finite else "True")
    source = f"def usual(msg):\n{''.join(loads)}    return ({' and '.join(terms)})\n"
    exec(source, env)  # noqa: S102 - source made above from the class's own field types
    return env["usual"], tuple(rest)


def _needs_check_after_decode(tp) -> bool:
    """Whether msgspec's decoding leaves part of a field's check undone (arrays and records)."""
    return _spec(tp) is not None or (typing.get_origin(tp) is list and _spec(typing.get_args(tp)[0]) is not None)


# ---- declarations ------------------------------------------------------------------------------------


class doc(NamedTuple):  # noqa: N801 - read as a declaration: field: type = doc("...")
    """What a message field means (units, frame), and optionally its default when a message is made
    without it; an `optional` field may be missing from a payload and is left out while at its default."""

    text: str
    default: Any = None
    optional: bool = False


class Field(NamedTuple):
    """One field of a message type, as its class declares it."""

    name: str
    type: Any
    doc: str
    optional: bool
    default: Any                              # a value, or a function making one (arrays, lists, maps)
    check: Callable[[Any], None]              # raises ValueError saying what was expected
    coerce: Callable[[Any], Any] | None
    schema: dict                              # its JSON schema (touch4d.log.schema writes it into logs)


TYPES: dict[str, type["Message"]] = {}


class MessageMeta(msgspec.StructMeta):
    """Makes each message class a tagged msgspec Struct of its declared fields and registers it."""

    def __new__(mcls, name, bases, namespace, **kwargs):
        if not any(isinstance(base, MessageMeta) for base in bases):   # Message itself
            return super().__new__(mcls, name, bases, namespace, **kwargs)
        type_name = namespace.get("TYPE", name)
        module = vars(sys.modules[namespace["__module__"]])
        types = {n: eval(t, module, dict(namespace)) if isinstance(t, str) else t  # noqa: S307 - the module's
                 for n, t in namespace.get("__annotations__", {}).items()}      # own annotations, as typing does
        docs: dict[str, doc] = {}
        for field_name, tp in types.items():
            declared = namespace.get(field_name)
            if not isinstance(declared, doc):
                raise TypeError(f"{name}.{field_name}: declare it as `{field_name}: TYPE = doc(\"what it means\")`")
            _checker(tp)   # a type no message can carry: TypeError, now
            docs[field_name] = declared
            del namespace[field_name]   # required in every payload (msgspec: no default) ...
            if declared.optional:       # ... but an optional field: msgspec leaves it out while at its default
                namespace[field_name] = _zero(tp) if declared.default is None else declared.default
                if callable(namespace[field_name]) or isinstance(namespace[field_name], (list, dict, np.ndarray)):
                    raise TypeError(f"{name}.{field_name}: only a number, bool or string field may be optional")
        # On the wire the array fields follow the others, as earlier versions wrote them: the same bytes.
        namespace["__annotations__"] = dict(sorted(types.items(), key=lambda t: isinstance(_spec(t[1]), ArraySpec)))
        cls = super().__new__(mcls, name, bases, namespace, **{"tag": type_name, "kw_only": True, **kwargs})
        cls.TYPE = type_name
        inherited = {f.name: f for base in bases for f in getattr(base, "FIELDS", ())}
        fields = []
        for info in msgspec.structs.fields(cls):   # header first, then each class's fields
            if info.name in inherited:
                fields.append(inherited[info.name])
                continue
            declared = docs.get(info.name) or doc(HEADER_DOCS[info.name], optional=not info.required)
            coerce = _coercer(info.type)
            if declared.optional:
                default = info.default     # that very object: msgspec leaves out only it (see `_encode`)
            elif declared.default is None:
                default = _zero(info.type)
            else:
                value = coerce(declared.default) if coerce else declared.default
                default = (lambda v=value: v.copy()) if isinstance(value, (np.ndarray, list, dict)) else value
            fields.append(Field(info.name, info.type, declared.text, declared.optional, default,
                                _checker(info.type), coerce, _schema(info.type)))
        order = [*inherited, *types]
        fields.sort(key=lambda f: order.index(f.name) if f.name in order else -1)   # -1: the header
        cls.FIELDS = tuple(fields)   # as declared (docs, schemas); the wire has the arrays last
        cls._made_defaults = tuple((f.name, f.default) for f in fields if callable(f.default))
        cls._defaults = _make(cls, **{f.name: f.default() if callable(f.default) else f.default for f in fields})
        cls._coerce = {f.name: f.coerce for f in fields if f.coerce is not None}
        cls._checks = tuple((f.name, f.check) for f in fields)
        cls._after_decode = tuple((f.name, f.check) for f in fields if _needs_check_after_decode(f.type))
        # the whole message at one look, then only what that look leaves (publishing; after decoding)
        usual, cls._rest = _usual([(f.name, f.type) for f in fields])
        usual_decoded, cls._rest_decoded = _usual([(f.name, f.type) for f in fields
                                                   if _needs_check_after_decode(f.type)])
        cls._usual, cls._usual_decoded = staticmethod(usual), staticmethod(usual_decoded)
        cls._optional = tuple((f.name, f.default) for f in fields if f.optional)
        cls._overrides_check = cls.check is not Message.check
        cls._decode = msgspec.msgpack.Decoder(cls, ext_hook=_ext_hook).decode
        TYPES[type_name] = cls
        _union.clear()
        return cls

    def __call__(cls, **values):
        """A new message: every field not given holds its default; given values are coerced to the
        field's type (a list to an array, an int to a float); nothing is checked before publishing."""
        coerce = cls._coerce
        name = ""
        try:
            for name, value in values.items():
                c = coerce.get(name)
                if c is not None:
                    values[name] = c(value)
        except (TypeError, ValueError) as exc:
            raise MessageError(f"{cls.TYPE}.{name}: {exc}") from None
        for name, make in cls._made_defaults:
            if name not in values:
                values[name] = make()
        # A copy of the class's message of defaults with these values: msgspec's replace, in C (quicker
        # than its __init__ with every field); each array, list or map default is made fresh above.
        return _replace(cls._defaults, **values)


_make, _replace = msgspec.StructMeta.__call__, msgspec.structs.replace


class Message(Header, metaclass=MessageMeta, tag_field="type", omit_defaults=True, forbid_unknown_fields=True,
              gc=False):
    """Base of all messages: the header (messages/header.py), encoding, checking and decoding.

    gc=False: the garbage collector does not track messages (made and dropped at 1 kHz, they would
    only make its collections longer); a message is data and never part of a reference cycle."""

    TYPE: ClassVar[str] = ""
    FIELDS: ClassVar[tuple[Field, ...]] = ()

    def check(self) -> None:
        """Rules across fields (equal lengths, unit quaternions): raise ValueError; subclasses override."""

    @classmethod
    def field_docs(cls) -> dict[str, str]:
        """Each field's documentation (units, frame), e.g. for log schemas and `topic echo`."""
        return {f.name: f.doc for f in cls.FIELDS}

    def validate(self) -> None:
        """Check every field (types, shapes, finiteness) and the message's own rules (`check`)."""
        # the message as it nearly always is, at one look; else each field's own check says what is wrong
        _checked(self, self._rest if self._usual(self) else self._checks)

    def to_dict(self) -> dict[str, Any]:
        """The message as the map it is sent as (an optional field at its default left out)."""
        out = {"type": self.TYPE}
        optional = dict(self._optional)
        for name in self.__struct_fields__:   # in wire order
            value = getattr(self, name)
            if not (name in optional and value == optional[name]):
                out[name] = value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Message":
        """A checked message of this class from a map (with or without its "type")."""
        return decode(encode_plain({**data, "type": cls.TYPE}), cls)

    def encode(self) -> bytes:
        """The msgpack payload of the message as it is (not checked: see `publish_payload`)."""
        try:
            return self._encode()
        except (TypeError, ValueError, OverflowError) as exc:   # e.g. an object in a map field
            raise MessageError(f"{self.TYPE}: cannot encode: {exc}") from None

    def _encode(self) -> bytes:
        for name, default in self._optional:
            # msgspec leaves a field out only while it holds its default object itself
            value = getattr(self, name)
            if value is not default and value == default:
                setattr(self, name, default)
        return encode_plain(self)

    def publish_payload(self, seq: int) -> bytes:
        """The payload a publisher sends: checked (`validate`), stamped (`stamp` now if 0, `source_stamp`
        the stamp if 0: a message that originates) as number `seq`, and encoded. Raises MessageError if
        a field is invalid or cannot be encoded; the header is then left as it was."""
        self.validate()
        header = self.stamp, self.source_stamp, self.seq
        stamp = header[0] or time.time()
        self.stamp, self.source_stamp, self.seq = stamp, header[1] or stamp, seq
        try:
            return self._encode()
        except (TypeError, ValueError, OverflowError) as exc:   # e.g. an object in a map field
            self.stamp, self.source_stamp, self.seq = header   # nothing is sent
            raise MessageError(f"{self.TYPE}: cannot encode: {exc}") from None


# ---- decoding -----------------------------------------------------------------------------------------

_union: dict[str, Callable] = {}   # the decoder of any registered type; remade when a type is declared


def _decode_any(payload: bytes) -> Message:
    decode_any = _union.get("decode")
    if decode_any is None:
        decode_any = _union["decode"] = msgspec.msgpack.Decoder(
            typing.Union[tuple(TYPES.values())], ext_hook=_ext_hook).decode   # noqa: UP007
    return decode_any(payload)


def _checked(msg: Message, checks: tuple) -> Message:
    """`msg` once its fields pass `checks` ((name, check) pairs) and it passes its class's `check()`;
    else a MessageError naming the type and the field. The one place both publishing and decoding
    check a message (after decoding, only what msgspec leaves: arrays and records)."""
    name = ""
    try:
        for name, check in checks:
            check(getattr(msg, name))
        name = None
        if msg._overrides_check:
            msg.check()
    except MessageError:
        raise
    except ValueError as exc:
        text = str(exc)
        if name is not None:
            raise MessageError(f"{msg.TYPE}.{name}{_sep(exc)}{text}") from None
        # the class's rule: "field: ..." or "objects[2].size: ..." reads TYPE.field: ...
        raise MessageError(f"{msg.TYPE}{'.' if _FIELD_PATH.match(text) else ': '}{text}") from None
    return msg


def decoder(expected: type[Message]) -> Callable[[bytes], Message]:
    """`decode(payload, expected)` as one function, made once (a subscription's)."""
    decode_one, checks = expected._decode, expected._after_decode
    usual, rest = expected._usual_decoded, expected._rest_decoded

    def decode_expected(payload: bytes) -> Message:
        try:
            msg = decode_one(payload)
        except (msgspec.ValidationError, msgspec.DecodeError, CodecError, UnicodeDecodeError) as exc:
            raise _error(exc, payload, expected) from None
        return _checked(msg, rest if usual(msg) else checks)

    return decode_expected


def decode(payload: bytes, expected: type[Message] | None = None) -> Message:
    """Payload bytes -> a checked message; raises MessageError saying exactly what is wrong."""
    try:
        msg = expected._decode(payload) if expected is not None else _decode_any(payload)
    except (msgspec.ValidationError, msgspec.DecodeError, CodecError, UnicodeDecodeError) as exc:
        raise _error(exc, payload, expected) from None
    return _checked(msg, msg._rest_decoded if msg._usual_decoded(msg) else msg._after_decode)


def encode(msg: Message) -> bytes:
    """Message -> msgpack payload bytes (the second frame on the wire)."""
    return msg.encode()


def _error(exc: Exception, payload: bytes, expected: type[Message] | None) -> MessageError:
    """msgspec's or the codec's complaint about a payload as a MessageError naming type and field.

    What is wrong is found from the message's declaration, not from msgspec's words: the payload is
    read as plain data and each field is given the check publishing gives it (`Field.check`)."""
    if isinstance(exc, CodecError):
        return MessageError(str(exc))
    if isinstance(exc, UnicodeDecodeError):   # msgspec decodes map keys itself, and raises this for bad UTF-8
        return MessageError(f"not a message: a string that is not UTF-8 ({exc.reason} at byte {exc.start})")
    if isinstance(exc, msgspec.DecodeError) and not isinstance(exc, msgspec.ValidationError):
        return MessageError(f"not a msgpack payload: {exc}")
    try:
        data = unpack(payload)
    except CodecError as bad:
        return MessageError(str(bad))
    if not isinstance(data, dict):
        return MessageError(f"expected a message map, got {_kind(data)}")
    name = data.get("type")
    cls = TYPES.get(name) if isinstance(name, str) else None
    if cls is None:
        return MessageError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        return MessageError(f"expected a {expected.TYPE} message, got {cls.TYPE}")
    return MessageError(f"{cls.TYPE}{_problem(cls, data) or f': {exc}'}")


def _problem(cls: type[Message], data: dict) -> str | None:
    """What is wrong with the map `data` as a `cls` message (".field: ..." or ": ..."), or None if
    the fields' own checks find nothing (msgspec's words are then all there is)."""
    keys = [k for k in data if not isinstance(k, str)]
    if keys:
        return f": keys: expected a string, got {_kind(keys[0])}"
    fields = {f.name: f for f in cls.FIELDS}
    unknown = [k for k in data if k != "type" and k not in fields]
    if unknown:
        return f": unknown field(s) {', '.join(unknown)}"
    for f in cls.FIELDS:
        if f.name not in data:
            if not f.optional:
                return f".{f.name}: missing"
            continue
        try:
            f.check(data[f.name])
        except ValueError as exc:
            return f".{f.name}{_sep(exc)}{exc}"
    return None


def _kind(value) -> str:
    """A wire value's kind in the messages' words (a list, a map, a string, ...)."""
    return _WIRE_NAMES.get(type(value).__name__, type(value).__name__)


_WIRE_NAMES = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
               "list": "a list", "dict": "a map", "ndarray": "a numpy array", "NoneType": "nil", "bytes": "bytes"}

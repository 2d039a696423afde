"""The message base class: typed fields, a header on every message, checked decoding."""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import numpy as np

from .codec import CodecError, pack, unpack


class MessageError(ValueError):
    """A payload that is not a valid message; the text names the type, the field and the problem."""


# ---- field kinds ---------------------------------------------------------------------------------


class Kind:
    """How one field is checked and coerced; `check` returns the clean value or raises ValueError."""

    def coerce(self, value):
        return value

    def check(self, value):
        return value

    def default(self):
        return None


class Float(Kind):
    def __init__(self, finite: bool = True):
        self.finite = finite

    def coerce(self, value):
        return float(value)

    def check(self, value):
        if value.__class__ is not float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"expected a number, got {type(value).__name__}")
            value = float(value)
        if self.finite and not math.isfinite(value):
            raise ValueError(f"expected a finite number, got {value}")
        return value

    def default(self):
        return 0.0


class Int(Kind):
    def coerce(self, value):
        return int(value)

    def check(self, value):
        if value.__class__ is not int:
            raise ValueError(f"expected an integer, got {type(value).__name__}")
        return value

    def default(self):
        return 0


class Bool(Kind):
    def check(self, value):
        if not isinstance(value, bool):
            raise ValueError(f"expected true or false, got {type(value).__name__}")
        return value

    def default(self):
        return False


class Str(Kind):
    def __init__(self, choices: tuple[str, ...] | None = None):
        self.choices = choices

    def check(self, value):
        if not isinstance(value, str):
            raise ValueError(f"expected a string, got {type(value).__name__}")
        if self.choices is not None and value not in self.choices:
            raise ValueError(f"expected one of {', '.join(self.choices)}, got {value!r}")
        return value

    def default(self):
        return self.choices[0] if self.choices else ""


class StrList(Kind):
    def coerce(self, value):
        return list(value)

    def check(self, value):
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise ValueError("expected a list of strings")
        return value

    def default(self):
        return []


class IntList(Kind):
    def coerce(self, value):
        return [int(v) for v in value]

    def check(self, value):
        if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise ValueError("expected a list of integers")
        return value

    def default(self):
        return []


class Map(Kind):
    """A map with string keys and plain values (numbers, strings, bools, lists)."""

    def coerce(self, value):
        return dict(value)

    def check(self, value):
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise ValueError("expected a map with string keys")
        return value

    def default(self):
        return {}


def _all_finite(value: np.ndarray) -> bool:
    if value.size <= 16:  # poses, quaternions: plain floats are quicker than a numpy reduction
        return all(map(math.isfinite, value.ravel().tolist()))
    # A finite sum proves every value finite; only a non-finite sum needs the element-wise look.
    return math.isfinite(value.sum()) or bool(np.isfinite(value).all())


class Array(Kind):
    """A numpy array of a dtype kind ('f' float, 'i' int, 'b' bool) and a shape; None is any length."""

    def __init__(self, shape: tuple[int | None, ...], dtype: str = "f8", finite: bool = True, default=None):
        self.shape = shape
        self.dtype = np.dtype(dtype)
        self.finite = finite
        self._default = default
        self._kinds = "iu" if self.dtype.kind in "iu" else self.dtype.kind
        self._check_finite = finite and self.dtype.kind == "f"

    def coerce(self, value):
        arr = np.asarray(value)
        if arr.dtype != self.dtype and not (arr.dtype.kind == self.dtype.kind and arr.dtype.kind in "fiu"):
            arr = arr.astype(self.dtype)
        return arr

    def check(self, value):
        if value.__class__ is not np.ndarray and not isinstance(value, np.ndarray):
            raise ValueError(f"expected a numpy array, got {type(value).__name__}")
        if value.dtype.kind not in self._kinds:
            raise ValueError(f"expected dtype kind '{self.dtype.kind}' ({self.dtype}), got {value.dtype}")
        shape = value.shape
        if shape != self.shape and (
            len(shape) != len(self.shape) or any(w is not None and w != g for w, g in zip(self.shape, shape))
        ):
            want = "x".join("N" if n is None else str(n) for n in self.shape) or "scalar"
            raise ValueError(f"expected shape {want}, got {'x'.join(map(str, shape)) or 'scalar'}")
        if self._check_finite and not _all_finite(value):
            raise ValueError("expected finite values, got NaN or infinity")
        return value

    def default(self):
        if self._default is not None:
            return np.array(self._default, dtype=self.dtype)
        return np.zeros([n or 0 for n in self.shape], dtype=self.dtype)


class Records(Kind):
    """A list of maps, each checked against its own field kinds (e.g. the objects of a scene)."""

    def __init__(self, fields: dict[str, Kind], optional: tuple[str, ...] = ()):
        self.fields = fields
        self.optional = optional

    def coerce(self, value):
        out = []
        for item in value:
            item = dict(item)
            for key, kind in self.fields.items():
                if key in item:
                    item[key] = kind.coerce(item[key])
            out.append(item)
        return out

    def check(self, value):
        if not isinstance(value, list):
            raise ValueError(f"expected a list, got {type(value).__name__}")
        for index, item in enumerate(value):
            if not isinstance(item, dict):
                raise ValueError(f"[{index}]: expected a map, got {type(item).__name__}")
            for key, kind in self.fields.items():
                if key not in item:
                    if key in self.optional:
                        continue
                    raise ValueError(f"[{index}].{key}: missing")
                try:
                    item[key] = kind.check(item[key])
                except ValueError as exc:
                    raise ValueError(f"[{index}].{key}: {exc}") from None
        return value

    def default(self):
        return []


class ArrayList(Kind):
    """A list of arrays of one kind (e.g. the half-space tables of a union's parts)."""

    def __init__(self, item: Array):
        self.item = item

    def coerce(self, value):
        return [self.item.coerce(v) for v in value]

    def check(self, value):
        if not isinstance(value, list):
            raise ValueError(f"expected a list, got {type(value).__name__}")
        for index, item in enumerate(value):
            try:
                self.item.check(item)
            except ValueError as exc:
                raise ValueError(f"[{index}]: {exc}") from None
        return value

    def default(self):
        return []


def spec(kind: Kind, doc: str, *, optional: bool = False):
    """Declare a message field: its kind (checked on decode) and what it means (units, frame).

    An `optional` (scalar) field may be absent from a payload, meaning its default, and is left out
    of the payload while it holds its default: payloads without it stay valid and byte-identical."""
    metadata = {"kind": kind, "doc": doc, "optional": optional}
    default = kind.default()
    if default.__class__ in (float, int, bool, str):   # immutable: shared, and no call per message made
        return field(default=default, metadata=metadata)
    return field(default_factory=kind.default, metadata=metadata)


# ---- the message base class ------------------------------------------------------------------------

TYPES: dict[str, type[Message]] = {}


@dataclass(kw_only=True)
class Message:
    """Base of all messages: the header, encoding to msgpack bytes and checked decoding."""

    TYPE: ClassVar[str] = ""

    stamp: float = spec(Float(), "wall-clock time the message was made, seconds (time.time()); set on publish")
    seq: int = spec(Int(), "per-topic, per-publisher sequence number from 0; a gap means a drop; set on publish")
    source_stamp: float = spec(
        Float(), "stamp of the hand/pose this message was derived from (= stamp for originating messages)"
    )
    recorded_stamp: float = spec(
        Float(), "stamp this message had when it was recorded, kept when a replay re-stamps it; 0 = live",
        optional=True,
    )

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "TYPE" not in cls.__dict__:
            cls.TYPE = cls.__name__
        TYPES[cls.TYPE] = cls

    def __post_init__(self):
        (type(self).__dict__.get("_FAST") or _fast_paths(type(self))).coerce(self)   # each kind's coerce

    @classmethod
    def prepare(cls) -> None:
        """Generate the class's fast paths now (about 10 ms) rather than on its first message, which
        would then reach its subscribers late, and the dozen behind it with it."""
        if "_FAST" not in cls.__dict__:
            _fast_paths(cls)

    @classmethod
    def _fields(cls) -> tuple[dataclasses.Field, ...]:
        cached = cls.__dict__.get("_FIELDS_CACHE")
        if cached is None:
            cached = tuple(f for f in dataclasses.fields(cls) if "kind" in f.metadata)
            cls._FIELDS_CACHE = cached
        return cached

    @classmethod
    def field_docs(cls) -> dict[str, str]:
        """Each field's documentation (units, frame), e.g. for log schemas and `topic echo`."""
        return {f.name: f.metadata["doc"] for f in cls._fields()}

    def to_dict(self) -> dict[str, Any]:
        out = {"type": self.TYPE}
        for name, _ in self._checks():
            out[name] = getattr(self, name)
        for name, default in self._optional():
            if out[name] == default:
                del out[name]
        return out

    def validate(self) -> None:
        """Check every field (types, shapes, finiteness) and the message's own rules."""
        try:
            if (type(self).__dict__.get("_FAST") or _fast_paths(type(self))).validate(self):
                return
        except (KeyError, TypeError, ValueError):
            pass  # the checks below say what is wrong
        for name, check in self._checks():
            try:
                check(getattr(self, name))
            except ValueError as exc:
                raise MessageError(_where(self.TYPE, name, exc)) from None
        try:
            self.check()
        except ValueError as exc:
            raise MessageError(f"{self.TYPE}: {exc}") from None

    def check(self) -> None:
        """Rules across fields (equal lengths, unit quaternions); subclasses override."""

    def encode(self) -> bytes:
        payload = (type(self).__dict__.get("_FAST") or _fast_paths(type(self))).encode(self)
        return pack(self.to_dict()) if payload is None else payload

    def stamp_for_publish(self, seq: int) -> None:
        """Fill the header as a publisher sends it: `stamp` (if 0) now, `source_stamp` (if 0) the
        stamp (an originating message), `seq` the publisher's number for it."""
        if not self.stamp:
            self.stamp = time.time()
        if not self.source_stamp:
            self.source_stamp = self.stamp
        self.seq = seq

    def publish_payload(self, seq: int) -> bytes:
        """The payload a publisher sends: validated, stamped (`stamp_for_publish`) and encoded, in
        one generated pass where it can. Raises MessageError if a field is invalid or cannot be
        encoded; the header (stamp, source_stamp, seq) is then left as it was."""
        try:
            payload = (type(self).__dict__.get("_FAST") or _fast_paths(type(self))).publish(self, seq)
        except (KeyError, TypeError, ValueError):
            payload = None  # the reference below says what is wrong
        if payload is None:
            self.validate()
            header = (self.stamp, self.source_stamp, self.seq)
            self.stamp_for_publish(seq)
            try:
                payload = self.encode()
            except (TypeError, ValueError, OverflowError) as exc:   # e.g. an object in a map field
                self.stamp, self.source_stamp, self.seq = header     # nothing is sent
                raise MessageError(f"{self.TYPE}: cannot encode: {exc}") from None
        return payload

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Message:
        """Build and fully check a message of this class from a decoded map."""
        msg = cls.__new__(cls)
        fields = cls._checks()
        absent = 0
        for name, check in fields:
            try:
                value = data[name]
            except KeyError:
                default = dict(cls._optional()).get(name, _REQUIRED)
                if default is _REQUIRED:
                    raise MessageError(f"{cls.TYPE}.{name}: missing") from None
                object.__setattr__(msg, name, default)
                absent += 1
                continue
            try:
                object.__setattr__(msg, name, check(value))
            except ValueError as exc:
                raise MessageError(_where(cls.TYPE, name, exc)) from None
        if len(data) != len(fields) - absent + ("type" in data):
            unknown = set(data) - {name for name, _ in fields} - {"type"}
            raise MessageError(f"{cls.TYPE}: unknown field(s) {', '.join(sorted(map(str, unknown)))}")
        try:
            msg.check()
        except ValueError as exc:
            raise MessageError(f"{cls.TYPE}: {exc}") from None
        return msg

    @classmethod
    def _optional(cls) -> tuple[tuple[str, Any], ...]:
        """(name, default) of the optional fields, which payloads may leave out."""
        cached = cls.__dict__.get("_OPTIONAL_CACHE")
        if cached is None:
            cached = tuple((f.name, f.metadata["kind"].default()) for f in cls._fields() if f.metadata.get("optional"))
            cls._OPTIONAL_CACHE = cached
        return cached

    @classmethod
    def _checks(cls) -> tuple[tuple[str, Any], ...]:
        cached = cls.__dict__.get("_CHECKS_CACHE")
        if cached is None:
            cached = tuple((f.name, f.metadata["kind"].check) for f in cls._fields())
            cls._CHECKS_CACHE = cached
        return cached


_REQUIRED = object()


def _fast_paths(cls):
    """The class's generated fast paths (messages/compiled.py), made on first use: @dataclass has
    not yet made the fields when __init_subclass__ runs."""
    from .compiled import compile_class

    fast = cls._FAST = compile_class(cls)
    return fast


def _where(type_name: str, field_name: str, exc: Exception) -> str:
    text = str(exc)
    sep = "" if text.startswith("[") else ": "  # list items read as objects[2].size: ...
    return f"{type_name}.{field_name}{sep}{text}"


def encode(msg: Message) -> bytes:
    """Message -> msgpack payload bytes (the second frame on the wire)."""
    return msg.encode()


def decoder(expected: type[Message]) -> Callable[[bytes], Message]:
    """`decode(payload, expected)` as one function made once (a subscription's): the class's
    generated decode first, without looking it up per message."""
    fast = (expected.__dict__.get("_FAST") or _fast_paths(expected)).decode
    name = expected.TYPE

    def decode_expected(payload: bytes) -> Message:
        if TYPES.get(name) is expected:
            try:
                msg = fast(payload)
            except Exception:  # noqa: BLE001 - whatever it is, decode() says what is wrong
                msg = None
            if msg is not None:
                return msg
        return _decode_reference(payload, expected)

    return decode_expected


def decode(payload: bytes, expected: type[Message] | None = None) -> Message:
    """Payload bytes -> a checked message; raises MessageError saying exactly what is wrong."""
    if expected is not None and TYPES.get(expected.TYPE) is expected:
        try:
            msg = (expected.__dict__.get("_FAST") or _fast_paths(expected)).decode(payload)
        except Exception:  # noqa: BLE001 - whatever it is, the checks below say what is wrong
            msg = None
        if msg is not None:
            return msg
    return _decode_reference(payload, expected)


def _decode_reference(payload: bytes, expected: type[Message] | None) -> Message:
    """decode() by the reference code, which names what is wrong."""
    try:
        data = unpack(payload)
    except CodecError as exc:
        raise MessageError(str(exc)) from None
    if not isinstance(data, dict):
        raise MessageError(f"expected a message map, got {type(data).__name__}")
    name = data.get("type")
    cls = TYPES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise MessageError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise MessageError(f"expected a {expected.TYPE} message, got {cls.TYPE}")
    del data["type"]
    try:
        msg = (cls.__dict__.get("_FAST") or _fast_paths(cls)).from_dict(data)
    except (KeyError, TypeError, ValueError):
        msg = None  # from_dict says what is wrong
    return cls.from_dict(data) if msg is None else msg

"""The WebSocket protocol between the WebXR node and its page, both directions, without I/O.

Node -> page: binary frames, one per WebSocket message, that the page reads with typed-array views
(no parsing library in the page):

    u32 little-endian  length of the header in bytes
    header             UTF-8 JSON: {"kind": ..., <fields>, "arrays": {name: [dtype, shape, offset]}}
    padding            to a multiple of 8 bytes
    arrays             raw little-endian data, each at its `offset` from the frame's start (8-aligned)

dtype is one of ARRAY_DTYPES ("f4", "u4", "i4", "u2", "u1"). Kinds:
- "setup", once per connection: the glove (samples, outline, motors), the screen's placement, the
  tactile cube's layout and colours, the renderer's style and its shaders as GLSL ES 3.00;
- "geometry", once per change of what the scene is made of: `SceneGeometry`'s data textures and
  vertex arrays (touch4d.render.scene_geometry, the GPU backend's bytes);
- "frame", at most once per tick: the objects' transforms texture (96 bytes per object), the
  projection, the hand's pose, h and "touched" per sample, the motors' intensities and duties, and
  while a study runs `study` (its phase, trial index and total, prompt, options, message) and
  `draw_objects` (false: the study's condition hides every object; touch4d.study.gate), and
  `haptic`, the intensity 0..1 the page's controller or gamepad plays (touch4d.web.haptics);
- "calibration", after a re-centre: the screen's new placement in the room.

Page -> node: UTF-8 JSON text, at most MAX_PAGE_MESSAGE bytes, no NaN or infinity (rejected here):

    {"type": "input", "time": ms, "tracking": bool, "head": pose|null, "sources": [source, ...],
     "played": {"time": ms, "intensity": [V >= 0 per motor]}}      ("played": touch on the page only)
    {"type": "recenter", "head": pose}
    {"type": "session", "mode": "immersive"|"inline", "active": bool}
    {"type": "stats", "fps": number, "scale": 0..1, "foveation": 0..1}   (scale, foveation: in a headset)
    {"type": "response", "index": int, "option": str, "time": ms}
    {"type": "haptics", "output": "pulse"|"dual-rumble"|"none"}
    {"type": "buttons", "held": [name, ...]}
    {"type": "batch", "poses": {"time": [ms], "valid": [bool], "hand": [x, y, z, qx, qy, qz, qw per pose]},
     "touches": {"time": [ms], "intensity": [V per motor, per touch]}}

where "haptics" says, when it changes, what the page can vibrate: the glove hand's controller
(WebXR `pulse`), a desktop gamepad (`dual-rumble`) or nothing; a "response" answers a study's trial `index` with one of its options from the page's own
buttons (a tap in a desktop or headset browser; controller buttons arrive with "input");
`time` is the page's clock (performance.timeOrigin + performance.now(), ms) when it read the
poses, a pose is [x, y, z, qx, qy, qz, qw] (metres, local-floor space), and a source is
{"handedness": "right"|"left"|"none", "grip": pose|null, "trigger": 0..1, "buttons": [name, ...]
(the xr-standard buttons, and "thumbstick-up" / "thumbstick-down" while the stick is pushed),
"joints": [[x, y, z, qx, qy, qz, qw, radius] x 25]|null}. With the node's `touch: page` the page
computes the touch itself (static/touch.js) and each input carries what it played since the last
one: the motors' intensities of eq. 3 and the `time` of the pose they were computed from.

A served page (the setup frame's `batch_s` > 0: touch4d.web.served) sends no "input": its touch is its
own, so the server needs its frames only for the record, a "batch" every `batch_s`: each frame's
time, whether the glove hand was tracked and its pose on the screen (screen units, as static/touch.js
placed it), and what it played for each pose it computed (the pose's time, one V per motor). Its
answers ("response"), re-centring ("recenter") and the glove hand's controller buttons when they
change ("buttons": what they do to the scene, the slice's c) go at once, not batched.
"""
from __future__ import annotations

import json
import math
import re
import struct
import sys
from typing import Annotated, Literal, Union

import msgspec
import numpy as np

from touch4d import schema
from touch4d.errors import ConfigError, Touch4dError
from touch4d.tracking.webxr import JOINTS, THUMBSTICK_BUTTONS, XR_STANDARD_BUTTONS, XRSource

ARRAY_DTYPES = ("f4", "u4", "i4", "u2", "u1")
MAX_PAGE_MESSAGE = 16384          # bytes: an input message with two tracked hands is about 6 kB
MAX_SOURCES = 4
MAX_POSITION_M = 100.0            # |x|, |y|, |z| of a pose: metres a room (or a hall) can hold
MAX_JOINT_RADIUS_M = 0.1          # a finger joint's radius, metres
QUAT_TOLERANCE = 1e-2             # |q| - 1 allowed in a page's quaternion (float32 poses)
WS_MESSAGE_TOO_BIG = 1009        # the WebSocket close code (RFC 6455)
PAGE_TYPES = ("input", "recenter", "session", "stats", "response", "haptics", "batch", "buttons")
MAX_BATCH = 64                    # frames in a page's batch, at most (0.25 s at 144 Hz, with room)
MAX_SCREEN_UNITS = 100.0          # |x|, |y|, |z| of a hand on the screen ([-1, 1]^3 is the screen)
HAPTIC_OUTPUTS = ("pulse", "dual-rumble", "none")   # what a page can vibrate (touch4d/web/static/haptics.js)
MAX_INTENSITY = 1e3               # a motor's V = gamma h (h <= 1): gamma as a glove file may set it
MAX_MOTORS = 256                  # intensities in a page's "played" (a glove file's motors)
MAX_OPTION = 64                   # characters of a response option
HANDEDNESS = ("right", "left", "none")
BUTTON_NAMES = frozenset(b for b in XR_STANDARD_BUTTONS if b) | frozenset(THUMBSTICK_BUTTONS)
_LEN = struct.Struct("<I")
_to_json = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode   # json.dumps's, made once (per frame)
_last_start: dict[str, int] = {}   # kind -> where the arrays of its last frame started (pack_frame's first guess)


class PageError(Touch4dError, ValueError):
    """A page message that is dropped; `cause` is its counter's name: malformed, oversized, non_finite
    or unresponsive (a page that answered no ping).
    A message of the wrong shape names its `field` (e.g. sources[0].grip), what was `expected` and what
    it `got`."""

    def __init__(self, cause: str, detail: str, field: str | None = None, expected: str | None = None, got=None):
        super().__init__(detail)
        self.cause = cause
        self.field, self.expected, self.got = field, expected, got


# ---- node -> page ----------------------------------------------------------------------------------


def json_members(fields: dict) -> bytes:
    """`fields` as the members of a JSON object (`"key":value,...`, no braces): a frame's fields that
    change rarely, encoded once per change and given to every `pack_frame` until then."""
    return _to_json(fields).encode()[1:-1]


_BIG_ENDIAN = (">", "=") if sys.byteorder == "big" else (">",)   # dtype byte orders that are big-endian here


def pack_frame(kind: str, fields: dict | None = None, arrays: dict[str, np.ndarray] | None = None,
               members: bytes = b"") -> bytes:
    """One binary frame: a JSON header (kind, fields, array table) then the arrays, 8-byte aligned.
    `members`: more fields already encoded (`json_members`), none of them also in `fields`."""
    head = _head(kind)
    if members:
        head += members + b","
    if fields:
        head += json_members(fields) + b","
    head += b'"arrays":{'
    entries, clean = [], []
    for name, arr in (arrays or {}).items():
        arr = np.ascontiguousarray(arr)
        entry = _entry(name, arr)
        if arr.dtype.byteorder in _BIG_ENDIAN:   # the page reads little-endian
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        entries.append(entry)
        clean.append(arr)
    # The offsets depend on the header's length, which depends on the offsets' digits: until the
    # arrays' start no longer moves, only the array table is written again. The first guess is where
    # the last frame of this kind had them.
    start, header, offsets = _last_start.get(kind), b"", []
    for _ in range(8):
        if start is not None:
            offsets, offset = [], start
            for arr in clean:
                offsets.append(offset)
                offset = _align(offset + arr.nbytes)
        header = head + ",".join(f"{entry}{offset}]" for entry, offset in
                                 zip(entries, offsets or [0] * len(entries))).encode() + b"}}"
        if _align(_LEN.size + len(header)) == start:
            break
        start = _align(_LEN.size + len(header))
    else:
        raise AssertionError("frame header offsets did not settle")
    _last_start[kind] = start
    parts, end = [_LEN.pack(len(header)), header], _LEN.size + len(header)
    for offset, arr in zip(offsets, clean):
        parts += (bytes(offset - end), arr.tobytes())
        end = offset + arr.nbytes
    parts.append(bytes(_align(end) - end))
    return b"".join(parts)


_HEADS: dict[str, bytes] = {}      # kind -> the header's start, `{"kind":"frame",`
_ENTRIES: dict[tuple, str] = {}   # (name, dtype, shape) -> its array table entry up to the offset


def _entry(name: str, arr: np.ndarray) -> str:
    """`"name":["f4",[shape],` (JSON): an array's entry in the frame's table, its offset to follow."""
    key = (name, arr.dtype, arr.shape)
    entry = _ENTRIES.get(key)
    if entry is None:
        dtype = arr.dtype.newbyteorder("<").str[1:]
        if dtype not in ARRAY_DTYPES:
            raise ValueError(f"array {name!r}: dtype {arr.dtype} is not one of {', '.join(ARRAY_DTYPES)}")
        if len(_ENTRIES) >= 1024:   # shapes that vary (a section's triangles) must not grow it without bound
            _ENTRIES.clear()
        entry = _ENTRIES[key] = json.dumps({name: [dtype, list(arr.shape)]}, separators=(",", ":"))[1:-2] + ","
    return entry


def _head(kind: str) -> bytes:
    """How a header of this kind begins (its kind first: `is_kind` reads it without parsing)."""
    head = _HEADS.get(kind)
    if head is None:
        head = _HEADS[kind] = b'{"kind":' + json.dumps(kind).encode() + b","
    return head


def header_span(data: bytes) -> tuple[int, int]:
    """Where a frame's JSON header lies in it (start, end)."""
    (n,) = _LEN.unpack_from(data, 0)
    return _LEN.size, _LEN.size + n


def is_kind(data: bytes, kind: str) -> bool:
    """Whether a frame is of this kind, its header not parsed (a tap on the wire: touch4d.web.wiretrace)."""
    return data.startswith(_head(kind), _LEN.size)


def frame_header(data: bytes) -> dict:
    """A frame's header fields (kind, fields, the array table), its arrays left unread."""
    start, end = header_span(data)
    return json.loads(data[start:end])


def unpack_frame(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """A frame back into (header fields, arrays) — what the page does with typed-array views."""
    header = frame_header(data)
    arrays = {}
    for name, (dtype, shape, offset) in header.pop("arrays").items():
        count = int(np.prod(shape)) if shape else 1
        arrays[name] = np.frombuffer(data, dtype="<" + dtype, count=count, offset=offset).reshape(shape)
    return header, arrays


def _align(n: int) -> int:
    return (n + 7) & ~7


# ---- page -> node ----------------------------------------------------------------------------------


# JSON cannot carry NaN or infinity; a number too big for a double (1e999) is refused by the decoder.
# Positions are metres from the headset's floor origin: a room, never 1e308 (which would be stored
# in the calibration file by a re-centre).
Metres = Annotated[float, msgspec.Meta(ge=-MAX_POSITION_M, le=MAX_POSITION_M)]
Pose = Annotated[tuple[Metres, Metres, Metres, float, float, float, float],
                 msgspec.Meta(description="a pose [x, y, z, qx, qy, qz, qw]")]
Joint = Annotated[tuple[Metres, Metres, Metres, float, float, float, float,
                        Annotated[float, msgspec.Meta(le=MAX_JOINT_RADIUS_M)]],
                  msgspec.Meta(description="a joint [x, y, z, qx, qy, qz, qw, radius]")]


def _check_quaternion(pose, key: str) -> None:
    norm = math.sqrt(sum(v * v for v in pose[3:7]))
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        raise schema.Invalid(f"a unit quaternion (norm {norm:.4g})", list(pose), key)


class SourceMessage(msgspec.Struct, forbid_unknown_fields=True):
    handedness: Literal["right", "left", "none"]
    trigger: Annotated[float, msgspec.Meta(ge=0, le=1)]
    buttons: list[Literal[tuple(sorted(BUTTON_NAMES))]]
    grip: Pose | None = None
    joints: Annotated[list[Joint], msgspec.Meta(min_length=len(JOINTS), max_length=len(JOINTS))] | None = None

    def __post_init__(self):
        if self.grip is not None:
            _check_quaternion(self.grip, "grip")
        for k, joint in enumerate(self.joints or ()):
            _check_quaternion(joint, f"joints[{k}]")
            if joint[7] < 0:
                raise schema.Invalid("a radius >= 0", joint[7], f"joints[{k}][7]")


class PlayedMessage(msgspec.Struct, forbid_unknown_fields=True):
    """What the page's own touch played: per motor V (eq. 3), from the pose the page read at `time` (ms)."""

    time: Annotated[float, msgspec.Meta(ge=0)]
    intensity: Annotated[list[Annotated[float, msgspec.Meta(ge=0, le=MAX_INTENSITY)]],
                         msgspec.Meta(max_length=MAX_MOTORS)]


class InputMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="input"):
    time: Annotated[float, msgspec.Meta(ge=0)]
    tracking: bool
    sources: Annotated[list[SourceMessage], msgspec.Meta(max_length=MAX_SOURCES)]
    head: Pose | None = None
    played: PlayedMessage | None = None

    def __post_init__(self):
        if self.head is not None:
            _check_quaternion(self.head, "head")


class RecenterMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="recenter"):
    head: Pose

    def __post_init__(self):
        _check_quaternion(self.head, "head")


class SessionMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="session"):
    mode: Literal["immersive", "inline"]
    active: bool


class StatsMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="stats"):
    fps: Annotated[float, msgspec.Meta(ge=0, le=1000)]
    scale: Annotated[float, msgspec.Meta(gt=0, le=1)] | None = None       # its XR layer's, now (static/pacing.js)
    foveation: Annotated[float, msgspec.Meta(ge=0, le=1)] | None = None


class ResponseMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="response"):
    index: Annotated[int, msgspec.Meta(ge=0, lt=2**31)]
    option: Annotated[str, msgspec.Meta(max_length=MAX_OPTION)]
    time: Annotated[float, msgspec.Meta(ge=0)]


class HapticsMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="haptics"):
    output: Literal[HAPTIC_OUTPUTS]


Millis = Annotated[float, msgspec.Meta(ge=0)]
Intensity = Annotated[float, msgspec.Meta(ge=0, le=MAX_INTENSITY)]


class PosesBatch(msgspec.Struct, forbid_unknown_fields=True):
    """A served page's frames: when, whether the glove hand was tracked, where it was on the screen."""

    time: Annotated[list[Millis], msgspec.Meta(max_length=MAX_BATCH)]
    valid: Annotated[list[bool], msgspec.Meta(max_length=MAX_BATCH)]
    hand: Annotated[list[Annotated[float, msgspec.Meta(ge=-MAX_SCREEN_UNITS, le=MAX_SCREEN_UNITS)]],
                    msgspec.Meta(max_length=7 * MAX_BATCH)]

    def __post_init__(self):   # the quaternions: at once, in parse_page_message
        if len(self.valid) != len(self.time) or len(self.hand) != 7 * len(self.time):
            raise schema.Invalid(f"{len(self.time)} valid flags and {7 * len(self.time)} numbers (7 per time)",
                                 f"{len(self.valid)} and {len(self.hand)}", "hand")


class TouchesBatch(msgspec.Struct, forbid_unknown_fields=True):
    """What a served page played: per pose it computed, that pose's time and one V per motor."""

    time: Annotated[list[Millis], msgspec.Meta(max_length=MAX_BATCH)]
    intensity: Annotated[list[Intensity], msgspec.Meta(max_length=MAX_MOTORS * MAX_BATCH)]


class ButtonsMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="buttons"):
    held: Annotated[list[Literal[tuple(sorted(BUTTON_NAMES))]], msgspec.Meta(max_length=len(BUTTON_NAMES))]


class BatchMessage(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="batch"):
    poses: PosesBatch
    touches: TouchesBatch


PageMessage = Union[InputMessage, RecenterMessage, SessionMessage, StatsMessage, ResponseMessage, HapticsMessage,
                    BatchMessage, ButtonsMessage]
_DECODER = msgspec.json.Decoder(PageMessage)


class _Type(msgspec.Struct):
    type: str = ""


_TYPE = msgspec.json.Decoder(_Type)


def message_type(data) -> str:
    """A page message's "type" (as sent, unchecked; '' if it has none or is not JSON): cheap enough
    for the server's thread, which paces inputs before the node parses anything."""
    if not isinstance(data, (str, bytes)) or len(data) > MAX_PAGE_MESSAGE:
        return ""
    try:
        return _TYPE.decode(data).type
    except (msgspec.DecodeError, RecursionError):
        return ""


# C0 and C1 controls, DEL, the Unicode line and paragraph separators and the bidirectional overrides:
# what could end a log line, move a terminal's cursor or colour it, or reorder what a reader sees.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """`text` from a page, safe to log: each control character as its escape (\\n, \\x1b, \\u2028)."""
    return _CONTROL.sub(_escape, text)


def _escape(match: re.Match) -> str:
    c = match.group()
    return {"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(c) or (f"\\x{ord(c):02x}" if ord(c) <= 0xff else f"\\u{ord(c):04x}")


def _reject_constant(name: str):
    raise PageError("non_finite", f"{name} is not a number")


def parse_page_message(data: str | bytes) -> dict:
    """A page's text message -> a checked map (see the module doc); PageError says why not. `data`
    may also be the WebSocket error that ended a connection (1009: a message too big to receive)."""
    if isinstance(data, BaseException):
        if isinstance(data, TimeoutError):   # answered no ping: a page that does not read, or is gone
            raise PageError("unresponsive", f"WebSocket closed: {data}")
        too_big = getattr(data, "code", None) == WS_MESSAGE_TOO_BIG
        raise PageError("oversized" if too_big else "malformed", f"WebSocket error: {data}")
    if isinstance(data, bytes):
        raise PageError("malformed", "expected a JSON text message, got binary")
    if len(data) > MAX_PAGE_MESSAGE:   # characters <= bytes: a cheap first bound
        raise PageError("oversized", f"{len(data)} characters, at most {MAX_PAGE_MESSAGE} bytes")
    if len(data.encode()) > MAX_PAGE_MESSAGE:
        raise PageError("oversized", f"more than {MAX_PAGE_MESSAGE} bytes")
    try:
        msg = _DECODER.decode(data)
    except msgspec.ValidationError as exc:      # (a DecodeError too: first)
        raise _shape_error(data, exc) from None
    except msgspec.DecodeError as exc:
        raise _syntax_error(data, exc) from None
    if isinstance(msg, InputMessage):
        return {"type": "input", "time": msg.time, "tracking": msg.tracking, "head": _array(msg.head),
                "sources": [XRSource(s.handedness, _array(s.grip), s.trigger, tuple(dict.fromkeys(s.buttons)),
                                     None if s.joints is None else np.array(s.joints, dtype=float))
                            for s in msg.sources],
                "played": None if msg.played is None else
                {"time": msg.played.time, "intensity": np.array(msg.played.intensity, dtype=float)}}
    if isinstance(msg, RecenterMessage):
        return {"type": "recenter", "head": _array(msg.head)}
    if isinstance(msg, SessionMessage):
        return {"type": "session", "mode": msg.mode, "active": msg.active}
    if isinstance(msg, ResponseMessage):
        return {"type": "response", "index": msg.index, "option": msg.option, "time": msg.time}
    if isinstance(msg, HapticsMessage):
        return {"type": "haptics", "output": msg.output}
    if isinstance(msg, ButtonsMessage):
        return {"type": "buttons", "held": tuple(dict.fromkeys(msg.held))}
    if isinstance(msg, BatchMessage):
        p, t = msg.poses, msg.touches
        n = len(t.time)
        if (len(t.intensity) % n if n else len(t.intensity)) != 0:
            raise PageError("malformed", f"touches.intensity: expected a multiple of {n} values (one row per time), "
                                         f"got {len(t.intensity)}", "touches.intensity", f"a multiple of {n}")
        hand = np.array(p.hand, dtype=float).reshape(-1, 7)
        valid = np.array(p.valid, dtype=bool)
        norms = np.sqrt((hand[:, 3:] ** 2).sum(axis=1))
        bad = np.flatnonzero(valid & ~(np.abs(norms - 1.0) <= QUAT_TOLERANCE))
        if len(bad):   # a tracked pose's orientation (an untracked one's is not read)
            k = int(bad[0])
            raise PageError("malformed", f"poses.hand[{k}]: expected a unit quaternion (norm {norms[k]:.4g})",
                            f"poses.hand[{k}]", "a unit quaternion", hand[k].tolist())
        return {"type": "batch", "time": np.array(p.time, dtype=float), "valid": valid,
                "position": hand[:, :3], "orientation": hand[:, 3:],
                "touch_time": np.array(t.time, dtype=float),
                "intensity": np.array(t.intensity, dtype=float).reshape(n, -1) if n else np.zeros((0, 0))}
    paced = {k: v for k, v in (("scale", msg.scale), ("foveation", msg.foveation)) if v is not None}
    return {"type": "stats", "fps": msg.fps, **paced}


def _array(pose) -> np.ndarray | None:
    return None if pose is None else np.array(pose, dtype=float)


def _syntax_error(data: str, exc: msgspec.DecodeError) -> PageError:
    """Not JSON: NaN or Infinity (which JavaScript's JSON.stringify never writes) count as non_finite."""
    try:
        json.loads(data, parse_constant=_reject_constant)
    except PageError as non_finite:
        return non_finite
    except (ValueError, RecursionError):
        pass
    return PageError("malformed", f"not JSON: {exc}")


def _shape_error(data: str, exc: msgspec.ValidationError) -> PageError:
    """A message of the wrong shape: its field, what was expected and what it got."""
    try:
        raw = json.loads(data)                  # a number too large for a float (1e999) reads inf here
        where = _non_finite(raw)
    except (ValueError, RecursionError):
        raw = where = None
    if where is not None:                       # msgspec's JSON refuses it before any field is looked at
        return PageError("non_finite", f"{where}: expected a finite number", where, "a finite number")
    err: ConfigError = schema.error_of(exc, raw, PageMessage)
    text = f"{err.key}: expected {err.expected}" + ("" if err.got is None else f", got {err.got!r}"[:120])
    if err.hint:
        text += f" ({err.hint})"
    return PageError("malformed", text, err.key, err.expected, err.got)


def _non_finite(value, key: str = "") -> str | None:
    """The key path of the first number in decoded JSON that is not finite, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return key or "(top level)"
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        found = _non_finite(v, schema.join(key, f"[{k}]" if isinstance(value, list) else str(k)))
        if found is not None:
            return found
    return None

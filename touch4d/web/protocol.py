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
  `draw_objects` (false: the study's condition hides every object; touch4d.study.gate);
- "calibration", after a re-centre: the screen's new placement in the room.

Page -> node: UTF-8 JSON text, at most MAX_PAGE_MESSAGE bytes, no NaN or infinity (rejected here):

    {"type": "input", "time": ms, "tracking": bool, "head": pose|null, "sources": [source, ...]}
    {"type": "recenter", "head": pose}
    {"type": "session", "mode": "immersive"|"inline", "active": bool}
    {"type": "stats", "fps": number}
    {"type": "response", "index": int, "option": str, "time": ms}

where a "response" answers a study's trial `index` with one of its options from the page's own
buttons (a tap in a desktop or headset browser; controller buttons arrive with "input");
`time` is the page's clock (performance.timeOrigin + performance.now(), ms) when it read the
poses, a pose is [x, y, z, qx, qy, qz, qw] (metres, local-floor space), and a source is
{"handedness": "right"|"left"|"none", "grip": pose|null, "trigger": 0..1, "buttons": [name, ...],
"joints": [[x, y, z, qx, qy, qz, qw, radius] x 25]|null}.
"""
from __future__ import annotations

import json
import math
import struct

import numpy as np

from touch4d.tracking.webxr import JOINTS, XR_STANDARD_BUTTONS, XRSource

ARRAY_DTYPES = ("f4", "u4", "i4", "u2", "u1")
MAX_PAGE_MESSAGE = 16384          # bytes: an input message with two tracked hands is about 6 kB
MAX_SOURCES = 4
QUAT_TOLERANCE = 1e-2             # |q| - 1 allowed in a page's quaternion (float32 poses)
WS_MESSAGE_TOO_BIG = 1009        # the WebSocket close code (RFC 6455)
PAGE_TYPES = ("input", "recenter", "session", "stats", "response")
MAX_OPTION = 64                   # characters of a response option
HANDEDNESS = ("right", "left", "none")
BUTTON_NAMES = frozenset(b for b in XR_STANDARD_BUTTONS if b)
_LEN = struct.Struct("<I")


class PageError(ValueError):
    """A page message that is dropped; `cause` is its counter's name: malformed, oversized or non_finite."""

    def __init__(self, cause: str, detail: str):
        super().__init__(detail)
        self.cause = cause


# ---- node -> page ----------------------------------------------------------------------------------


def pack_frame(kind: str, fields: dict | None = None, arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """One binary frame: a JSON header (kind, fields, array table) then the arrays, 8-byte aligned."""
    arrays = arrays or {}
    table, blobs = {}, []
    clean = {}
    for name, arr in arrays.items():
        arr = np.ascontiguousarray(arr)
        dtype = arr.dtype.newbyteorder("<").str[1:]
        if dtype not in ARRAY_DTYPES:
            raise ValueError(f"array {name!r}: dtype {arr.dtype} is not one of {', '.join(ARRAY_DTYPES)}")
        clean[name] = arr.astype(arr.dtype.newbyteorder("<"), copy=False)
        table[name] = [dtype, list(arr.shape), 0]
    # The offsets depend on the header's length, which depends on the offsets' digits: two passes.
    for _ in range(2):
        header = json.dumps({"kind": kind, **(fields or {}), "arrays": table}, separators=(",", ":"),
                            allow_nan=False).encode()
        offset = _align(_LEN.size + len(header))
        for name, arr in clean.items():
            table[name][2] = offset
            offset = _align(offset + arr.nbytes)
    header = json.dumps({"kind": kind, **(fields or {}), "arrays": table}, separators=(",", ":"),
                        allow_nan=False).encode()
    out = bytearray(_LEN.pack(len(header)) + header)
    for name, arr in clean.items():
        out += bytes(table[name][2] - len(out))
        out += arr.tobytes()
    out += bytes(_align(len(out)) - len(out))
    return bytes(out)


def unpack_frame(data: bytes) -> tuple[dict, dict[str, np.ndarray]]:
    """A frame back into (header fields, arrays) — what the page does with typed-array views."""
    (n,) = _LEN.unpack_from(data, 0)
    header = json.loads(data[_LEN.size:_LEN.size + n])
    arrays = {}
    for name, (dtype, shape, offset) in header.pop("arrays").items():
        count = int(np.prod(shape)) if shape else 1
        arrays[name] = np.frombuffer(data, dtype="<" + dtype, count=count, offset=offset).reshape(shape)
    return header, arrays


def _align(n: int) -> int:
    return (n + 7) & ~7


# ---- page -> node ----------------------------------------------------------------------------------


def _reject_constant(name: str):
    raise PageError("non_finite", f"{name} is not a number")


def parse_page_message(data: str | bytes) -> dict:
    """A page's text message -> a checked map (see the module doc); PageError says why not. `data`
    may also be the WebSocket error that ended a connection (1009: a message too big to receive)."""
    if isinstance(data, BaseException):
        too_big = getattr(data, "code", None) == WS_MESSAGE_TOO_BIG
        raise PageError("oversized" if too_big else "malformed", f"WebSocket error: {data}")
    if isinstance(data, bytes):
        raise PageError("malformed", "expected a JSON text message, got binary")
    if len(data) > MAX_PAGE_MESSAGE:   # characters <= bytes: a cheap first bound
        raise PageError("oversized", f"{len(data)} characters, at most {MAX_PAGE_MESSAGE} bytes")
    if len(data.encode()) > MAX_PAGE_MESSAGE:
        raise PageError("oversized", f"more than {MAX_PAGE_MESSAGE} bytes")
    try:
        msg = json.loads(data, parse_constant=_reject_constant)
    except PageError:
        raise
    except (ValueError, RecursionError) as exc:
        raise PageError("malformed", f"not JSON: {exc}") from None
    if not isinstance(msg, dict):
        raise PageError("malformed", f"expected a JSON object, got {type(msg).__name__}")
    kind = msg.get("type")
    if kind not in PAGE_TYPES:
        raise PageError("malformed", f"type: expected one of {', '.join(PAGE_TYPES)}, got {kind!r}")
    if kind == "input":
        return {"type": "input", "time": _number(msg, "time", 0.0, math.inf),
                "tracking": _bool(msg, "tracking"), "head": _pose(msg.get("head"), "head", optional=True),
                "sources": _sources(msg.get("sources"))}
    if kind == "recenter":
        return {"type": "recenter", "head": _pose(msg.get("head"), "head")}
    if kind == "session":
        mode = msg.get("mode")
        if mode not in ("immersive", "inline"):
            raise PageError("malformed", f"mode: expected immersive or inline, got {mode!r}")
        return {"type": "session", "mode": mode, "active": _bool(msg, "active")}
    if kind == "response":
        index, option = msg.get("index"), msg.get("option")
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < 2**31:
            raise PageError("malformed", f"index: expected a trial index (an integer >= 0), got {index!r}")
        if not isinstance(option, str) or len(option) > MAX_OPTION:
            raise PageError("malformed", f"option: expected a string of at most {MAX_OPTION} characters")
        return {"type": "response", "index": index, "option": option, "time": _number(msg, "time", 0.0, math.inf)}
    return {"type": "stats", "fps": _number(msg, "fps", 0.0, 1000.0)}


def _number(msg: dict, key: str, lo: float, hi: float) -> float:
    value = msg.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PageError("malformed", f"{key}: expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise PageError("non_finite", f"{key}: not finite")
    if not lo <= value <= hi:
        raise PageError("malformed", f"{key}: expected {lo:g}..{hi:g}, got {value:g}")
    return value


def _bool(msg: dict, key: str) -> bool:
    value = msg.get(key)
    if not isinstance(value, bool):
        raise PageError("malformed", f"{key}: expected true or false, got {type(value).__name__}")
    return value


def _floats(value, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A nested JSON list of numbers of exactly `shape` as float64, every value finite."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise PageError("malformed", f"{where}: expected numbers of shape {shape}") from None
    if arr.shape != shape:
        raise PageError("malformed", f"{where}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise PageError("non_finite", f"{where}: not finite")
    # np.array turns true/false and numeric strings into numbers: only real JSON numbers pass.
    flat = value if len(shape) == 1 else [x for row in value for x in row]
    if not all(type(x) in (int, float) for x in flat):
        raise PageError("malformed", f"{where}: expected numbers only")
    return arr


def _pose(value, where: str, optional: bool = False) -> np.ndarray | None:
    if value is None and optional:
        return None
    pose = _floats(value, (7,), where)
    _check_quaternion(pose[3:7], where)
    return pose


def _check_quaternion(q: np.ndarray, where: str) -> None:
    norm = math.sqrt(float(q @ q))
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        raise PageError("malformed", f"{where}: quaternion norm {norm:.4g}, expected 1")


def _sources(value) -> list[XRSource]:
    if not isinstance(value, list) or len(value) > MAX_SOURCES:
        raise PageError("malformed", f"sources: expected a list of at most {MAX_SOURCES}")
    out = []
    for i, item in enumerate(value):
        where = f"sources[{i}]"
        if not isinstance(item, dict):
            raise PageError("malformed", f"{where}: expected an object")
        handedness = item.get("handedness")
        if handedness not in HANDEDNESS:
            raise PageError("malformed", f"{where}.handedness: expected one of {', '.join(HANDEDNESS)}")
        grip = _pose(item.get("grip"), f"{where}.grip", optional=True)
        trigger = _number(item, "trigger", 0.0, 1.0)
        buttons = item.get("buttons")
        if not isinstance(buttons, list) or not all(b in BUTTON_NAMES for b in buttons):
            raise PageError("malformed", f"{where}.buttons: expected names among {', '.join(sorted(BUTTON_NAMES))}")
        joints = item.get("joints")
        if joints is not None:
            joints = _floats(joints, (len(JOINTS), 8), f"{where}.joints")
            for k in range(len(JOINTS)):
                _check_quaternion(joints[k, 3:7], f"{where}.joints[{k}]")
            if (joints[:, 7] < 0).any():
                raise PageError("malformed", f"{where}.joints: negative radius")
        out.append(XRSource(handedness, grip, trigger, tuple(dict.fromkeys(buttons)), joints))
    return out

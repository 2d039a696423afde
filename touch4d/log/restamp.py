"""Re-stamping a replayed message in its encoded bytes: only the header values change.

A replayed message goes out as if made now: `stamp` = now, `source_stamp` moved by the same amount
(so latencies derived downstream stay true), a fresh `seq`, and `recorded_stamp` = the stamp it had
when recorded (kept when already set: a log recorded from a replay still names the first recording).
The msgpack map is patched rather than decoded and encoded again, so every other byte stays as
recorded (arrays, key order, another encoder's choices) and a large message costs only a walk over
its keys.
"""
from __future__ import annotations

import math
import struct

import msgpack

from touch4d.messages.header import NAMES, RECORDED_STAMP, SEQ, SOURCE_STAMP, STAMP

_HEADER = frozenset(NAMES)
_FLOAT64 = struct.Struct(">d")
_RECORDED_KEY = msgpack.packb(RECORDED_STAMP)


def _float64(value: float) -> bytes:
    return b"\xcb" + _FLOAT64.pack(value)


def _map_header(length: int) -> bytes:
    if length < 16:
        return bytes((0x80 | length,))
    return b"\xde" + struct.pack(">H", length) if length < 1 << 16 else b"\xdf" + struct.pack(">I", length)


def _is_time(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0


def header_spans(payload: bytes) -> tuple[int, int, dict[str, tuple[int, int, object]]]:
    """(map length, where the map's keys begin, {header key: (value start, value end, value)}).

    Raises ValueError (or msgpack's errors) when `payload` is not exactly one msgpack map."""
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=False)
    unpacker.feed(payload)
    length = unpacker.read_map_header()
    body = unpacker.tell()
    found: dict[str, tuple[int, int, object]] = {}
    for _ in range(length):
        key = unpacker.unpack()
        start = unpacker.tell()
        if isinstance(key, str) and key in _HEADER:
            value = unpacker.unpack()
            found[key] = (start, unpacker.tell(), value)
        else:
            unpacker.skip()  # arrays and the like: stepped over, never decoded
    if unpacker.tell() != len(payload):
        raise ValueError("bytes after the message map")
    return length, body, found


def restamp(payload: bytes, now: float, seq: int) -> bytes | None:
    """`payload` stamped `now` with sequence number `seq`, its recorded stamp kept in `recorded_stamp`;
    None if it is not a message map with a stamp (it is then sent as recorded)."""
    try:
        length, body, found = header_spans(payload)
    except Exception:  # noqa: BLE001 - msgpack raises many types for bytes that are not one map
        return None
    if STAMP not in found or not _is_time(found[STAMP][2]):
        return None
    recorded = float(found[STAMP][2])
    edits = [found[STAMP][:2] + (_float64(now),)]
    if SEQ in found:
        edits.append(found[SEQ][:2] + (msgpack.packb(seq),))
    if SOURCE_STAMP in found and _is_time(found[SOURCE_STAMP][2]):
        # now - (stamp - source_stamp): exactly `now` for a message that originates (source = stamp)
        edits.append(found[SOURCE_STAMP][:2] + (_float64(now - (recorded - found[SOURCE_STAMP][2])),))
    header = payload[:body]
    if RECORDED_STAMP not in found:
        # right after the header values: where the encoder puts it, so the bytes are as it would make them
        at = max(end for _, end, _ in found.values())
        edits.append((at, at, _RECORDED_KEY + _float64(recorded)))
        header = _map_header(length + 1)
    elif not _is_time(found[RECORDED_STAMP][2]):
        edits.append(found[RECORDED_STAMP][:2] + (_float64(recorded),))
    edits.sort(key=lambda edit: edit[:2])
    out, pos = [header], body
    for start, end, data in edits:
        out += (payload[pos:start], data)
        pos = end
    out.append(payload[pos:])
    return b"".join(out)

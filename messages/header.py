"""The header every message carries (stamp, seq, source_stamp, recorded_stamp): declared here once,
for the messages (`Header`, the base of `Message`), the log writer (`peek`: the header of a payload
without decoding the rest) and the replay's re-stamping (`NAMES`, the header keys in wire order)."""
import math
import sys
from typing import Annotated

import msgpack
import msgspec

# A finite float: NaN and the infinities are out of range.
Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]

STAMP, SEQ, SOURCE_STAMP, RECORDED_STAMP = "stamp", "seq", "source_stamp", "recorded_stamp"
NAMES = (STAMP, SEQ, SOURCE_STAMP, RECORDED_STAMP)   # after "type", in this order, in every payload
OPTIONAL = (RECORDED_STAMP,)                          # left out of a payload while 0 (a live message)
DOCS = {
    STAMP: "wall-clock time the message was made, seconds (time.time()); set on publish",
    SEQ: "per-topic, per-publisher sequence number from 0; a gap means a drop; set on publish",
    SOURCE_STAMP: "stamp of the hand/pose this message was derived from (= stamp for originating messages)",
    RECORDED_STAMP: "stamp this message had when it was recorded, kept when a replay re-stamps it; 0 = live",
}


class Header(msgspec.Struct, kw_only=True, omit_defaults=True):
    """The header fields as the messages declare them (see `Message`): every one checked on decode,
    `recorded_stamp` the only one a payload may leave out."""

    stamp: Finite
    seq: int
    source_stamp: Finite
    recorded_stamp: Finite = 0.0


class _Peeked(msgspec.Struct):
    """The header keys of a message map as a log writer reads them (a finite stamp >= 0, a seq >= 0);
    msgspec steps over every other field without decoding it."""

    type: str
    stamp: Annotated[float, msgspec.Meta(ge=0.0, le=sys.float_info.max)] = 0.0
    seq: Annotated[int, msgspec.Meta(ge=0)] = -1


peek_fast = msgspec.msgpack.Decoder(_Peeked).decode   # raises msgspec.DecodeError: then `peek_any`


def peek(payload: bytes) -> tuple[str, float, int] | None:
    """(type, stamp, seq) of a payload without decoding the rest; None if it is not a message map.

    A stamp that is not a finite number >= 0 reads 0.0, a seq that is not an integer >= 0 reads -1."""
    try:
        header = peek_fast(payload)  # a recorder's hot path: one C call
    except msgspec.DecodeError:  # odd values, cut short, bytes after the map: looked at key by key
        return peek_any(payload)
    return header.type, header.stamp, header.seq


def peek_any(payload: bytes) -> tuple[str, float, int] | None:
    """`peek` for payloads of any shape, with msgpack's streaming unpacker."""
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=False)
    unpacker.feed(payload)
    data: dict = {}
    try:
        for _ in range(unpacker.read_map_header()):
            key = unpacker.unpack()
            if key in ("type", STAMP, SEQ):
                data[key] = unpacker.unpack()
            else:
                unpacker.skip()
    except msgpack.OutOfData:
        pass  # cut short: the keys before the cut
    except Exception:  # noqa: BLE001 - any garbage: recorded as is, counted as malformed
        return None
    if not isinstance(data.get("type"), str):
        return None
    stamp, seq = data.get(STAMP), data.get(SEQ)
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float)) or not math.isfinite(stamp) or stamp < 0:
        stamp = 0.0
    if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
        seq = -1
    return data["type"], float(stamp), seq

"""The study server's wire trace: rows written from real page messages and frames (and from their
bytes on the wire), and pose -> pulse paired from a known synthetic trace."""
import asyncio
import csv
import json
from types import SimpleNamespace

import numpy as np
from aiohttp import WSMsgType
from aiohttp.http import WebSocketWriter

from touch4d.web.protocol import pack_frame
from touch4d.web.wiretrace import Move, WireTrace, pose_to_pulse


def write(path, rows):
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_rows_from_page_inputs_and_frames(tmp_path):
    trace = WireTrace(tmp_path / "t.csv")
    trace.page_in("P01", json.dumps({"type": "input", "time": 1234.5678901, "tracking": True, "head": None,
                                     "sources": []}))
    trace.page_in("P01", json.dumps({"type": "stats", "fps": 72}))          # not an input: no row
    trace.page_in("P01", "{not json")                                         # refused downstream: no row
    trace.page_in("P01", '{"type":"input","time":1e}')                       # not a number: no row, no error
    trace.frame_out("P01", pack_frame("frame", {"n": 1, "haptic": 0.75}, {"h": np.zeros(3, np.float32)}))
    trace.frame_out("P01", pack_frame("setup", {"tracker": True}))             # not a frame: no row
    trace.close()
    rows = list(csv.reader(open(tmp_path / "t.csv", newline="")))
    assert [r[:3] for r in rows] == [["P01", "in", "1234.5678901"], ["P01", "out", "0.75"]]
    assert int(rows[0][3]) <= int(rows[1][3])


def test_pairs_each_move_with_the_first_following_frame(tmp_path):
    ms = 1_000_000   # ns
    write(tmp_path / "t.csv", [
        ("A", "out", "0.0", 0),
        ("A", "in", "100.0", 10 * ms),           # A moves in
        ("A", "out", "0.0", 12 * ms),            # not yet
        ("B", "in", "100.0", 13 * ms),           # B, same page time: another participant
        ("A", "out", "0.6", 17 * ms),            # A's touch: 7 ms
        ("A", "in", "200.0", 30 * ms),           # A moves out
        ("A", "out", "0.02", 31 * ms),           # fading, not 0 yet
        ("A", "out", "0.0", 39 * ms),            # 9 ms
        ("B", "out", "0.04", 40 * ms),           # below the touch
        ("B", "out", "0.3", 43 * ms),            # B's touch: 30 ms
    ])
    moves = [Move("A", 100.0, True), Move("B", 100.0, True), Move("A", 200.0, False),
             Move("B", 999.0, False), Move("A", 300.0, True)]   # never arrived; arrived without a frame
    latencies, missed = pose_to_pulse(tmp_path / "t.csv", moves)
    assert np.allclose(latencies, [0.007, 0.030, 0.009])
    assert missed == 2


class _Wire:
    """A transport that keeps what aiohttp's WebSocket writer writes."""

    def __init__(self):
        self.data = bytearray()

    def write(self, data):
        self.data += data

    def is_closing(self):
        return False


def _wire(masked: bool, messages) -> bytes:
    """The bytes of `messages` (str: text, bytes: binary) as aiohttp's writer frames them."""
    wire = _Wire()
    writer = WebSocketWriter(SimpleNamespace(_paused=False), wire, use_mask=masked)

    async def send():
        for m in messages:
            await writer.send_frame(m.encode() if isinstance(m, str) else m,
                                    WSMsgType.TEXT if isinstance(m, str) else WSMsgType.BINARY)
    asyncio.run(send())
    return bytes(wire.data)


def test_rows_from_spliced_bytes_each_message_at_its_last_byte(tmp_path):
    trace = WireTrace(tmp_path / "t.csv")
    page = _wire(True, [json.dumps({"type": "input", "time": 1.5}), json.dumps({"type": "stats"}),
                        json.dumps({"type": "input", "time": 2.5, "pad": "x" * 9000})])   # a 16-bit length
    frames = _wire(False, [pack_frame("frame", {"haptic": 0.5}), pack_frame("setup", {}),
                           pack_frame("frame", {"haptic": 0.0}, {"h": np.zeros(20000, np.float32)})])
    into, out = trace.page_bytes("P01"), trace.frame_bytes("P01")
    rows = lambda: list(csv.reader(open(tmp_path / "t.csv", newline="")))  # noqa: E731
    for i in range(len(page)):          # a byte at a time: a message is read when its last byte is
        into(page[i:i + 1])
    out(frames[:7])
    out(frames[7:])
    trace._file.flush()
    assert [r[:3] for r in rows()] == [["P01", "in", "1.5"], ["P01", "in", "2.5"], ["P01", "out", "0.5"],
                                       ["P01", "out", "0.0"]]
    into(b"\x81\x7e\xff\xff" + b"\0" * 65535)  # a text message over the page's limit: no row, no error,
    into(page)                                     # and nothing more read from that connection
    trace.close()
    assert len(rows()) == 4

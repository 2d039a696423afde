"""The page protocol: binary frames keep arrays exactly and aligned; page messages are checked, and
malformed, oversized or NaN-bearing ones are rejected with the counter they belong to."""
import json

import numpy as np
import pytest

from touch4d.web.protocol import (MAX_PAGE_MESSAGE, PageError, json_members, pack_frame, parse_page_message,
                                  unpack_frame)

GRIP = [0.1, 1.2, -0.4, 0.0, 0.0, 0.0, 1.0]


def joints(n=25):
    return [[0.01 * k, 1.0, -0.3, 0.0, 0.0, 0.0, 1.0, 0.01] for k in range(n)]


def source(**over):
    out = {"handedness": "right", "grip": GRIP, "trigger": 0.25, "buttons": ["a"], "joints": None}
    out.update(over)
    return out


def input_message(**over):
    msg = {"type": "input", "time": 1.7e12, "tracking": True, "head": [0, 1.6, 0, 0, 0, 0, 1], "sources": [source()]}
    msg.update(over)
    return json.dumps(msg)


def test_frame_round_trip_keeps_dtype_shape_values_and_8_byte_alignment():
    arrays = {"a": np.arange(7, dtype=np.float32).reshape(7, 1), "b": np.array([1, 2, 3], np.uint32),
              "c": np.array([1, 0, 1], np.uint8), "d": np.arange(12, dtype=np.float32).reshape(2, 2, 3)}
    data = pack_frame("frame", {"n": 3, "name": "x"}, arrays)
    header, back = unpack_frame(data)
    assert header == {"kind": "frame", "n": 3, "name": "x"}
    for name, arr in arrays.items():
        assert back[name].dtype == arr.dtype and back[name].shape == arr.shape
        np.testing.assert_array_equal(back[name], arr)
    table = json.loads(data[4:4 + int.from_bytes(data[:4], "little")])["arrays"]
    assert all(offset % 8 == 0 for _, _, offset in table.values())
    assert len(data) % 8 == 0


@pytest.mark.parametrize("pad", [0, 1, 5, 37, 90, 9000])
def test_frame_arrays_start_right_after_the_header_whatever_its_length(pad):
    # the header's length moves the arrays' offsets, whose digits move the header's length
    arrays = {f"a{k}": np.full(1000 * k + 1, k, np.float32) for k in range(12)}
    data = pack_frame("frame", {"text": "x" * pad}, arrays)
    length = int.from_bytes(data[:4], "little")
    table = json.loads(data[4:4 + length])["arrays"]
    first = min(offset for _, _, offset in table.values())
    assert first == (4 + length + 7) // 8 * 8          # no gap, no overlap: the next 8-byte boundary
    header, back = unpack_frame(data)
    assert header["text"] == "x" * pad
    for name, arr in arrays.items():
        np.testing.assert_array_equal(back[name], arr)


def test_frames_of_one_kind_shrinking_and_growing_each_start_their_arrays_right_after_the_header():
    # each frame's first guess is the last one's layout: a stale guess must never leave a gap
    arrays = {"a": np.arange(5, dtype=np.float32), "b": np.arange(3, dtype=np.int32)}
    for pad in (9000, 0, 300, 1, 9000, 9000, 2):
        data = pack_frame("shrinking", {"text": "x" * pad}, arrays)
        length = int.from_bytes(data[:4], "little")
        table = json.loads(data[4:4 + length])["arrays"]
        assert table["a"][2] == (4 + length + 7) // 8 * 8 and table["b"][2] == table["a"][2] + 24
        header, back = unpack_frame(data)
        assert header["text"] == "x" * pad
        np.testing.assert_array_equal(back["a"], arrays["a"])
        np.testing.assert_array_equal(back["b"], arrays["b"])


def test_fields_encoded_beforehand_read_as_the_frames_own():
    steady = {"study": {"prompt": "Which?", "options": ["a", "b"]}, "boards": [], "eye": 2.5, "view": None}
    arrays = {"h": np.arange(5, dtype=np.float32)}
    header, back = unpack_frame(pack_frame("frame", {"n": 4, "time": 12.5}, arrays, json_members(steady)))
    assert header == {"kind": "frame", "n": 4, "time": 12.5, **steady}
    np.testing.assert_array_equal(back["h"], arrays["h"])
    assert unpack_frame(pack_frame("frame", None, None, json_members({"x": 1})))[0] == {"kind": "frame", "x": 1}
    with pytest.raises(ValueError):
        json_members({"t": float("inf")})


def test_frame_refuses_float64_and_nan_fields():
    with pytest.raises(ValueError, match="dtype"):
        pack_frame("frame", {}, {"x": np.zeros(3)})
    with pytest.raises(ValueError):
        pack_frame("frame", {"t": float("nan")})


def test_a_controller_input_is_parsed():
    msg = parse_page_message(input_message())
    assert msg["type"] == "input" and msg["tracking"] is True and msg["time"] == 1.7e12
    (s,) = msg["sources"]
    assert s.handedness == "right" and s.trigger == 0.25 and s.buttons == ("a",) and s.joints is None
    np.testing.assert_array_equal(s.grip, GRIP)


def test_a_tracked_hand_is_parsed():
    msg = parse_page_message(input_message(sources=[source(grip=None, joints=joints())]))
    assert msg["sources"][0].joints.shape == (25, 8)


@pytest.mark.parametrize("text, cause", [
    ("{not json", "malformed"),
    ("[1, 2]", "malformed"),
    ('{"type": "launch-missiles"}', "malformed"),
    (input_message(time="now"), "malformed"),
    (input_message(tracking=1), "malformed"),
    (input_message(head=[0, 1, 0, 0, 0, 0]), "malformed"),
    (input_message(head=[0, 1, 0, 0, 0, 0, 2]), "malformed"),                       # not a unit quaternion
    (input_message(sources=[source(trigger=1.5)]), "malformed"),
    (input_message(sources=[source(buttons=["self-destruct"])]), "malformed"),
    (input_message(sources=[source(handedness="third")]), "malformed"),
    (input_message(sources=[source(grip=[0, "1", 0, 0, 0, 0, 1])]), "malformed"),
    (input_message(sources=[source(grip=[0, True, 0, 0, 0, 0, 1])]), "malformed"),
    (input_message(sources=[source(joints=joints(24))]), "malformed"),
    (input_message(sources=[source()] * 5), "malformed"),
    (input_message().replace("1.2", "NaN"), "non_finite"),
    (input_message().replace("1.2", "Infinity"), "non_finite"),
    (input_message().replace("1.2", "1e999"), "non_finite"),
    (input_message(time=float("-inf")), "non_finite"),          # json.dumps writes -Infinity
    ("x" * (MAX_PAGE_MESSAGE + 1), "oversized"),
    ("é" * (MAX_PAGE_MESSAGE // 2 + 1), "oversized"),                               # bytes, not characters
    (b"\x00\x01binary", "malformed"),
    ("[" * 100000 + "]" * 100000, "oversized"),
])
def test_bad_page_messages_are_rejected_with_their_cause(text, cause):
    with pytest.raises(PageError) as info:
        parse_page_message(text)
    assert info.value.cause == cause


def test_deep_nesting_within_the_size_limit_is_malformed_not_a_crash():
    with pytest.raises(PageError) as info:
        parse_page_message("[" * 8000 + "]" * 8000)
    assert info.value.cause == "malformed"


def test_a_websocket_error_1009_counts_as_oversized():
    class TooBig(Exception):
        code = 1009

    with pytest.raises(PageError) as info:
        parse_page_message(TooBig("message too big"))
    assert info.value.cause == "oversized"


def test_other_page_messages():
    assert parse_page_message('{"type": "stats", "fps": 72.5}') == {"type": "stats", "fps": 72.5}
    assert parse_page_message('{"type": "session", "mode": "immersive", "active": true}')["active"] is True
    head = parse_page_message('{"type": "recenter", "head": [0, 1.6, 0, 0, 0, 0, 1]}')["head"]
    np.testing.assert_array_equal(head, [0, 1.6, 0, 0, 0, 0, 1])


def test_a_frames_kind_and_header_are_found_without_parsing_it():
    from touch4d.web.protocol import header_span, is_kind
    data = pack_frame("frame", {"haptic": 0.5}, {"h": np.arange(3, dtype=np.float32)})
    n = int.from_bytes(data[:4], "little")                  # the layout: a uint32 length, then the JSON header
    assert header_span(data) == (4, 4 + n)
    assert json.loads(data[4:4 + n])["haptic"] == 0.5
    assert is_kind(data, "frame") and not is_kind(data, "geometry") and not is_kind(data[:3], "frame")
    assert is_kind(pack_frame("geometry", {"key": "g1"}), "geometry")

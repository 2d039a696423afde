"""The generated fast paths of the messages (messages/compiled.py) against the reference code of
messages/base.py: the same messages and the same errors for valid and broken payloads, the same
payloads published (and nothing touched when publishing fails), the wire readable by another msgpack
implementation, large arrays decoded without a copy."""
import time
from contextlib import contextmanager
from dataclasses import dataclass

import msgpack
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from touch4d.messages import TYPES, HandPose, Message, MessageError, MotorCommand, TactileField, decode, decoder
from touch4d.messages.base import Array, Float, Str, spec
from touch4d.messages.codec import pack, unpack
from touch4d.messages.compiled import FastPaths, compile_class

from test_messages import EXAMPLES


def same(a: Message, b: Message) -> bool:
    """Field by field equality (arrays: dtype, shape and values, NaN equal to NaN)."""
    if type(a) is not type(b):
        return False
    for name in a.field_docs():
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not (isinstance(y, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape
                    and np.array_equal(x, y, equal_nan=True)):
                return False
        elif name == "objects":
            if len(x) != len(y) or any(p.keys() != q.keys() for p, q in zip(x, y)):
                return False
        elif x != y:
            return False
    return True


def reference_decode(payload: bytes, cls: type[Message]):
    """What base.py alone makes of a payload: the message, or the MessageError's text."""
    try:
        data = unpack(payload)
        if not isinstance(data, dict) or data.get("type") != cls.TYPE:
            return "not a " + cls.TYPE
        return cls.from_dict(data)
    except (MessageError, ValueError) as exc:
        return str(exc)


def outcome(payload: bytes, cls: type[Message]):
    """decode(payload, cls), or its error's text; a subscription's decoder() must say the same."""
    try:
        got = decode(payload, cls)
    except MessageError as exc:
        got = str(exc)
    try:
        by_decoder = decoder(cls)(payload)
    except MessageError as exc:
        by_decoder = str(exc)
    assert by_decoder == got if isinstance(got, str) else same(by_decoder, got)
    return got


def _decline(*_args):
    return None


@contextmanager
def reference_only(cls: type[Message]):
    """The class's generated code switched off (but the coercion of new messages): base.py alone."""
    cls.prepare()
    saved = cls.__dict__["_FAST"]
    cls._FAST = FastPaths(coerce=saved.coerce, validate=lambda msg: False, encode=_decline, publish=_decline,
                          from_dict=_decline, decode=_decline)
    try:
        yield
    finally:
        cls._FAST = saved


def published(msg: Message, seq: int):
    """msg.publish_payload(seq) decoded, or the error's text."""
    try:
        return unpack(msg.publish_payload(seq))
    except MessageError as exc:
        return str(exc)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_every_fast_path_takes_a_valid_message(msg):
    fast = compile_class(type(msg))
    assert fast.validate(msg) is True
    payload = fast.encode(msg)
    assert payload is not None
    back = fast.decode(payload)
    assert back is not None and same(back, msg)
    # the fast encoding and the reference encoding are the same map
    assert same(type(msg).from_dict(unpack(pack(msg.to_dict()))), back)
    data = unpack(payload)
    del data["type"]
    assert same(fast.from_dict(data), msg)
    fresh, reference = type(msg).from_dict(dict(data)), type(msg).from_dict(dict(data))
    sent = fast.publish(fresh, 41)   # the message is stamped and numbered as a publisher sends it
    assert sent is not None and fresh.seq == 41 and fresh.stamp and fresh.source_stamp
    assert same(fast.decode(sent), fresh)
    with reference_only(type(msg)):
        reference.stamp, reference.source_stamp = fresh.stamp, fresh.source_stamp   # the fast run's stamps
        assert same(decode(reference.publish_payload(41)), fast.decode(sent))


@settings(max_examples=300, deadline=None)
@given(
    stamp=st.one_of(st.floats(), st.integers(-5, 5), st.booleans(), st.text(max_size=2)),
    seq=st.one_of(st.integers(-2, 2**64 - 1), st.floats(allow_nan=False), st.booleans()),
    position=st.one_of(
        st.lists(st.floats(width=64), min_size=2, max_size=4).map(np.array),
        st.lists(st.integers(-3, 3), min_size=3, max_size=3).map(np.array),
        st.lists(st.floats(width=32), min_size=3, max_size=3).map(lambda v: np.array(v, np.float32)),
        st.just([0.0, 0.0, 0.0]), st.just("abc")),
    norm=st.sampled_from([1.0, 1.0005, 0.5, float("nan")]),
    valid=st.one_of(st.booleans(), st.integers(0, 1)),
    extra=st.sampled_from([None, "extra", "type"]),
    missing=st.sampled_from([None, "valid", "position"]),
)
@example(stamp=1.0, seq=0, position=np.array([0.0, np.inf, 0.0]), norm=1.0, valid=True, extra=None, missing=None)
@example(stamp=1.0, seq=0, position=np.zeros(3), norm=float("nan"), valid=False, extra=None, missing=None)
@example(stamp=1.0, seq=0, position=np.zeros(3, np.int64), norm=1.0, valid=True, extra=None, missing=None)
def test_fast_decoding_agrees_with_the_reference_on_any_pose_payload(stamp, seq, position, norm, valid, extra,
                                                                      missing):
    data = {"type": "HandPose", "stamp": stamp, "seq": seq, "source_stamp": 1.0, "position": position,
            "orientation": np.array([0.0, 0.0, 0.6, 0.8]) * norm, "valid": valid}
    if extra == "extra":
        data["extra"] = 1
    if missing:
        del data[missing]
    payload = pack(data)
    want, got = reference_decode(payload, HandPose), outcome(payload, HandPose)
    if isinstance(want, str):
        assert got == want
    else:
        assert same(got, want)


@settings(max_examples=150, deadline=None)
@given(names=st.lists(st.one_of(st.text(max_size=3), st.integers(-2**63, 2**63 - 1)), max_size=4),
       intensity=st.lists(st.floats(width=64), max_size=4))
def test_fast_decoding_agrees_with_the_reference_on_any_motor_command(names, intensity):
    payload = pack({"type": "MotorCommand", "stamp": 2.0, "seq": 0, "source_stamp": 2.0, "names": names,
                    "intensity": np.array(intensity, dtype=float)})
    want, got = reference_decode(payload, MotorCommand), outcome(payload, MotorCommand)
    if isinstance(want, str):
        assert got == want
    else:
        assert same(got, want)


_ANY_NUMBER = st.one_of(st.floats(), st.just(0.0), st.integers(-3, 3), st.booleans())


@settings(max_examples=300, deadline=None)
@given(
    stamp=_ANY_NUMBER, source_stamp=_ANY_NUMBER, recorded_stamp=st.one_of(st.just(0.0), st.floats()),
    seq=st.one_of(st.integers(0, 5), st.floats(allow_nan=False), st.booleans()),
    position=st.one_of(
        st.lists(st.floats(width=64), min_size=3, max_size=3).map(np.array),
        st.lists(st.floats(width=64, allow_nan=False), min_size=2, max_size=4).map(np.array),
        st.lists(st.integers(-3, 3), min_size=3, max_size=3).map(np.array),
        st.lists(st.floats(width=32, allow_nan=False), min_size=3, max_size=3).map(lambda v: np.array(v, np.float32)),
        st.just(np.arange(6.0)[::2]), st.just(np.zeros(3, ">f8")), st.just(np.zeros((1, 3))),
        st.just([0.0, 0.0, 0.0]), st.just("abc")),
    norm=st.sampled_from([1.0, 1.0005, 0.5, float("nan"), float("inf")]),
    valid=st.one_of(st.booleans(), st.integers(0, 1)),
)
@example(stamp=0.0, source_stamp=0.0, recorded_stamp=0.0, seq=0, position=np.array([0.0, np.nan, 0.0]), norm=1.0,
         valid=True)
@example(stamp=1.0, source_stamp=0.0, recorded_stamp=0.0, seq=0, position=np.zeros(3), norm=float("inf"),
         valid=False)   # no quaternion rule while invalid: only the finiteness check stops it
@example(stamp=float("nan"), source_stamp=0.0, recorded_stamp=0.0, seq=0, position=np.zeros(3), norm=1.0, valid=True)
def test_publishing_agrees_with_the_reference_and_touches_nothing_when_it_fails(
        stamp, source_stamp, recorded_stamp, seq, position, norm, valid):
    def pose():
        msg = HandPose(position=[0.0, 0.0, 0.0], valid=True)
        with np.errstate(invalid="ignore"):
            orientation = np.array([0.0, 0.0, 0.6, 0.8]) * norm
        # fields set after construction, as a node does (the constructor's coercion does not see them)
        msg.__dict__.update(stamp=stamp, source_stamp=source_stamp, recorded_stamp=recorded_stamp, seq=seq,
                            position=position, orientation=orientation, valid=valid)
        return msg

    fast_msg, reference_msg = pose(), pose()
    before = dict(fast_msg.__dict__)
    started = time.time()
    got = published(fast_msg, 9)
    with reference_only(HandPose):
        want = published(reference_msg, 9)
    if isinstance(want, str):
        assert got == want
        assert fast_msg.__dict__.keys() == before.keys()
        assert all(fast_msg.__dict__[k] is v for k, v in before.items())   # nothing stamped, numbered or coerced
        return
    assert not isinstance(got, str), got
    # a stamp of 0 becomes the time of publishing (the two runs differ there only); a source_stamp of 0, the stamp
    if not before["stamp"]:
        assert started <= got["stamp"] <= want["stamp"] <= time.time()
    if not before["source_stamp"]:
        assert got["source_stamp"] == got["stamp"] and want["source_stamp"] == want["stamp"]
    for key in ("stamp", "source_stamp"):
        if not before[key]:
            got[key] = want[key]
    assert got.keys() == want.keys()
    for key, value in want.items():
        if isinstance(value, np.ndarray):
            assert got[key].dtype == value.dtype and np.array_equal(got[key], value, equal_nan=True), key
        else:
            assert got[key] == value and type(got[key]) is type(value), key
    assert got["seq"] == 9 and fast_msg.seq == 9


def old_encoding(msg: Message) -> bytes:
    """How the previous encoder (msgpack-python, one ExtType per array) wrote a message."""
    def default(obj):
        header = np.array([len(obj.dtype.str)], np.uint8).tobytes() + obj.dtype.str.encode()
        header += np.array([obj.ndim], np.uint8).tobytes() + np.array(obj.shape, "<u4").tobytes()
        return msgpack.ExtType(1, header + obj.tobytes())
    return msgpack.packb(msg.to_dict(), default=default, use_bin_type=True)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_payloads_of_the_previous_encoder_still_decode(msg):
    payload = old_encoding(msg)
    assert same(decode(payload), msg) and same(decode(payload, type(msg)), msg)


def test_another_msgpack_implementation_reads_the_wire():
    msg = HandPose(position=[0.1, -0.2, 0.3], orientation=[0, 0, 0.6, 0.8], valid=True, stamp=12.5, seq=300)
    data = msgpack.unpackb(msg.encode(), raw=False)
    assert list(data)[:3] == ["type", "stamp", "seq"]   # header first: a log writer peeks at it
    assert {k: data[k] for k in ("type", "stamp", "seq", "source_stamp", "valid")} == {
        "type": "HandPose", "stamp": 12.5, "seq": 300, "source_stamp": 0.0, "valid": True}
    ext = data["position"]
    assert ext.code == 1
    # [len(dtype), dtype, ndim, shape as u32 little-endian, raw little-endian float64]
    assert ext.data[:9] == b"\x03<f8\x01\x03\x00\x00\x00"
    assert np.frombuffer(ext.data[9:], "<f8").tolist() == [0.1, -0.2, 0.3]


def test_decoded_arrays_are_read_only_views_of_the_payload():
    field = TactileField(positions=np.arange(30.0).reshape(10, 3), l=np.zeros(10), s=np.zeros(10),
                         h=np.zeros(10))
    payload = field.encode()
    back = decode(payload, TactileField)
    raw = np.frombuffer(payload, np.uint8)
    for name in ("positions", "l", "s", "h"):
        arr = getattr(back, name)
        assert np.shares_memory(arr, raw), name       # no copy of the array's bytes
        assert not arr.flags.writeable
    np.testing.assert_array_equal(back.positions, np.arange(30.0).reshape(10, 3))
    # a small array of fixed shape (a pose's 24 bytes) is copied, quicker than checking a view; read-only too
    pose = decode(HandPose(position=[0.1, 0.2, 0.3], valid=True).encode(), HandPose)
    assert not pose.position.flags.writeable and not pose.orientation.flags.writeable
    assert pose.position.tolist() == [0.1, 0.2, 0.3] and pose.orientation.tolist() == [0.0, 0.0, 0.0, 1.0]


def test_arrays_that_are_not_contiguous_or_not_native_encode_their_values():
    base_positions = np.asfortranarray(np.arange(12.0).reshape(4, 3))
    msg = TactileField(positions=base_positions, l=np.arange(8.0)[::2], s=np.zeros(4, ">f8"), h=np.ones(4))
    back = decode(msg.encode(), TactileField)
    np.testing.assert_array_equal(back.positions, base_positions)
    np.testing.assert_array_equal(back.l, [0.0, 2.0, 4.0, 6.0])
    assert back.s.dtype == np.dtype(">f8")
    pose = HandPose(position=np.arange(6.0)[::2], valid=True)
    np.testing.assert_array_equal(decode(pose.encode(), HandPose).position, [0.0, 2.0, 4.0])


@dataclass(kw_only=True)
class _Joints(Message):
    """A message type declared elsewhere (as another part of touch4d would): it gets fast paths too."""

    TYPE = "test_fastpaths.Joints"
    positions: np.ndarray = spec(Array((25, 3)), "joint positions")
    radii: np.ndarray = spec(Array((25,), dtype="f4"), "joint radii")
    hand: str = spec(Str(("left", "right")), "which hand")
    confidence: float = spec(Float(), "0..1")


@dataclass(kw_only=True)
class _Custom(Message):
    """A message that overrides the reference decoding: its own from_dict must run."""

    TYPE = "test_fastpaths.Custom"
    value: float = spec(Float(), "a number")

    @classmethod
    def from_dict(cls, data):
        data = dict(data)
        data.setdefault("value", -1.0)
        return super().from_dict(data)


@dataclass(kw_only=True)
class _Bounded(Message):
    """A message that adds a rule in its own validate(): publishing must run it."""

    TYPE = "test_fastpaths.Bounded"
    value: float = spec(Float(), "0..1")

    def validate(self):
        super().validate()
        if self.value > 1.0:
            raise MessageError(f"{self.TYPE}.value: expected at most 1, got {self.value}")


@dataclass(kw_only=True)
class _Normalised(Message):
    """A message whose check() normalises an array: what it sends is the normalised one."""

    TYPE = "test_fastpaths.Normalised"
    q: np.ndarray = spec(Array((4,)), "a quaternion, made unit length")

    def check(self):
        self.q = self.q / float(np.linalg.norm(self.q))


@pytest.fixture(scope="module")
def declared_here():
    """The test types stay registered while this module runs, and no longer."""
    yield
    for name in (_Joints.TYPE, _Custom.TYPE, _Bounded.TYPE, _Normalised.TYPE):
        TYPES.pop(name, None)


def test_a_newly_declared_type_gets_checked_fast_paths(declared_here):
    msg = _Joints(positions=np.ones((25, 3)), radii=np.full(25, 0.01, np.float32), hand="left", confidence=0.9)
    fast = compile_class(_Joints)
    assert fast.validate(msg)
    assert same(fast.decode(msg.encode()), msg)
    bad = _Joints(positions=np.ones((24, 3)), radii=np.zeros(25, np.float32), hand="left", confidence=1.0)
    with pytest.raises(MessageError, match=r"test_fastpaths.Joints.positions: expected shape 25x3, got 24x3"):
        decode(bad.encode(), _Joints)
    with pytest.raises(MessageError, match=r"hand: expected one of left, right, got 'middle'"):
        decode(pack({**msg.to_dict(), "hand": "middle"}), _Joints)


def test_a_fixed_array_too_large_to_copy_is_decoded_as_a_view(declared_here):
    msg = _Joints(positions=np.arange(75.0).reshape(25, 3), radii=np.full(25, 0.01, np.float32), hand="left",
                  confidence=0.9)   # 600 bytes of positions
    payload = msg.encode()
    back = decode(payload, _Joints)
    assert np.shares_memory(back.positions, np.frombuffer(payload, np.uint8))
    np.testing.assert_array_equal(back.positions, msg.positions)


def test_a_class_that_overrides_validate_has_it_run_on_publish(declared_here):
    assert decode(_Bounded(value=0.5).publish_payload(7)).seq == 7
    msg = _Bounded(value=2.0)
    with pytest.raises(MessageError, match="expected at most 1, got 2.0"):
        msg.publish_payload(7)
    assert msg.stamp == 0.0 and msg.source_stamp == 0.0 and msg.seq == 0


def test_what_a_class_check_changes_is_what_gets_published(declared_here):
    msg = _Normalised(q=[0.0, 0.0, 0.0, 2.0])
    sent = unpack(msg.publish_payload(3))["q"]   # as sent (decoding would normalise it again)
    assert sent.tolist() == [0.0, 0.0, 0.0, 1.0] == msg.q.tolist()


def test_a_value_msgpack_cannot_carry_fails_the_publish_and_leaves_the_header():
    from touch4d.messages import MotorStatus

    msg = MotorStatus(boards=[], duty=np.zeros(30), bus_load=0.2, errors={"send": object()})
    msg.seq = 4
    with pytest.raises(MessageError, match="MotorStatus: cannot encode"):
        msg.publish_payload(9)
    assert (msg.stamp, msg.source_stamp, msg.seq) == (0.0, 0.0, 4)
    msg.errors = {"send": 1}
    assert decode(msg.publish_payload(9), MotorStatus).errors == {"send": 1}


def test_a_class_that_overrides_from_dict_keeps_its_override(declared_here):
    payload = pack({"type": _Custom.TYPE, "stamp": 1.0, "seq": 0, "source_stamp": 1.0})
    assert decode(payload, _Custom).value == -1.0
    assert decode(payload).value == -1.0



@dataclass(kw_only=True)
class _Published(Message):
    """A type no message has used yet, as a node's own topic type would be."""

    TYPE = "test_fastpaths.Published"
    value: float = spec(Float(), "a number")


@dataclass(kw_only=True)
class _Subscribed(Message):
    """Another type no message has used yet."""

    TYPE = "test_fastpaths.Subscribed"
    value: float = spec(Float(), "a number")


def test_a_node_makes_the_fast_paths_when_it_declares_a_topic_not_on_its_first_message():
    # Made on the first message, they would hold that message (and the dozen queued behind it at
    # 1 kHz) back by about 10 ms.
    from touch4d.bus import Node
    from touch4d.bus.testing import running_broker

    try:
        assert "_FAST" not in _Published.__dict__ and "_FAST" not in _Subscribed.__dict__
        with running_broker() as bus:
            node = Node("declares", bus=bus, heartbeat=False)
            try:
                node.create_publisher("test/published", _Published)
                node.create_subscription("test/subscribed", _Subscribed, lambda m: None)
                assert "_FAST" in _Published.__dict__ and "_FAST" in _Subscribed.__dict__
            finally:
                node.shutdown()
    finally:
        for t in (_Published, _Subscribed):
            TYPES.pop(t.TYPE, None)

"""The one code path of the messages (messages/base.py): what publishing and decoding accept, against
a rule written out here for a pose; every field of every type refused with its name when wrong,
on publish (the header left as it was) and on the wire; the wire readable by another msgpack
implementation and by earlier versions; large arrays decoded without a copy; a new type needing
nothing but its declaration; a bug in a message class raising, never hidden."""
import math
import re
import time
import typing

import msgpack
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from touch4d.errors import Touch4dError
from touch4d.messages import (
    TOPIC_TYPES, TYPES, HandJoints, HandPose, Message, MessageError, MotorCommand, MotorStatus, TactileField, decode, decoder,
)
from touch4d.messages.base import Array, ArraySpec, Float, Map, Records, RecordsSpec, doc
from touch4d.messages.codec import CodecError, pack, unpack

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
        elif x != y or type(x) is not type(y):
            return False
    return True


def named_field(text: str, type_name: str) -> str:
    """The field a MessageError's text names ("HandPose.position: ..." -> "position")."""
    found = re.match(rf"{re.escape(type_name)}\.(\w+)", text)
    assert found, text
    return found.group(1)


# ---- a pose by a rule written out here ---------------------------------------------------------


def _number(v, finite=True) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and (not finite or math.isfinite(v))


def _vector(v, n) -> bool:
    return (isinstance(v, np.ndarray) and v.dtype.kind == "f" and v.shape == (n,)
            and bool(np.isfinite(v).all()))


def pose_problems(data: dict) -> set[str]:
    """The fields of a HandPose map that are wrong (contracts.md's table), by a rule of its own."""
    wrong = {k for k in data if k not in ("stamp", "seq", "source_stamp", "recorded_stamp", "position",
                                           "orientation", "valid")}
    for key in ("stamp", "seq", "source_stamp", "position", "orientation", "valid"):
        if key not in data:
            wrong.add(key)
    if "stamp" in data and not _number(data["stamp"]):
        wrong.add("stamp")
    if "source_stamp" in data and not _number(data["source_stamp"]):
        wrong.add("source_stamp")
    if "recorded_stamp" in data and not _number(data["recorded_stamp"]):
        wrong.add("recorded_stamp")
    if "seq" in data and (type(data["seq"]) is not int or not -2**63 <= data["seq"] < 2**64):
        wrong.add("seq")
    if "position" in data and not _vector(data["position"], 3):
        wrong.add("position")
    if "orientation" in data and not _vector(data["orientation"], 4):
        wrong.add("orientation")
    if "valid" in data and type(data["valid"]) is not bool:
        wrong.add("valid")
    if not wrong and data["valid"] and abs(math.hypot(*data["orientation"].tolist()) - 1) > 1e-3:
        wrong.add("orientation")
    return wrong


_ANY_NUMBER = st.one_of(st.floats(), st.just(0.0), st.integers(-3, 3), st.booleans(), st.text(max_size=2))
_ANY_VECTOR = st.one_of(
    st.lists(st.floats(width=64), min_size=2, max_size=5).map(np.array),
    st.lists(st.floats(width=64, allow_nan=False, allow_infinity=False), min_size=3, max_size=4).map(np.array),
    st.lists(st.integers(-3, 3), min_size=3, max_size=4).map(np.array),
    st.lists(st.floats(width=32), min_size=3, max_size=4).map(lambda v: np.array(v, np.float32)),
    st.just(np.arange(6.0)[::2]), st.just(np.zeros(3, ">f8")), st.just(np.zeros((1, 3))),
    st.just([0.0, 0.0, 0.0]), st.just("abc"))


def _quaternion(norm):
    with np.errstate(invalid="ignore"):
        return np.array([0.0, 0.0, 0.6, 0.8]) * norm


@settings(max_examples=300, deadline=None)
@given(stamp=_ANY_NUMBER, seq=st.one_of(st.integers(-2, 2**64 - 1), st.floats(allow_nan=False), st.booleans()),
       position=_ANY_VECTOR, norm=st.sampled_from([1.0, 1.0005, 0.5, float("nan")]),
       valid=st.one_of(st.booleans(), st.integers(0, 1)), extra=st.sampled_from([None, "extra"]),
       missing=st.sampled_from([None, "valid", "position", "stamp", "recorded_stamp"]),
       recorded=st.one_of(st.just(None), st.floats()))
@example(stamp=1.0, seq=0, position=np.array([0.0, np.inf, 0.0]), norm=1.0, valid=True, extra=None, missing=None,
         recorded=None)
@example(stamp=1.0, seq=0, position=np.zeros(3), norm=float("nan"), valid=False, extra=None, missing=None,
         recorded=None)
def test_decoding_any_pose_payload_follows_the_rule(stamp, seq, position, norm, valid, extra, missing, recorded):
    data = {"type": "HandPose", "stamp": stamp, "seq": seq, "source_stamp": 1.0, "position": position,
            "orientation": _quaternion(norm), "valid": valid}
    if recorded is not None:
        data["recorded_stamp"] = recorded
    if extra:
        data[extra] = 1
    if missing:
        data.pop(missing, None)
    wire = {k: v for k, v in data.items() if k != "type"}
    payload = pack(data)
    wrong = pose_problems(wire)
    for decode_it in (lambda: decode(payload, HandPose), lambda: decoder(HandPose)(payload), lambda: decode(payload)):
        if wrong:
            with pytest.raises(MessageError) as info:
                decode_it()
            text = str(info.value)
            assert (named_field(text, "HandPose") if "unknown field" not in text else "extra") in wrong, text
        else:
            msg = decode_it()
            for key, value in wire.items():
                got = getattr(msg, key)
                if isinstance(value, np.ndarray):
                    assert got.dtype == value.dtype and np.array_equal(got, value) and not got.flags.writeable
                else:
                    assert got == value and type(got) is (float if key.endswith("stamp") else type(value))
            assert msg.recorded_stamp == wire.get("recorded_stamp", 0.0)


@settings(max_examples=300, deadline=None)
@given(stamp=_ANY_NUMBER, source_stamp=_ANY_NUMBER, recorded_stamp=st.one_of(st.just(0.0), st.floats()),
       seq=st.one_of(st.integers(0, 5), st.floats(allow_nan=False), st.booleans()), position=_ANY_VECTOR,
       norm=st.sampled_from([1.0, 1.0005, 0.5, float("nan"), float("inf")]),
       valid=st.one_of(st.booleans(), st.integers(0, 1)))
@example(stamp=0.0, source_stamp=0.0, recorded_stamp=0.0, seq=0, position=np.array([0.0, np.nan, 0.0]), norm=1.0,
         valid=True)
@example(stamp=float("nan"), source_stamp=0.0, recorded_stamp=0.0, seq=0, position=np.zeros(3), norm=1.0, valid=True)
def test_publishing_follows_the_rule_and_touches_nothing_when_it_fails(
        stamp, source_stamp, recorded_stamp, seq, position, norm, valid):
    msg = HandPose(position=[0.0, 0.0, 0.0], valid=True)
    # fields set after the message was made, as a node does (making it coerces; this does not)
    values = dict(stamp=stamp, source_stamp=source_stamp, recorded_stamp=recorded_stamp, seq=seq,
                  position=position, orientation=_quaternion(norm), valid=valid)
    for key, value in values.items():
        setattr(msg, key, value)
    wrong = pose_problems(values)
    started = time.time()
    if wrong:
        with pytest.raises(MessageError) as info:
            msg.publish_payload(9)
        assert named_field(str(info.value), "HandPose") in wrong, str(info.value)
        assert all(getattr(msg, k) is v for k, v in values.items())   # nothing stamped, numbered or coerced
        return
    sent = unpack(msg.publish_payload(9))
    assert sent["seq"] == 9 == msg.seq
    if not stamp:   # a stamp of 0 becomes the time of publishing; a source_stamp of 0, the stamp
        assert started <= sent["stamp"] <= time.time()
    else:
        assert sent["stamp"] == stamp
    assert sent["source_stamp"] == (source_stamp or sent["stamp"])
    assert (sent["stamp"], sent["source_stamp"]) == (msg.stamp, msg.source_stamp)
    assert ("recorded_stamp" in sent) == (recorded_stamp != 0) and list(sent)[:4] == ["type", "stamp", "seq",
                                                                                       "source_stamp"]
    assert sent["valid"] is valid
    for key in ("position", "orientation"):
        assert sent[key].dtype == values[key].dtype and np.array_equal(sent[key], values[key])


@settings(max_examples=60, deadline=None)
@given(n=st.integers(0, 40), dtype=st.sampled_from(["<f8", "<f4", ">f8"]), seed=st.integers(0, 2**32 - 1),
       alpha=st.floats(-1e6, 1e6), stamp=st.floats(0, 2e9))
def test_a_tactile_field_round_trips_with_its_dtypes_shapes_and_nans(n, dtype, seed, alpha, stamp):
    rng = np.random.default_rng(seed)
    l = rng.random(n).astype(dtype)
    l[rng.random(n) < 0.3] = np.nan
    msg = TactileField(positions=rng.random((n, 3)).astype(dtype), l=l, s=rng.random(n), h=rng.random(n),
                       alpha=alpha, beta=0.5, gamma=1, stamp=stamp)
    back = decode(msg.publish_payload(3), TactileField)
    assert same(back, msg) and back.seq == 3 and type(back.gamma) is float


# ---- every field of every type, refused by name ---------------------------------------------------


def bad_values(tp) -> list:
    """Values a field of type `tp` must refuse (chosen here from the type, for any message type)."""
    spec = typing.get_args(tp)[1] if typing.get_origin(tp) is typing.Annotated else None
    if isinstance(spec, ArraySpec):
        shape = [n or 2 for n in spec.shape]
        other = np.zeros(shape) if spec.dtype.kind == "b" else np.zeros(shape, bool)   # another dtype's kind
        out = [np.zeros(shape + [1]), other, np.zeros(shape).tolist(), "x"]
        if spec.finite:
            out.append(np.full(shape, np.inf))
        if None not in spec.shape:
            out.append(np.zeros([n + 1 for n in shape]))
        return out
    if isinstance(spec, RecordsSpec):
        return [[{}], ["x"], "x"]
    if tp is Float:
        return ["x", float("nan"), True, None]
    if tp is float:
        return ["x", None]
    if tp is int:
        return [1.5, True, "1"]
    if tp is bool:
        return [1, "true"]
    if tp is str:
        return [3, None]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Literal:
        return ["nope", 3]
    if origin is list:
        return [[1.5], "abc"] if args[0] is str else [[1.5], [True]] if args[0] is int else [["x"], "abc"]
    if origin is dict:
        return [{1: 2}, "x"]
    raise AssertionError(f"no bad values known for {tp}")


def _cases():
    by_type = {type(m): m for m in EXAMPLES}
    for cls in TOPIC_TYPES.values():
        for field in cls.FIELDS:
            yield pytest.param(by_type[cls], field.name, id=f"{cls.TYPE}.{field.name}")


@pytest.mark.parametrize("example, name", list(_cases()))
def test_every_field_refuses_bad_values_by_name_on_publish_and_on_the_wire(example, name):
    cls = type(example)
    field = next(f for f in cls.FIELDS if f.name == name)
    good = unpack(example.encode())
    for bad in bad_values(field.type):
        msg = decode(example.encode(), cls)
        msg.stamp, msg.seq = 0.0, 5
        setattr(msg, name, bad)
        header = msg.stamp, msg.source_stamp, msg.seq
        with pytest.raises(MessageError) as info:
            msg.publish_payload(6)
        assert str(info.value).startswith(f"{cls.TYPE}.{name}"), (bad, str(info.value))
        assert all(a is b for a, b in zip((msg.stamp, msg.source_stamp, msg.seq), header))
        try:
            payload = pack({**good, name: bad})
        except (TypeError, CodecError):
            continue   # not even msgpack (an array of bools is)
        with pytest.raises(MessageError) as info:
            decode(payload, cls)
        assert str(info.value).startswith(f"{cls.TYPE}.{name}"), (bad, str(info.value))
    if not field.optional:
        with pytest.raises(MessageError, match=rf"^{cls.TYPE}\.{name}: missing"):
            decode(pack({k: v for k, v in good.items() if k != name}), cls)


@pytest.mark.parametrize("example, name", [c for c in _cases() if c.values[1] not in dict(type(c.values[0])._rest)])
def test_the_one_look_at_a_message_never_passes_what_its_fields_checks_refuse(example, name):
    """Publishing looks at the whole message once (`_usual`), then at the fields that look leaves
    (`_rest`), and at each field only when it says no: a yes must never let through a value the
    field's own check refuses."""
    cls = type(example)
    field = next(f for f in cls.FIELDS if f.name == name)
    odd = [*bad_values(field.type), 1, 1.0, True, "x", math.nan, np.ones(3, np.float32), np.ones(4), [0.0]]
    for value in odd:
        msg = decode(example.encode(), cls)
        setattr(msg, name, value)
        try:
            field.check(value)
        except ValueError:
            assert not cls._usual(msg), (name, value)
    assert cls._usual(decode(example.encode(), cls))


def test_a_joint_set_names_its_first_quaternion_that_is_not_unit_length():
    q = np.tile([0.0, 0.0, 0.0, 1.0], (25, 1)).astype(np.float32)
    q[3] = [0.0, 0.6, 0.0, 0.8005]                   # within the float32 tolerance (norm 1.0004)
    joints = HandJoints(handedness="left", names=[f"j{i}" for i in range(25)], positions=np.zeros((25, 3)),
                        orientations=q, radii=np.full(25, 0.01), valid=True)
    joints.publish_payload(0)
    joints.orientations[7, 3] = 1.01
    joints.orientations[12, 3] = 0.5
    with pytest.raises(MessageError, match=r"^HandJoints.orientations\[7\]: expected a unit quaternion .* norm 1.01$"):
        joints.publish_payload(1)
    with pytest.raises(MessageError, match=r"^HandJoints.orientations\[7\]: expected a unit quaternion"):
        decode(joints.encode(), HandJoints)
    joints.valid = False                              # an untracked hand's arrays are stale: not checked
    joints.publish_payload(2)


def test_every_topic_type_has_an_example_here():
    assert {type(m) for m in EXAMPLES} >= set(TOPIC_TYPES.values())


def test_message_errors_are_touch4d_errors_and_value_errors():
    assert issubclass(MessageError, Touch4dError) and issubclass(CodecError, Touch4dError)
    assert issubclass(MessageError, ValueError)   # callers that caught ValueError still do


# ---- the wire ---------------------------------------------------------------------------------------


def old_encoding(msg: Message) -> bytes:
    """How an earlier encoder (msgpack-python, one ExtType per array, fields as declared) wrote a message."""
    def default(obj):
        header = np.array([len(obj.dtype.str)], np.uint8).tobytes() + obj.dtype.str.encode()
        header += np.array([obj.ndim], np.uint8).tobytes() + np.array(obj.shape, "<u4").tobytes()
        return msgpack.ExtType(1, header + obj.tobytes())
    data = {"type": msg.TYPE, **{f.name: getattr(msg, f.name) for f in msg.FIELDS if f.name != "recorded_stamp"}}
    return msgpack.packb(data, default=default, use_bin_type=True)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_payloads_of_an_earlier_encoder_still_decode(msg):
    payload = old_encoding(msg)
    assert same(decode(payload), msg) and same(decode(payload, type(msg)), msg)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_a_message_round_trips_through_publish_to_dict_and_from_dict(msg):
    fresh = decode(msg.encode(), type(msg))
    assert same(decode(fresh.publish_payload(4)), fresh) and fresh.seq == 4
    assert same(type(msg).from_dict(msg.to_dict()), msg)
    assert list(msg.to_dict()) == list(unpack(msg.encode()))


def test_another_msgpack_implementation_reads_the_wire():
    msg = HandPose(position=[0.1, -0.2, 0.3], orientation=[0, 0, 0.6, 0.8], valid=True, stamp=12.5, seq=300)
    data = msgpack.unpackb(msg.encode(), raw=False)
    # the header first (a log writer peeks at it), the arrays last, as earlier versions wrote them
    assert list(data) == ["type", "stamp", "seq", "source_stamp", "valid", "position", "orientation"]
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
    pose = decode(HandPose(position=[0.1, 0.2, 0.3], valid=True).encode(), HandPose)
    assert not pose.position.flags.writeable and not pose.orientation.flags.writeable
    assert pose.position.tolist() == [0.1, 0.2, 0.3] and pose.orientation.tolist() == [0.0, 0.0, 0.0, 1.0]


def test_arrays_that_are_not_contiguous_or_not_native_encode_their_values():
    base_positions = np.asfortranarray(np.arange(1200.0).reshape(400, 3))   # large: not copied by tobytes
    msg = TactileField(positions=base_positions, l=np.arange(800.0)[::2], s=np.zeros(400, ">f8"), h=np.ones(400))
    back = decode(msg.encode(), TactileField)
    np.testing.assert_array_equal(back.positions, base_positions)
    np.testing.assert_array_equal(back.l, np.arange(800.0)[::2])
    assert back.s.dtype == np.dtype(">f8")
    pose = HandPose(position=np.arange(6.0)[::2], valid=True)
    np.testing.assert_array_equal(decode(pose.encode(), HandPose).position, [0.0, 2.0, 4.0])


def test_making_a_message_coerces_and_fills_fresh_defaults():
    a, b = HandPose(position=[1, 2, 3]), HandPose(position=(0.5, 0.5, 0.5), valid=True)
    assert a.position.dtype == np.float64 and a.position.tolist() == [1.0, 2.0, 3.0]
    a.orientation[0] = 0.5                      # each message has its own default arrays and lists
    assert b.orientation.tolist() == [0.0, 0.0, 0.0, 1.0]
    m1, m2 = MotorStatus(), MotorStatus()
    assert m1.boards is not m2.boards and m1.errors is not m2.errors and m1.duty.shape == (0,)
    assert type(MotorStatus(bus_load=1).bus_load) is float
    assert TactileField(positions=np.zeros((1, 3), np.float32)).positions.dtype == np.float32
    with pytest.raises(MessageError, match="HandPose.position"):
        HandPose(position="abc")
    with pytest.raises(TypeError):
        HandPose(positoin=[0, 0, 0])   # a misspelt field


# ---- a type declared elsewhere -------------------------------------------------------------------------


class _Joints(Message):
    """A message type declared elsewhere (as another part of touch4d would): nothing more is needed."""

    TYPE = "test_checks.Joints"
    positions: Array(25, 3) = doc("joint positions")
    radii: Array(25, dtype="f4") = doc("joint radii")
    hand: typing.Literal["left", "right"] = doc("which hand")
    confidence: Float = doc("0..1")
    tags: Map = doc("anything")
    parts: Records(name=str, size=Float, optional=("size",)) = doc("named parts")
    note: str = doc("left out of payloads while empty", optional=True)


class _Normalised(Message):
    """A message whose check() normalises an array: what it sends is the normalised one."""

    TYPE = "test_checks.Normalised"
    q: "Array(4)" = doc("a quaternion, made unit length")   # as `from __future__ import annotations` has it

    def check(self):
        self.q = self.q / float(np.linalg.norm(self.q))


class _Buggy(Message):
    """A message whose check() has a bug (a TypeError): it must surface, not read as a bad message."""

    TYPE = "test_checks.Buggy"
    value: Float = doc("a number")

    def check(self):
        if self.value > 1:
            return self.value + "1"   # the bug


@pytest.fixture(scope="module")
def declared_here():
    """The test types stay registered while this module runs, and no longer."""
    yield
    for cls in (_Joints, _Normalised, _Buggy):
        TYPES.pop(cls.TYPE, None)


def test_a_newly_declared_type_is_checked_and_decodes_large_fixed_arrays_as_views(declared_here):
    msg = _Joints(positions=np.arange(75.0).reshape(25, 3), radii=np.full(25, 0.01, np.float32), hand="left",
                  confidence=0.9, parts=[{"name": "a"}, {"name": "b", "size": 2}])
    payload = msg.publish_payload(0)
    back = decode(payload)   # found by its type name
    assert type(back) is _Joints and same(back, msg) and back.parts == [{"name": "a"}, {"name": "b", "size": 2}]
    assert np.shares_memory(back.positions, np.frombuffer(payload, np.uint8))   # 600 bytes: not copied
    assert _Joints.field_docs()["confidence"] == "0..1"
    assert "note" not in unpack(payload) and back.note == ""
    noted = decode(_Joints(positions=msg.positions, radii=msg.radii, note="hi").encode(), _Joints)
    assert noted.note == "hi" and list(unpack(noted.encode()))[-4:] == ["parts", "note", "positions", "radii"]
    bad = _Joints(positions=np.ones((24, 3)), radii=np.zeros(25, np.float32), hand="left", confidence=1.0)
    with pytest.raises(MessageError, match=r"^test_checks.Joints.positions: expected shape 25x3, got 24x3"):
        decode(bad.encode(), _Joints)
    with pytest.raises(MessageError, match=r"^test_checks.Joints.hand: expected one of left, right, got 'middle'"):
        decode(pack({**msg.to_dict(), "hand": "middle"}), _Joints)
    with pytest.raises(MessageError, match=r"^test_checks.Joints.parts\[1\].size: expected a number, got str"):
        decode(pack({**msg.to_dict(), "parts": [{"name": "a"}, {"name": "b", "size": "big"}]}), _Joints)
    with pytest.raises(MessageError, match=r"^test_checks.Joints.parts\[0\].name: missing"):
        _Joints(parts=[{"size": 1.0}]).publish_payload(0)


def test_a_field_must_be_documented_and_of_a_known_type():
    with pytest.raises(TypeError, match="declare it as"):
        class _Undocumented(Message):
            TYPE = "test_checks.Undocumented"
            value: float
    with pytest.raises(TypeError, match="cannot be of type"):
        class _Unknown(Message):
            TYPE = "test_checks.Unknown"
            value: set = doc("a set")
    with pytest.raises(TypeError, match="only a number, bool or string field may be optional"):
        class _OptionalList(Message):
            TYPE = "test_checks.OptionalList"
            value: list[str] = doc("names", optional=True)
    for name in ("test_checks.Undocumented", "test_checks.Unknown", "test_checks.OptionalList"):
        TYPES.pop(name, None)


def test_what_a_class_check_changes_is_what_gets_published(declared_here):
    msg = _Normalised(q=[0.0, 0.0, 0.0, 2.0])
    sent = unpack(msg.publish_payload(3))["q"]   # as sent (decoding would normalise it again)
    assert sent.tolist() == [0.0, 0.0, 0.0, 1.0] == msg.q.tolist()


def test_a_bug_in_a_message_class_raises_on_publish_and_on_decode(declared_here):
    assert decode(_Buggy(value=0.5).publish_payload(0)).value == 0.5
    with pytest.raises(TypeError):
        _Buggy(value=2.0).publish_payload(0)
    with pytest.raises(TypeError):
        decode(_Buggy(value=2.0).encode(), _Buggy)


def test_a_value_msgpack_cannot_carry_fails_the_publish_and_leaves_the_header():
    msg = MotorStatus(boards=[], duty=np.zeros(30), bus_load=0.2, errors={"send": object()})
    msg.seq = 4
    with pytest.raises(MessageError, match="MotorStatus: cannot encode"):
        msg.publish_payload(9)
    assert (msg.stamp, msg.source_stamp, msg.seq) == (0.0, 0.0, 4)
    msg.errors = {"send": 1}
    assert decode(msg.publish_payload(9), MotorStatus).errors == {"send": 1}


def test_a_message_is_not_checked_until_it_is_published():
    msg = MotorCommand(names=["a", "b"], intensity=[1.0])   # a node may fill it in later
    with pytest.raises(MessageError, match=r"^MotorCommand.intensity: expected 2 values"):
        msg.publish_payload(0)
    msg.intensity = np.array([1.0, 0.5])
    assert decode(msg.publish_payload(0), MotorCommand).intensity.tolist() == [1.0, 0.5]


@pytest.mark.parametrize("n", [1, 30, 64, 65, 500])
def test_a_negative_motor_intensity_is_refused_on_publish_and_on_decode(n):
    for k in (0, n // 2, n - 1):
        intensity = np.full(n, 0.25, np.float32)
        intensity[k] = -1e-6
        msg = MotorCommand(names=[f"m{i}" for i in range(n)], intensity=intensity)
        with pytest.raises(MessageError, match=r"^MotorCommand.intensity: expected values >= 0"):
            msg.publish_payload(0)
        with pytest.raises(MessageError, match=r"^MotorCommand.intensity: expected values >= 0"):
            decode(pack(msg))   # written without the check, as another process might
    ok = MotorCommand(names=[f"m{i}" for i in range(n)], intensity=np.zeros(n))
    assert decode(ok.publish_payload(0), MotorCommand).intensity.tolist() == [0.0] * n

"""Messages: round trips keep types, dtypes and shapes; bad payloads are rejected with a clear reason."""
import msgpack
import msgspec
import numpy as np
import pytest

from touch4d.messages import (
    TOPIC_TYPES, TYPES, ControllerState, HandJoints, HandPose, HandPoses, Heartbeat, InputEvents, MessageError, MotorCommand, MotorCommands,
    MotorStatus, MotorTrace, PhysicsContacts, PhysicsInput, SceneCommand, SceneState, Stop, StudyCommand, StudyResponse,
    StudyTrial, TactileField, decode, decoder, encode,
)
from touch4d.messages.codec import pack


def scene_object(**over):
    obj = dict(name="cube", shape="tesseract", params={}, size=1.0, position=np.array([0, 0, 0, 1.5]),
               orientation=np.eye(4), color=np.array([1.0, 0.5, 0.0, 1.0]))
    obj.update(over)
    return obj


EXAMPLES = [
    HandPose(position=[0.1, -0.2, 0.3], orientation=[0, 0, 0.6, 0.8], valid=True, stamp=12.5, seq=3, source_stamp=12.5),
    ControllerState(position=[1, 2, 3], orientation=[0, 0, 0, 1], trigger=0.7, buttons=["menu"], valid=True),
    HandJoints(handedness="left", names=["wrist", "index-finger-tip"], positions=np.zeros((2, 3)),
               orientations=[[0, 0, 0, 1], [0, 0, 0.6, 0.8]], radii=[0.02, 0.01], valid=True),
    SceneState(objects=[scene_object(), scene_object(shape="custom", parts=[np.ones((6, 5))])],
               projection="perspective", eye_distance=3.0, selected=1, revision=7),
    SceneCommand(command="projection", argument="toggle"),
    TactileField(positions=np.zeros((4, 3)), l=np.array([0.1, np.nan, 0.3, np.nan]), s=np.ones(4),
                 h=np.full(4, 0.5), alpha=1.0, beta=0.5, gamma=1.0),
    MotorCommand(names=["palm0", "palm1"], intensity=[0.0, 0.4]),
    HandPoses(stamps=[10.0, 10.014], positions=[[0.1, -0.2, 0.3], [0.0, 0.0, 0.0]],
              orientations=[[0, 0, 0.6, 0.8], [0, 0, 0, 1]], valid=np.array([True, False])),
    MotorCommands(names=["grip"], source_stamps=[10.0, 10.014], intensity=[[0.4], [0.0]]),
    MotorStatus(boards=[dict(id=1, online=True, faults=[], last_frame=1.0, state="operational")],
                duty=np.zeros(30), bus_load=0.21, errors={"send": 0}),
    Stop(reason="test", origin="pytest"),
    MotorTrace(source_stamps=[1.0, 2.0], frame_times=[1.001, 2.002]),
    Heartbeat(node="tactile", pid=42, kind="tactile", publishes=["tactile/field"], subscribes=[], stats={"received": 3}),
    InputEvents(keys_down=["w"], pressed=["space"], mouse=[10, 20], mouse_delta=[1, -1], buttons=[1], scroll=0.5),
    PhysicsContacts(names=["floor", "cube"], a=np.array([0, -1]), b=np.array([1, 1]), points=np.zeros((2, 4)),
                    normals=[[0, 1, 0, 0], [1, 0, 0, 0]], impulses=[0.01, 0.002], speeds=[1.2, 0.3], step=7, time=0.007),
    PhysicsInput(step=12, kind="controller", args={"position": [0.0, 1.2, -0.4], "orientation": [0, 0, 0, 1],
                                                   "trigger": 1.0, "buttons": ["menu"], "valid": True}),
    StudyTrial(study="paper", participant="P01", phase="stimulus", index=4, total=40, block=1, trial=2, practice=False,
               task="front", kind="front-element", condition="touch", stimulus="edge", prompt="What is in front?",
               options=["face", "edge", "vertex"], onset=100.25, time_limit_s=20.0, message=""),
    StudyResponse(index=4, response="edge", source="controller", stamp=101.5),
    StudyCommand(command="pause", reason="the participant asked"),
]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: m.TYPE)
def test_round_trip_keeps_values_dtypes_and_shapes(msg):
    back = decode(encode(msg))
    assert type(back) is type(msg)
    for name in msg.field_docs():
        a, b = getattr(msg, name), getattr(back, name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(a, b)
        elif name == "objects":
            for oa, ob in zip(a, b):
                assert oa.keys() == ob.keys()
                np.testing.assert_array_equal(oa["orientation"], ob["orientation"])
        else:
            assert a == b


def test_every_topic_type_is_registered_and_documented():
    assert set(TOPIC_TYPES.values()) <= set(TYPES.values())
    for cls in TOPIC_TYPES.values():
        docs = cls.field_docs()
        assert {"stamp", "seq", "source_stamp"} <= docs.keys()
        assert all(doc for doc in docs.values())


def test_integer_and_float32_arrays_keep_their_dtype():
    msg = TactileField(positions=np.zeros((2, 3), np.float32), l=np.zeros(2, np.float32), s=np.zeros(2),
                       h=np.zeros(2))
    back = decode(encode(msg))
    assert back.positions.dtype == np.float32 and back.l.dtype == np.float32


@pytest.mark.parametrize("payload, reason", [
    (b"\xc1garbage", "not a msgpack payload"),
    (pack([1, 2, 3]), "expected a message map"),
    (pack({"type": "Nope"}), "unknown message type 'Nope'"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "valid": True}), "HandPose.orientation: missing"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.zeros(4),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.position: expected shape 3, got 4"),
    (pack({"type": "HandPose", "stamp": "now", "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.stamp: expected a number"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.array([np.inf, 0, 0]),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.position: expected finite"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "orientation": np.zeros(4), "valid": True}), "expected a unit quaternion"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True, "extra": 1}), "unknown field(s) extra"),
    (msgpack.packb({"type": "HandPose", "position": msgpack.ExtType(1, b"\x03<f8\x01\x03\x00\x00\x00abc")}),
     "needs 24 bytes, got 3"),
    (msgpack.packb({"type": "HandPose", "position": msgpack.ExtType(1, b"\x03|O8\x00")}), "not allowed"),
    (msgpack.packb({"type": "HandPose", "position": msgpack.ExtType(9, b"")}), "unknown msgpack ext type 9"),
])
def test_bad_payloads_are_rejected_with_the_reason(payload, reason):
    with pytest.raises(MessageError) as info:
        decode(payload)
    assert reason in str(info.value)


@pytest.mark.parametrize("payload, reason", [
    (pack({"type": "HandPose", "stamp": float("inf"), "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.stamp: expected a finite number, got inf"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 1.5, "source_stamp": 0.0, "position": np.zeros(3),
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.seq: expected an integer, got float"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": [0, 0, 0],
           "orientation": np.array([0, 0, 0, 1.0]), "valid": True}), "HandPose.position: expected a numpy array, got list"),
    (pack({"type": "HandJoints", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "handedness": "middle", "names": [],
           "positions": np.zeros((0, 3)), "orientations": np.zeros((0, 4)), "radii": np.zeros(0), "valid": False}),
     "HandJoints.handedness: expected one of right, left, got 'middle'"),
    (pack({"type": "HandPose", "stamp": 0.0, "seq": 0, "source_stamp": 0.0, "position": np.zeros(3),
           "valid": True}), "HandPose.orientation: missing"),
    (pack({"type": "HandPose", 7: 0.0}), "HandPose: keys: expected a string, got an integer"),
])
def test_what_is_wrong_is_read_from_the_declaration_not_from_msgspecs_words(monkeypatch, payload, reason):
    """msgspec's message for a payload it refuses may change wording: the error says the same."""
    cls = HandJoints if b"HandJoints" in payload else HandPose
    def reworded(data):
        try:
            return real(data)
        except msgspec.ValidationError:
            raise msgspec.ValidationError("Something else entirely - at `$.nowhere`") from None
    real = cls._decode
    monkeypatch.setattr(cls, "_decode", reworded)
    for decode_it in (lambda: decode(payload, cls), lambda: decoder(cls)(payload)):
        with pytest.raises(MessageError) as info:
            decode_it()
        assert str(info.value) == reason


def test_expected_type_is_enforced():
    with pytest.raises(MessageError, match="expected a HandPose message, got Stop"):
        decode(encode(Stop(reason="x", origin="y")), expected=HandPose)


def test_cross_field_rules():
    with pytest.raises(MessageError, match="intensity: expected 2 values"):
        decode(encode(MotorCommand(names=["a", "b"], intensity=[1.0])))
    bad = scene_object(orientation=np.full((4, 4), 0.5) + np.eye(4))
    with pytest.raises(MessageError, match=r"objects\[0\].orientation: expected an orthogonal"):
        decode(encode(SceneState(objects=[bad], projection="orthographic", eye_distance=0.0)))
    with pytest.raises(MessageError, match=r"objects\[0\].position: expected shape 4"):
        decode(encode(SceneState(objects=[scene_object(position=np.zeros(3))])))


def test_orientations_default_to_the_identity_quaternion():
    for cls in (HandPose, ControllerState):
        back = decode(encode(cls(position=[0, 0, 0], valid=True)))
        np.testing.assert_array_equal(back.orientation, [0, 0, 0, 1])


def test_recorded_stamp_is_an_optional_header_field_left_out_of_live_messages():
    live = HandPose(position=[0.1, 0.2, 0.3], valid=True, stamp=5.0, seq=2, source_stamp=4.5)
    payload = encode(live)
    plain = msgpack.unpackb(payload)
    assert "recorded_stamp" not in plain  # a live message's bytes are as they were before the field
    assert decode(payload).recorded_stamp == 0.0
    replayed = HandPose(position=[0.1, 0.2, 0.3], valid=True, stamp=105.0, seq=0, source_stamp=104.5,
                        recorded_stamp=5.0)
    plain = msgpack.unpackb(encode(replayed))
    assert list(plain)[:5] == ["type", "stamp", "seq", "source_stamp", "recorded_stamp"]
    assert plain["recorded_stamp"] == 5.0
    assert decode(encode(replayed)).recorded_stamp == 5.0
    assert "recorded_stamp" in HandPose.field_docs()
    with pytest.raises(MessageError, match="HandPose.recorded_stamp: expected a number"):
        decode(msgpack.packb({**plain, "recorded_stamp": "x"}))
    with pytest.raises(MessageError, match="HandPose.valid: missing"):  # required fields stay required
        decode(msgpack.packb({k: v for k, v in plain.items() if k != "valid"}))


def test_a_key_that_is_not_utf8_is_a_message_error():
    """Found by fuzzing: a map key with a byte that is not UTF-8 raised UnicodeDecodeError, not MessageError."""
    payload = (b"\x86\xa4ty\xa9e\xacMotorCommand\xa5stamp\xcb\x00\x00\x00\x00\x00*\x00\x00\xa3seq\x00"
               b"\xacsource_stamp\xcb\x00\xde\x00\x00\x00\x00\x00\x00\xa5names\x92\xa1a\xa1b\xa9intensit"
               b"\xd6\xc7\x19\x01\x03<f8\x01\x02\x00\x00")
    for expected in (HandPose, MotorCommand):
        with pytest.raises(MessageError):
            decode(payload, expected)


def test_each_field_carries_the_json_schema_logs_write_for_it():
    """A field's JSON schema is made where its type is read (messages.base), and the log's schema of the type
    is those schemas with the fields' docs: arrays nested by their shape, floats that may be NaN nullable."""
    from touch4d.log.schema import message_schema

    for name, cls in TYPES.items():
        props = message_schema(name)["properties"]
        for f in cls.FIELDS:
            assert props[f.name] == {**f.schema, "description": f.doc}, (name, f.name)
    fields = {f.name: f for f in HandPose.FIELDS}
    assert fields["position"].schema == {"type": "array", "items": {"type": ["number", "null"]},
                                         "minItems": 3, "maxItems": 3}
    assert fields["valid"].schema == {"type": "boolean"}
    assert fields["stamp"].schema == {"type": "number"}                 # Float: finite, never null

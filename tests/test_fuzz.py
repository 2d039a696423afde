"""Property-based fuzzing of everything that arrives from outside: message payloads on the bus, a
page's WebSocket messages, CAN frames at a board, scene and launch files. Whatever arrives, nothing
crashes or hangs, and every rejection is counted (bus, page, board) or named (files: a
ConfigError with the file and key). Each property runs a bounded number of examples (a few
seconds at most)."""
from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import can
import msgpack
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import REJECTED, make_glove_emulator
from touch4d.boards.protocol import FrameError, GloveProtocol
from touch4d.bus import Node
from touch4d.bus.testing import running_broker
from touch4d.errors import Touch4dError
from touch4d.geometry.scene import parse_scene
from touch4d.messages import TOPIC_TYPES, HandPose, MessageError, MotorCommand, decode, encode
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import Placement, load_calibration
from touch4d.web.bridge import PAGE_COUNTERS, BridgeConfig, WebBridge

REPO = Path(__file__).resolve().parents[1]
FAST = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ---- message payloads ------------------------------------------------------------------------------

json_like = st.recursive(st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1) | st.floats() | st.text(max_size=8)
                         | st.binary(max_size=16),
                         lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                   max_size=4), max_leaves=12)
VALID = [encode(HandPose(position=np.array([0.1, 0.2, 0.3]), orientation=np.array([0, 0, 0, 1.0]), valid=True)),
         encode(MotorCommand(names=["a", "b"], intensity=np.array([0.5, 1.0])))]


@st.composite
def payloads(draw):
    """Random bytes, random msgpack, valid payloads with bytes flipped or cut, or valid maps with a
    field replaced by anything."""
    kind = draw(st.integers(0, 4))
    if kind == 4:
        return draw(st.sampled_from(VALID))
    if kind == 0:
        return draw(st.binary(max_size=200))
    if kind == 1:
        return msgpack.packb(draw(json_like), use_bin_type=True)
    base = bytearray(draw(st.sampled_from(VALID)))
    if kind == 2:
        for _ in range(draw(st.integers(1, 4))):
            base[draw(st.integers(0, len(base) - 1))] = draw(st.integers(0, 255))
        return bytes(base[:draw(st.integers(0, len(base)))])
    data = msgpack.unpackb(bytes(base), raw=False, strict_map_key=False)
    data[draw(st.sampled_from(sorted(data)))] = draw(json_like)
    return msgpack.packb(data, use_bin_type=True)


@FAST
@given(payload=payloads(), expected=st.sampled_from([None, HandPose, MotorCommand, *TOPIC_TYPES.values()]))
def test_any_payload_decodes_to_a_message_or_a_message_error(payload, expected):
    try:
        msg = decode(payload, expected)
    except MessageError as exc:
        assert str(exc)                       # says what is wrong
        return
    assert expected is None or isinstance(msg, expected)
    assert decode(encode(msg), type(msg)).seq == msg.seq   # what was accepted is a valid message


def test_a_node_counts_every_payload_it_rejects_and_keeps_serving():
    """Through a real bus: every payload is either delivered or counted as malformed."""
    sent = []

    @settings(max_examples=100, deadline=None, database=None)
    @given(payload=payloads())
    def draw(payload):
        sent.append(payload)

    draw()
    accepted = 0
    for payload in sent:
        try:
            accepted += isinstance(decode(payload, HandPose), HandPose)
        except MessageError:
            pass
    with running_broker() as bus, Node("sub", bus=bus, heartbeat=False) as sub, \
            Node("pub", bus=bus, heartbeat=False) as pub:
        got = []
        sub.create_subscription("hand/pose", HandPose, got.append)
        raw = pub.create_raw_publisher("hand/pose")
        probe = encode(HandPose(position=np.zeros(3), orientation=np.array([0, 0, 0, 1.0]), valid=False))
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:    # until the subscription is live
            raw.publish(probe)
            sub.spin_once(0.01)
        assert got
        quiet = time.monotonic() + 0.3   # probes still in flight arrive before the count starts
        while time.monotonic() < quiet:
            sub.spin_once(0.01)
        n0, m0 = len(got), sub.stats_flat().get("hand/pose:malformed", 0)
        for payload in sent:
            raw.publish(payload)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            sub.spin_once(0.01)
            delivered, malformed = len(got) - n0, sub.stats_flat().get("hand/pose:malformed", 0) - m0
            if delivered + malformed >= len(sent):
                break
        assert (delivered, malformed) == (accepted, len(sent) - accepted)
        assert 0 < accepted < len(sent)   # the strategy reaches both sides


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(sent=st.lists(payloads() | st.binary(max_size=12).map(lambda b: b"\x83\xa4type\xa3" + b), min_size=1,
                     max_size=6))
def test_the_recorder_keeps_any_payload_as_it_came_and_counts_what_is_not_a_message(tmp_path, sent):
    from touch4d.log.reader import LogReader
    from touch4d.log.writer import LogWriter

    path = tmp_path / f"fuzz-{uuid.uuid4().hex}.mcap"
    with LogWriter(path) as writer:
        for i, payload in enumerate(sent):
            writer.write("hand/pose", payload, 1_000_000_000 + i)
        malformed = writer.malformed["hand/pose"]
    assert [m.data for m in LogReader(path).messages()] == sent    # recorded as is, in order
    not_messages = 0
    for payload in sent:
        try:
            decode(payload)
        except MessageError:
            not_messages += 1
    assert malformed <= not_messages      # only what is not a message map can be counted so


# ---- a page's messages -----------------------------------------------------------------------------

SOURCE = {"handedness": "right", "grip": [0.0, 1.2, -0.45, 0, 0, 0, 1], "trigger": 0.5, "buttons": ["a"],
          "joints": None}
PAGE_VALID = [{"type": "input", "time": 1000.0, "tracking": True, "head": [0, 1.6, 0, 0, 0, 0, 1],
               "sources": [SOURCE]},
              {"type": "session", "mode": "immersive", "active": True}, {"type": "stats", "fps": 72.0},
              {"type": "recenter", "head": [0, 1.6, 0, 0, 0, 0, 1]}]


@st.composite
def page_messages(draw):
    """Text or bytes: random, JSON of anything, or a valid message with one value replaced."""
    kind = draw(st.integers(0, 3))
    if kind == 0:
        return draw(st.text(max_size=100) | st.binary(max_size=50))
    if kind == 1:
        return json.dumps(_jsonable(draw(json_like)))
    msg = json.loads(json.dumps(draw(st.sampled_from(PAGE_VALID))))
    if kind == 2:
        target = msg
        if "sources" in msg and draw(st.booleans()):
            target = msg["sources"][0]
        target[draw(st.sampled_from(sorted(target)))] = _jsonable(draw(json_like))
    return json.dumps(msg, allow_nan=True)


def _jsonable(value):
    if isinstance(value, bytes):
        return value.decode("latin-1")
    if isinstance(value, list):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, int) and abs(value) > 2**53:
        return float(value)
    return value


GLOVE = load_glove()
CALIBRATION = load_calibration(REPO / "config/calibration.yaml", "hand_in_grip")


@FAST
@given(data=st.lists(page_messages(), min_size=1, max_size=5))
def test_any_page_message_is_acted_on_or_counted_and_the_bridge_keeps_serving(data):
    published = []
    bridge = WebBridge(BridgeConfig(tracker=True), GLOVE, CALIBRATION, Placement(0.5, 0.3),
                       publish=lambda topic, msg: published.append(msg), broadcast=lambda *a: None,
                       send=lambda *a: None, now=lambda: 1000.0)
    bridge.connected(1, "fuzz")
    rejected = ("page_malformed", "page_oversized", "page_non_finite")
    for i, message in enumerate(data):
        before = sum(bridge.counts[k] for k in rejected)
        bridge.page_message(1, message, 1000.0 + i * 0.01)
        assert bridge.counts["page_messages"] == i + 1
        assert sum(bridge.counts[k] for k in rejected) - before in (0, 1)
    for msg in published:   # what it did publish is a valid message, finite where it must be
        assert decode(encode(msg), type(msg)) is not None
        assert np.all(np.isfinite(msg.position))
    bridge.tick()


# ---- CAN frames at a board -------------------------------------------------------------------------

CFG = load_glove_can(REPO / "tests/data/glove_can_test.yaml")
PROTO = GloveProtocol(CFG)
IDS = sorted({0x000} | {base + b.id for b in CFG.boards for base in (0x180, 0x200, 0x700)})


@st.composite
def can_frames(draw):
    if draw(st.integers(0, 3)) == 0:   # a valid frame now and then: the boards get to run
        kind = draw(st.sampled_from(["start", "stop", "duty"]))
        if kind == "duty":
            board = draw(st.sampled_from([b.id for b in CFG.boards]))
            return PROTO.duty(board, draw(st.lists(st.integers(0, 127), min_size=8, max_size=8)),
                              draw(st.integers(0, 255)))
        return PROTO.nmt("START" if kind == "start" else "STOP", draw(st.sampled_from([0, *[b.id for b in CFG.boards]])))
    return can.Message(arbitration_id=draw(st.sampled_from(IDS) | st.integers(0, 0x7FF)),
                       data=draw(st.binary(max_size=8)), is_extended_id=draw(st.booleans()) and draw(st.booleans()),
                       is_remote_frame=draw(st.integers(0, 9)) == 0, is_error_frame=draw(st.integers(0, 9)) == 0)


@pytest.fixture(scope="module")
def emulators():
    made = {kind: make_glove_emulator(kind, CFG, interface="virtual", channel=f"fuzz-{uuid.uuid4().hex}")
            for kind in ("python", "firmware")}
    yield made
    for emu in made.values():
        emu.bus.shutdown()


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(can_frames(), min_size=1, max_size=12))
def test_any_can_frame_is_applied_or_counted_the_same_by_the_python_and_firmware_boards(emulators, frames):
    now = 1000.0
    for emu in emulators.values():
        for board in emu.boards.values():
            board.boot(now)
    for msg in frames:
        now += 0.001
        try:
            decoded = PROTO.decode(msg)
        except FrameError:
            decoded = "rejected"
        outcome = {}
        for kind, emu in emulators.items():
            before = {b: (list(board.levels), sum(board.counters[r] for r in REJECTED))
                      for b, board in emu.boards.items()}
            emu.process(msg, now)
            after = {b: (list(board.levels), sum(board.counters[r] for r in REJECTED))
                     for b, board in emu.boards.items()}
            outcome[kind] = after
            if decoded == "rejected" or decoded is None:
                for b in before:   # a frame it rejects changes no output...
                    assert after[b][0] == before[b][0], (kind, msg)
                # ...and one addressed to the boards (NMT, duty, an id the glove does not use) is
                # counted; another board's status or heartbeat is their traffic, not a rejection.
                addressed = msg.is_extended_id or PROTO.decode_kind(msg.arbitration_id) is None \
                    or PROTO.decode_kind(msg.arbitration_id)[0] in ("nmt", "duty")
                if addressed:
                    assert any(after[b][1] > before[b][1] for b in before), (kind, msg)
            assert all(0 <= v <= 127 for levels, _ in after.values() for v in levels)
        assert outcome["python"] == outcome["firmware"], msg


# ---- scene and launch files -------------------------------------------------------------------------

scene_values = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 3) | st.floats(-3, 3) | st.floats() | st.text(max_size=6)
    | st.sampled_from(["tesseract", "24-cell", "xw", "red", "#ff0000", "perspective", "vertices", "parts"]),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(
        st.sampled_from(["objects", "shape", "name", "size", "position", "rotation", "color", "vertices", "halfspaces",
                         "parts", "params", "projection", "eye_distance", "selected"]) | st.text(max_size=4),
        inner, max_size=5), max_leaves=20)
GOOD_SCENE = yaml.safe_load((REPO / "config/scenes/multi-object.yaml").read_text())


@st.composite
def scenes(draw):
    if draw(st.booleans()):
        return draw(scene_values)
    data = json.loads(json.dumps(GOOD_SCENE))
    obj = data["objects"][draw(st.integers(0, len(data["objects"]) - 1))]
    obj[draw(st.sampled_from(sorted(obj) + ["vertices", "rotation"]))] = draw(scene_values)
    return data


@settings(max_examples=80, deadline=None)
@given(data=scenes())
def test_any_scene_data_is_a_scene_or_a_config_error_naming_the_file(data):
    try:
        scene = parse_scene(data, "fuzz.yaml")
    except Touch4dError as exc:
        assert "fuzz.yaml" in str(exc)
        return
    assert scene.objects is not None


@settings(max_examples=60, deadline=None)
@given(text=st.text(max_size=120) | scene_values.map(lambda v: yaml.safe_dump({"nodes": v})))
def test_any_launch_file_text_is_a_launch_or_a_config_error_naming_the_file(tmp_path_factory, text):
    from touch4d.bus.launchfile import load_launch

    path = tmp_path_factory.mktemp("fuzz") / "l.yaml"
    path.write_text(text)
    try:
        load_launch(path)
    except Touch4dError as exc:
        assert str(path) in str(exc) or "l.yaml" in str(exc)


def alias_bomb(levels: int = 9) -> str:
    """YAML whose last list, expanded, holds 9^levels items (anchors and aliases: a few hundred bytes)."""
    rows = ["- &a0 [x, x, x, x, x, x, x, x, x]"]
    rows += [f"- &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, levels)]
    return "\n".join(rows)


def test_a_yaml_alias_bomb_in_a_scene_or_launch_file_is_refused_at_once(tmp_path):
    import signal

    from touch4d.bus.launchfile import load_launch
    from touch4d.errors import ConfigError
    from touch4d.geometry.scene import load_scene

    bomb = "\n".join("      " + row for row in alias_bomb().splitlines())
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"objects:\n  - shape: tesseract\n    size:\n{bomb}\n")
    launch = tmp_path / "launch.yaml"
    launch.write_text(f"nodes:\n  tracker:\n    node: scripted\n    params:\n      rate:\n{bomb}\n")
    # A mapping parameter takes any values: it would go to the node as JSON of 9^9 values.
    remap = tmp_path / "remap.yaml"
    deeper = "\n".join("    " + row for row in bomb.splitlines())
    remap.write_text(f"nodes:\n  tracker:\n    node: replay\n    params:\n      remap:\n        a:\n{deeper}\n")

    def hung(signum, frame):
        raise TimeoutError("still expanding the aliases after 10 s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(10)
    try:
        for load, path, key in ((load_scene, scene, "objects[0].size"), (load_launch, launch, "nodes.tracker.params.rate"),
                                (load_launch, remap, "nodes.tracker.params.remap")):
            started = time.process_time()     # this process's CPU: a loaded machine's waits do not count
            with pytest.raises(ConfigError) as err:
                load(path)
            assert time.process_time() - started < 2.0   # refused before expanding (that takes minutes)
            assert key in str(err.value) and len(str(err.value)) < 1000
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)

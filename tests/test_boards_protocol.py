"""The glove's CAN protocol: generated DBC, frame layout, round trips, malformed frames, config errors."""
from __future__ import annotations

from pathlib import Path

import can
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.cli import main as cli_main
from touch4d.errors import ConfigError
from touch4d.boards.config import DEFAULT_GLOVE, glove_can_from_mapping, load_glove_can
from touch4d.boards.dbc import build_database, dbc_text, load_dbc
from touch4d.boards.protocol import FAULT_NAMES, FrameError, GloveProtocol

ROOT = Path(__file__).resolve().parents[1]
TEST_GLOVE = ROOT / "tests" / "data" / "glove_can_test.yaml"
CFG = load_glove_can(TEST_GLOVE)
PROTO = GloveProtocol(CFG)
LOADED = load_dbc(dbc_text(CFG))


def test_committed_dbc_is_what_the_cli_generates(tmp_path, capsys):
    out = tmp_path / "glove.dbc"
    assert cli_main(["glove", "dbc", "-o", str(out)]) == 0
    assert out.read_bytes() == (ROOT / "config" / "glove.dbc").read_bytes()
    assert cli_main(["glove", "dbc", "--glove", str(DEFAULT_GLOVE)]) == 0
    assert capsys.readouterr().out.encode() == out.read_bytes()


def test_default_dbc_loads_with_every_frame_of_every_board():
    db = load_dbc((ROOT / "config" / "glove.dbc").read_text())
    cfg = load_glove_can()
    names = {m.name: m for m in db.messages}
    assert set(names) == {"NMT"} | {f"{k}_B{b.id}" for b in cfg.boards for k in ("Duty", "Status", "Heartbeat")}
    for b in cfg.boards:
        assert names[f"Duty_B{b.id}"].frame_id == 0x200 + b.id
        assert names[f"Status_B{b.id}"].frame_id == 0x180 + b.id
        assert names[f"Heartbeat_B{b.id}"].frame_id == 0x700 + b.id
        assert names[f"Duty_B{b.id}"].length == 8
        assert names[f"Duty_B{b.id}"].cycle_time == 5  # 200 Hz refresh
    # The broadcast stop wins arbitration against every other frame of the glove.
    assert names["NMT"].frame_id == min(m.frame_id for m in db.messages) == 0


def test_duty_frame_layout_counter_then_seven_bits_per_channel():
    msg = PROTO.duty(2, [1, 0, 0, 0, 0, 0, 0, 0], counter=0xA5)
    assert msg.arbitration_id == 0x202 and not msg.is_extended_id
    assert bytes(msg.data) == bytes([0xA5, 0x01, 0, 0, 0, 0, 0, 0])
    # channel 1's lowest bit is bit 15 (8 + 7): the top bit of byte 1
    assert bytes(PROTO.duty(2, [0, 1] + [0] * 6, 0).data) == bytes([0, 0x80, 0, 0, 0, 0, 0, 0])
    assert bytes(PROTO.duty(1, [127] * 8, 0xFF).data) == b"\xff" * 8
    assert bytes(PROTO.nmt("STOP").data) == bytes([2, 0])


def test_encode_is_strict_about_range():
    with pytest.raises(Exception, match="Duty_Ch0"):
        PROTO.duty(1, [128] + [0] * 7, 0)
    with pytest.raises(Exception):
        PROTO.duty(1, [0] * 7, 0)  # a channel missing


levels = st.lists(st.integers(0, 127), min_size=8, max_size=8)


@settings(max_examples=60, deadline=None)
@given(board=st.sampled_from([b.id for b in CFG.boards]), lv=levels, counter=st.integers(0, 255),
       state=st.sampled_from(["IDLE", "ACTIVE", "WATCHDOG_OFF", "STOPPED", "FAULT_OFF", "PRE_OPERATIONAL"]),
       faults=st.sets(st.sampled_from(FAULT_NAMES)), mask=st.integers(0, 255), bad=st.integers(0, 70000),
       nmt_state=st.sampled_from(["BOOTUP", "STOPPED", "OPERATIONAL", "PRE_OPERATIONAL"]),
       command=st.sampled_from(["START", "STOP", "PRE_OPERATIONAL", "RESET_NODE"]), node=st.integers(0, 127))
def test_every_frame_round_trips_through_the_generated_dbc(board, lv, counter, state, faults, mask, bad,
                                                            nmt_state, command, node):
    db = LOADED
    duty = PROTO.duty(board, lv, counter)
    f = PROTO.decode(duty)
    assert (f.kind, f.board, PROTO.levels(f, 8), f.signals["Counter"]) == ("duty", board, lv, counter)
    raw = db.decode_message(duty.arbitration_id, duty.data, scaling=False)
    assert [raw[f"Duty_Ch{c}"] for c in range(8)] == lv
    physical = db.decode_message(duty.arbitration_id, duty.data)
    assert [physical[f"Duty_Ch{c}"] for c in range(8)] == pytest.approx([v / 127 for v in lv])

    status = PROTO.status(board, state, faults, counter, mask, bad)
    f = PROTO.decode(status)
    assert (f.kind, f.board, PROTO.state_name(f), set(PROTO.faults(f))) == ("status", board, state, faults)
    assert (f.signals["LastCounter"], f.signals["ActiveMask"], f.signals["BadFrames"]) == (counter, mask, min(bad, 65535))
    assert db.decode_message(status.arbitration_id, status.data)["State"] == state

    hb = PROTO.heartbeat(board, nmt_state)
    f = PROTO.decode(hb)
    assert (hb.arbitration_id, f.kind, PROTO.state_name(f)) == (0x700 + board, "heartbeat", nmt_state)
    assert db.decode_message(hb.arbitration_id, hb.data)["State"] == nmt_state

    nmt = PROTO.nmt(command, node)
    f = PROTO.decode(nmt)
    assert (f.kind, f.board) == ("nmt", node)
    assert db.decode_message(0, nmt.data) == {"Command": command, "Node": node}



def test_unknown_ids_decode_to_none_and_malformed_frames_raise():
    assert PROTO.decode(can.Message(arbitration_id=0x123, data=b"\x00")) is None
    assert PROTO.decode(can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=True)) is None
    bad = [
        can.Message(arbitration_id=0x201, data=bytes(7), is_extended_id=False),           # short
        can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False, is_remote_frame=True),
        can.Message(arbitration_id=0x000, data=bytes([7, 0]), is_extended_id=False),      # no such command
        can.Message(arbitration_id=0x701, data=bytes([9]), is_extended_id=False),         # no such state
        can.Message(arbitration_id=0x181, data=bytes([77, 0, 0, 0, 0, 0]), is_extended_id=False),
        can.Message(arbitration_id=0x001, is_error_frame=True),
    ]
    for msg in bad:
        with pytest.raises(FrameError):
            PROTO.decode(msg)


def test_fewer_channels_give_a_shorter_duty_frame():
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["motors"] = [{"name": "a", "position": [0, 0, 0], "board": 5, "channel": 2}]
    data["can"]["boards"] = [{"id": 5, "channels": 3}]
    cfg = glove_can_from_mapping(data, "mini.yaml")
    db = build_database(cfg)
    msg = db.get_message_by_name("Duty_B5")
    assert msg.length == 4  # 8 + 3 x 7 = 29 bits
    proto = GloveProtocol(cfg)
    f = proto.decode(proto.duty(5, [0, 0, 99], 3))
    assert proto.levels(f, 3) == [0, 0, 99]


@pytest.mark.parametrize("change, key", [
    (lambda d: d["motors"][0].update(board=9), "motors[0].board"),
    (lambda d: d["motors"][1].update(board=1, channel=0), "motors[1].channel"),
    (lambda d: d["can"]["boards"][0].update(channels=9), "can.boards[0].channels"),
    (lambda d: d["can"].update(refresh_hz=0), "can.refresh_hz"),
    (lambda d: d["can"].update(refersh_hz=100), "can.refersh_hz"),
    (lambda d: d["can"].update(duty={"start": 0.9, "max": 0.5}), "can.duty.start"),
    (lambda d: d["can"].update(ids={"status": 0x1FF}), "can.ids.status"),
    (lambda d: d["can"].update(ids={"duty": 0x700}), "can.ids.heartbeat"),  # clashes with duty
    (lambda d: d["can"].update(thermal={"max_on_s": "long"}), "can.thermal.max_on_s"),
    (lambda d: d["can"]["boards"].append({"id": 1, "channels": 8}), "can.boards[4].id"),
])
def test_bad_glove_config_names_the_key(change, key):
    data = yaml.safe_load(TEST_GLOVE.read_text())
    change(data)
    with pytest.raises(ConfigError) as err:
        glove_can_from_mapping(data, "bad.yaml")
    assert f"'{key}'" in str(err.value) and "bad.yaml" in str(err.value)


def test_the_duty_curves_old_gamma_key_points_to_exponent():
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["can"]["duty"] = {"gamma": 2.0}
    with pytest.raises(ConfigError) as err:
        glove_can_from_mapping(data, "old.yaml")
    text = str(err.value)
    assert "'can.duty.gamma'" in text and "can.duty.exponent" in text and "old.yaml" in text


def test_cli_reports_a_bad_glove_file_without_traceback(tmp_path, capsys):
    bad = tmp_path / "g.yaml"
    bad.write_text("motors: [\n")
    assert cli_main(["glove", "dbc", "--glove", str(bad)]) == 2
    assert "g.yaml" in capsys.readouterr().err

"""Log files without a bus: writing, reading, schemas, seq gaps, info, exports, damaged files."""
from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from touch4d.cli import main as touch4d_main
from touch4d.log.export import export_csv, export_foxglove, export_json, flatten
from touch4d.log.gaps import SeqGaps
from touch4d.log.reader import LogFileError, LogReader
from touch4d.log.summary import summarize
from touch4d.log.writer import LogWriter
from touch4d.messages import HandPose, MotorCommand, SceneState, TactileField, encode

T0 = 1_700_000_000_000_000_000  # ns


def hand(i: int) -> bytes:
    angle = 0.01 * i
    return encode(HandPose(position=np.array([0.1 * i, -0.5, 0.25]),
                           orientation=np.array([0.0, 0.0, math.sin(angle), math.cos(angle)]),
                           valid=True, stamp=1700000000.0 + i / 100, seq=i, source_stamp=1700000000.0 + i / 100))


def field(i: int) -> bytes:
    return encode(TactileField(positions=np.arange(12, dtype=float).reshape(4, 3) + i, l=np.array([0.5, np.nan, 1.0, 2.0]),
                               s=np.array([1.0, 0.0, 0.5, 0.25]), h=np.array([0.9, 0.0, 0.4, 0.2]),
                               alpha=1.0, beta=0.5, gamma=1.0, stamp=1700000000.0 + i / 50, seq=i,
                               source_stamp=1700000000.0 + i / 50 - 0.001))


def write_log(path, n_hand=300, n_field=100, skip=(), chunk_size=1 << 20, flush_every=0, close=True):
    """hand/pose at 100 Hz (seq numbers in `skip` left out) and tactile/field at 50 Hz; returns what was written."""
    written = []
    w = LogWriter(path, chunk_size=chunk_size)
    events = [(T0 + i * 10_000_000, "hand/pose", i) for i in range(n_hand) if i not in skip]
    events += [(T0 + i * 20_000_000 + 1, "tactile/field", i) for i in range(n_field)]
    for k, (t, topic, i) in enumerate(sorted(events)):
        payload = hand(i) if topic == "hand/pose" else field(i)
        w.write(topic, payload, t)
        written.append((topic, t, payload))
        if flush_every and (k + 1) % flush_every == 0:
            w.flush()
    if close:
        w.close({"note": "test"})
    else:
        w.flush()
    return written


def test_roundtrip_keeps_bytes_times_order_and_types(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_log(path)
    reader = LogReader(path)
    got = list(reader.messages())
    assert [(m.topic, m.log_time, m.data) for m in got] == written
    assert {m.type for m in got if m.topic == "hand/pose"} == {"HandPose"}
    first_hand = next(m for m in got if m.topic == "hand/pose")
    assert first_hand.publish_time == 1_700_000_000_000_000_000
    assert [m.sequence for m in got if m.topic == "tactile/field"] == list(range(100))
    assert reader.metadata["touch4d.recording"] == {"note": "test"}
    assert reader.topics() == {"hand/pose": "HandPose", "tactile/field": "TactileField"}


def test_standard_mcap_reader_sees_msgpack_channels_and_json_schemas(tmp_path):
    path = tmp_path / "a.mcap"
    write_log(path)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {"hand/pose", "tactile/field"}
    assert {c.message_encoding for c in channels.values()} == {"msgpack"}
    schema = summary.schemas[channels["tactile/field"].schema_id]
    assert (schema.name, schema.encoding) == ("TactileField", "jsonschema")
    doc = json.loads(schema.data)
    assert doc["properties"]["positions"]["items"]["maxItems"] == 3
    assert doc["properties"]["l"]["items"]["type"] == ["number", "null"]
    assert "eq. 7" in doc["properties"]["l"]["description"]
    assert summary.statistics.channel_message_counts[channels["hand/pose"].id] == 300


def test_one_schema_per_type_shared_by_topics(tmp_path):
    path = tmp_path / "a.mcap"
    with LogWriter(path) as w:
        for topic in ("hand/pose", "hand/pose_left"):
            w.write(topic, hand(0), T0)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert len(summary.schemas) == 1 and len(summary.channels) == 2


def test_malformed_payloads_are_kept_and_counted(tmp_path):
    path = tmp_path / "a.mcap"
    w = LogWriter(path)
    w.write("hand/pose", b"\xc1 not msgpack", T0)
    w.write("hand/pose", hand(0), T0 + 1)
    assert w.malformed == {"hand/pose": 1}
    w.close()
    got = list(LogReader(path).messages())
    assert [m.data for m in got] == [b"\xc1 not msgpack", hand(0)]
    assert [m.type for m in got] == ["", "HandPose"]


def test_seq_gaps_single_and_interleaved_publishers():
    g = SeqGaps()
    for seq in [0, 1, 2, 5, 6, 9]:
        g.add("a", seq)
    assert g.lost["a"] == 4 and g.gaps["a"] == 2
    # two publishers on one topic (heartbeats), one restarting at 0: no gap at all
    for seq in [10, 3, 11, 4, 12, 5, 0, 13, 1]:
        g.add("b", seq)
    assert g.lost.get("b", 0) == 0 and g.streams("b") == 3
    g.add("b", 16)  # the publisher at 13 skipped 14 and 15
    assert g.report() == {"a": 4, "b": 2}


def test_info_counts_rates_duration_and_lost(tmp_path):
    path = tmp_path / "a.mcap"
    write_log(path, skip={10, 11, 12, 50})
    s = summarize(str(path))
    topics = {t.topic: t for t in s.topics}
    assert topics["hand/pose"].count == 296 and topics["hand/pose"].lost == 4
    assert topics["tactile/field"].lost == 0
    assert topics["tactile/field"].rate == pytest.approx(50.0, rel=1e-6)
    assert s.duration == pytest.approx(2.99, abs=1e-6)
    assert s.complete and not s.problems


def test_info_cli_text_and_json(tmp_path, capsys):
    path = tmp_path / "a.mcap"
    write_log(path)
    assert touch4d_main(["log", "info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "hand/pose" in text and "HandPose" in text and "100.00" in text
    assert touch4d_main(["log", "info", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["count"] == 400
    assert {t["topic"]: t["count"] for t in data["topics"]} == {"hand/pose": 300, "tactile/field": 100}


def _same(a, b) -> bool:
    if isinstance(a, float) and math.isnan(a):
        return b is None or (isinstance(b, float) and math.isnan(b))
    return a == b


def test_csv_export_loads_back_with_the_same_values(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_log(path)
    out = io.StringIO()
    assert export_csv(LogReader(path), "tactile/field", out).written == 100
    rows = list(csv.DictReader(io.StringIO(out.getvalue())))
    expected = [(t, flatten(LogReaderMessage(p))) for topic, t, p in written if topic == "tactile/field"]
    assert len(rows) == len(expected)
    for row, (t, fields) in zip(rows, expected):
        assert float(row["log_time"]) == t / 1e9
        assert row["type"] == "TactileField"
        for key, value in fields.items():
            if isinstance(value, str):
                assert row[key] == value
            else:
                assert _same(value, float(row[key])), key
    assert "positions.3.2" in rows[0] and "l.1" in rows[0]


def LogReaderMessage(payload: bytes):
    from touch4d.messages.codec import unpack
    return unpack(payload)


def test_json_export_loads_back_with_the_same_values(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_log(path)
    out = io.StringIO()
    export_json(LogReader(path), "hand/pose", out)
    rows = [json.loads(line) for line in out.getvalue().splitlines()]
    # a live log: every row has the header's recorded_stamp column, 0 (= live)
    expected = [{**flatten(LogReaderMessage(p)), "recorded_stamp": 0.0}
                for topic, _, p in written if topic == "hand/pose"]
    assert len(rows) == 300
    for row, fields in zip(rows, expected):
        assert {k: v for k, v in row.items() if k != "log_time"} == fields
    assert list(rows[0])[:6] == ["log_time", "type", "stamp", "seq", "source_stamp", "recorded_stamp"]
    out = io.StringIO()
    export_json(LogReader(path), "tactile/field", out)
    assert json.loads(out.getvalue().splitlines()[0])["l.1"] is None  # NaN: JSON has none


def test_exports_give_the_recorded_stamp_of_replayed_messages(tmp_path):
    from touch4d.log.restamp import restamp

    path, fox = tmp_path / "replayed.mcap", tmp_path / "fox.mcap"
    with LogWriter(path) as w:
        for i in range(3):
            w.write("hand/pose", restamp(hand(i), 1800000000.0 + i, i), T0 + i)
    out = io.StringIO()
    export_json(LogReader(path), "hand/pose", out)
    rows = [json.loads(line) for line in out.getvalue().splitlines()]
    assert [(r["stamp"], r["recorded_stamp"]) for r in rows] == \
        [(1800000000.0 + i, 1700000000 + i / 100) for i in range(3)]
    export_foxglove(LogReader(path), str(fox))
    with open(fox, "rb") as f:
        got = [json.loads(m.data)["recorded_stamp"] for _, _, m in make_reader(f).iter_messages()]
    assert got == [1700000000 + i / 100 for i in range(3)]


def test_foxglove_export_is_json_mcap_with_the_same_values(tmp_path):
    path, out = tmp_path / "a.mcap", tmp_path / "fox.mcap"
    written = write_log(path)
    assert export_foxglove(LogReader(path), str(out)).written == 400
    with open(out, "rb") as f:
        reader = make_reader(f)
        got = list(reader.iter_messages(log_time_order=False))
        summary = reader.get_summary()
    assert {c.message_encoding for c in summary.channels.values()} == {"json"}
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    assert len(got) == len(written)
    for (schema, channel, message), (topic, t, payload) in zip(got, written):
        assert channel.topic == topic and message.log_time == t
        decoded = json.loads(message.data)
        original = LogReaderMessage(payload)
        assert decoded["position" if topic == "hand/pose" else "positions"] == \
            original["position" if topic == "hand/pose" else "positions"].tolist()
        if topic == "tactile/field":
            assert decoded["l"] == [0.5, None, 1.0, 2.0]


def test_export_of_an_unknown_topic_names_the_topics_there(tmp_path, capsys):
    path = tmp_path / "a.mcap"
    write_log(path, n_hand=3, n_field=1)
    assert touch4d_main(["log", "export", str(path), "--format", "csv", "--topic", "hand/psoe"]) == 2
    err = capsys.readouterr().err
    assert "hand/psoe" in err and "hand/pose, tactile/field" in err and str(path) in err


def test_export_cli_writes_files(tmp_path):
    path = tmp_path / "a.mcap"
    write_log(path, n_hand=5, n_field=2)
    assert touch4d_main(["log", "export", str(path), "--format", "csv", "--topic", "hand/pose",
                         "-o", str(tmp_path / "h.csv")]) == 0
    assert len(list(csv.DictReader(open(tmp_path / "h.csv")))) == 5
    assert touch4d_main(["log", "export", str(path), "--format", "foxglove", "--topic", "tactile/field"]) == 0
    assert summarize(str(tmp_path / "a.foxglove.mcap")).count == 2


# ---- damaged files ------------------------------------------------------------------------------


def chunk_spans(path) -> list[tuple[int, int]]:
    """(start, end) byte offsets of the Chunk records of an intact (maybe unfinished) file."""
    spans = []
    with open(path, "rb") as f:
        start = 8
        try:
            for record in StreamReader(f, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    spans.append((start, f.tell()))
                start = f.tell()
        except EndOfFile:
            pass
    return spans


def test_truncated_file_gives_a_clear_error_and_recovers_flushed_chunks(tmp_path, capsys):
    path = tmp_path / "cut.mcap"
    # ~45 messages per flushed chunk; the file is cut in the middle of the last chunk
    written = write_log(path, close=False, flush_every=45)
    last_start, last_end = chunk_spans(path)[-1]
    with open(path, "r+b") as f:
        f.truncate((last_start + last_end) // 2)
    with pytest.raises(LogFileError) as exc:
        LogReader(path)
    assert str(path) in str(exc.value) and "truncated" in str(exc.value)
    reader = LogReader(path, recover=True)
    got = list(reader.messages())
    complete_chunks = len(written) // 45 * 45  # every chunk but the last, cut one (of 400 % 45)
    assert [(m.topic, m.log_time, m.data) for m in got] == written[:complete_chunks]
    assert reader.problems == [f"the file ends inside a record at byte {(last_start + last_end) // 2} "
                               f"(truncated after byte {last_start})"]
    # the recover command writes a complete copy of what was readable
    out = tmp_path / "fixed.mcap"
    assert touch4d_main(["log", "recover", str(path), "-o", str(out)]) == 0
    assert f"recovered {complete_chunks} messages" in capsys.readouterr().out
    assert [m.data for m in LogReader(out).messages()] == [p for _, _, p in written[:complete_chunks]]


def corrupt_second_chunk(path) -> int:
    """Zero 16 bytes in the middle of the second chunk of a complete log; returns the chunk's offset."""
    data = bytearray(path.read_bytes())
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    second = chunks[1]
    middle = second.chunk_start_offset + second.chunk_length // 2
    data[middle:middle + 16] = b"\x00" * 16
    path.write_bytes(bytes(data))
    return second.chunk_start_offset


def test_corrupt_chunk_in_the_middle_is_skipped_counted_and_named(tmp_path):
    path = tmp_path / "bad.mcap"
    written = write_log(path, flush_every=100)  # 4 chunks of 100 messages
    offset = corrupt_second_chunk(path)
    for recover in (False, True):  # a damaged chunk never stops the reading: it is skipped and counted
        reader = LogReader(path, recover=recover)
        got = [m.data for m in reader.messages()]
        assert got == [p for _, _, p in written[:100] + written[200:]]
        assert (reader.skipped_chunks, reader.skipped_messages) == (1, 100)
        assert len(reader.problems) == 1
        assert f"damaged chunk at byte {offset}" in reader.problems[0]
        assert "skipped, 100 message(s) lost" in reader.problems[0]


def test_damaged_chunk_cli_goes_on_warns_and_exits_0(tmp_path, capsys):
    path = tmp_path / "bad.mcap"
    written = write_log(path, flush_every=100)
    offset = corrupt_second_chunk(path)
    assert touch4d_main(["log", "info", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["count"] == 300
    assert f"warning: {path}: damaged chunk at byte {offset}" in captured.err
    assert "1 damaged chunk skipped, 100 message(s) lost" in captured.err
    out = tmp_path / "h.csv"
    assert touch4d_main(["log", "export", str(path), "--format", "csv", "--topic", "hand/pose", "-o", str(out)]) == 0
    rows = list(csv.DictReader(open(out)))
    assert len(rows) == sum(1 for topic, _, _ in written[:100] + written[200:] if topic == "hand/pose")
    assert "1 damaged chunk skipped, 100 message(s) lost" in capsys.readouterr().err


def test_not_an_mcap_file_and_missing_file(tmp_path):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello, not a log")
    with pytest.raises(LogFileError, match="not an MCAP log"):
        LogReader(bad)
    with pytest.raises(LogFileError, match="no such file"):
        LogReader(tmp_path / "missing.mcap")


def test_damaged_file_cli_error_without_traceback(tmp_path, capsys):
    path = tmp_path / "cut.mcap"
    write_log(path, close=False, flush_every=50)
    assert touch4d_main(["log", "info", str(path)]) == 2
    err = capsys.readouterr().err
    assert "truncated" in err and "--recover" in err and "Traceback" not in err
    assert touch4d_main(["log", "info", str(path), "--recover"]) == 0
    assert "incomplete" in capsys.readouterr().out


def test_other_message_types_flatten_into_columns(tmp_path):
    path = tmp_path / "a.mcap"
    with LogWriter(path) as w:
        w.write("tactile/motors", encode(MotorCommand(names=["thumb", "index"], intensity=np.array([0.5, 1.0]),
                                                      stamp=1.0, seq=0, source_stamp=1.0)), T0)
        w.write("scene/state", encode(SceneState(stamp=1.0, seq=0, source_stamp=1.0)), T0 + 1)
    out = io.StringIO()
    export_csv(LogReader(path), "tactile/motors", out)
    row = next(csv.DictReader(io.StringIO(out.getvalue())))
    assert (row["names.0"], row["names.1"], float(row["intensity.1"])) == ("thumb", "index", 1.0)


def test_header_peek_finds_keys_anywhere_and_rejects_non_messages():
    import msgpack
    from touch4d.log.writer import peek_header
    late = msgpack.packb({"a": "x" * 300, "seq": 3, "type": "HandPose", "stamp": 2.5})
    assert peek_header(late) == ("HandPose", 2.5, 3)
    assert peek_header(hand(7)) == ("HandPose", 1700000000.07, 7)
    assert peek_header(msgpack.packb([1, 2])) is None
    assert peek_header(b"\xc1") is None
    assert peek_header(msgpack.packb({"type": "X", "stamp": float("nan"), "seq": -4})) == ("X", 0.0, -1)


def test_seq_gaps_stay_bounded_for_publishers_that_do_not_count():
    g = SeqGaps()
    for _ in range(1000):
        g.add("t", 0)  # a foreign publisher that always sends seq 0
    assert g.streams("t") == 1 and g.total_lost() == 0
    for seq in range(1000, 0, -1):  # counting down: each one looks like a new publisher
        g.add("u", seq)
    assert g.streams("u") == 32 and g.total_lost() == 0


def test_the_index_gives_topics_counts_and_times_without_reading_messages(tmp_path):
    from touch4d.log.summary import indexed_summary

    path = tmp_path / "a.mcap"
    written = write_log(path, skip={0, 299}, flush_every=60)
    reader = LogReader(path)
    quick = indexed_summary(reader)
    assert reader.channels == {}  # nothing read but the summary section
    assert reader.metadata["touch4d.recording"] == {"note": "test"}
    for topic in ("hand/pose", "tactile/field"):
        times = [t for tp, t, _ in written if tp == topic]
        t = next(t for t in quick.topics if t.topic == topic)
        assert (t.count, t.first, t.last) == (len(times), times[0], times[-1])
    assert quick.start == written[0][1]
    assert reader.topics() == {"hand/pose": "HandPose", "tactile/field": "TactileField"}
    assert reader.channels == {}
    # an unfinished file has no index: read through instead
    cut = tmp_path / "cut.mcap"
    write_log(cut, close=False, flush_every=60)
    assert indexed_summary(LogReader(cut, recover=True)) is None


def test_reading_from_a_time_starts_at_its_chunk(tmp_path):
    path = tmp_path / "a.mcap"
    written = write_log(path, flush_every=100)  # 4 chunks of 100 messages
    start = written[250][1]
    expected = [(topic, t, p) for topic, t, p in written if t >= start]
    assert [(m.topic, m.log_time, m.data) for m in LogReader(path).messages(start=start)] == expected
    assert [m.data for m in LogReader(path).messages({"tactile/field"}, start=start)] == \
        [p for topic, _, p in expected if topic == "tactile/field"]
    # the chunks before the start are not read at all: damage there goes unnoticed
    corrupt_second_chunk(path)
    reader = LogReader(path)
    assert [(m.topic, m.log_time, m.data) for m in reader.messages(start=start)] == expected
    assert reader.problems == [] and reader.skipped_chunks == 0


@settings(max_examples=300, deadline=None)
@given(seq=st.integers(0, 2**64 - 1), stamp=st.floats(allow_nan=True, allow_infinity=True),
       name=st.text(min_size=1, max_size=40), reorder=st.booleans())
def test_header_peek_reads_what_a_full_decode_reads(seq, stamp, name, reorder):
    import msgpack
    from touch4d.log.writer import peek_header

    fields = {"type": name, "stamp": stamp, "seq": seq, "source_stamp": 1.0, "position": b"\x00" * 24}
    if reorder:
        fields = dict(reversed(list(fields.items())))
    payload = msgpack.packb(fields)
    decoded = msgpack.unpackb(payload)
    want_stamp = decoded["stamp"] if math.isfinite(decoded["stamp"]) and decoded["stamp"] >= 0 else 0.0
    assert peek_header(payload) == (decoded["type"], want_stamp, decoded["seq"])
    for cut in (1, 7, 20, len(payload) // 2):  # cut short: what is there (-1, 0.0: unknown), never an exception
        got = peek_header(payload[:cut])
        assert got is None or (got[0] == decoded["type"] and got[1] in (want_stamp, 0.0) and got[2] in (seq, -1))

"""`touch4d log export`: one topic as flat CSV or JSON Lines, or the whole log as a JSON-encoded MCAP.

Flat rows hold `log_time` (receive time, seconds) and every field (`recorded_stamp` 0 where the
message was live, the recorded stamp where a replay re-stamped it), nested values flattened into
dotted columns (`position.0`, `positions.3.1`, `objects.0.name`), ready for pandas
(`read_csv`, `read_json(lines=True)`) or a spreadsheet. The Foxglove copy keeps topics, times and
schemas but encodes messages as JSON, which Foxglove decodes and plots (it does not decode msgpack).
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from typing import IO, Any, Iterable

import numpy as np
from mcap.writer import CompressionType, Writer

from touch4d.messages.codec import CodecError

from .reader import LogFileError, LogReader
from .schema import message_schema, to_jsonable, with_optional_fields

FORMATS = ("csv", "json", "foxglove")


@dataclass
class ExportResult:
    written: int = 0
    skipped: dict[str, int] = field(default_factory=dict)  # topic -> payloads that did not decode

    def skip(self, topic: str) -> None:
        self.skipped[topic] = self.skipped.get(topic, 0) + 1


def flatten(value: Any, prefix: str = "", out: dict | None = None) -> dict[str, Any]:
    """Nested maps, lists and arrays -> {"a.b.0": scalar}; array elements become Python scalars."""
    out = {} if out is None else out
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, dict):
        for key, item in value.items():
            flatten(item, f"{prefix}.{key}" if prefix else str(key), out)
    elif isinstance(value, (list, tuple)):
        for index, item in enumerate(value):
            flatten(item, f"{prefix}.{index}" if prefix else str(index), out)
    else:
        out[prefix] = value
    return out


def check_topics(reader: LogReader, wanted: Iterable[str]) -> dict[str, str]:
    """The log's topic -> type map; raises LogFileError naming any wanted topic it lacks."""
    available = reader.topics()
    missing = [t for t in wanted if t not in available]
    if missing:
        raise LogFileError(f"{reader.path}: no topic {', '.join(repr(t) for t in missing)} in this log; "
                           f"its topics are: {', '.join(sorted(available)) or '(none)'}")
    return available


def flat_rows(reader: LogReader, topic: str, result: ExportResult) -> list[dict[str, Any]]:
    rows = []
    for msg in reader.messages({topic}):
        try:
            data = with_optional_fields(msg.decode())
        except CodecError:
            result.skip(topic)
            continue
        row = {"log_time": msg.log_time / 1e9}
        flatten(data if isinstance(data, dict) else {"value": data}, "", row)
        rows.append(row)
    return rows


def export_csv(reader: LogReader, topic: str, out: IO[str]) -> ExportResult:
    """One topic as CSV: a header of every column seen, one row per message, empty where absent."""
    check_topics(reader, [topic])
    result = ExportResult()
    rows = flat_rows(reader, topic, result)
    columns: dict[str, None] = {}
    for row in rows:
        columns.update(dict.fromkeys(row))
    writer = csv.DictWriter(out, fieldnames=list(columns), restval="", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    result.written = len(rows)
    return result


def export_json(reader: LogReader, topic: str, out: IO[str]) -> ExportResult:
    """One topic as JSON Lines of flat objects; NaN and infinities are null (JSON has none)."""
    check_topics(reader, [topic])
    result = ExportResult()
    for row in flat_rows(reader, topic, result):
        out.write(json.dumps({k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                              for k, v in row.items()}) + "\n")
        result.written += 1
    return result


def export_foxglove(reader: LogReader, out_path: str, topics: list[str] | None = None) -> ExportResult:
    """A copy of the log (all topics, or `topics`) with JSON-encoded messages and JSON schemas."""
    if topics:
        check_topics(reader, topics)
    wanted = set(topics) if topics else None
    result = ExportResult()
    with open(out_path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="", library="touch4d log export")
        schemas: dict[str, int] = {}
        channels: dict[tuple[str, str], int] = {}
        for msg in reader.messages(wanted):
            try:
                data = with_optional_fields(msg.decode())
            except CodecError:
                result.skip(msg.topic)
                continue
            if not msg.type or not isinstance(data, dict):
                result.skip(msg.topic)
                continue
            key = (msg.topic, msg.type)
            if key not in channels:
                if msg.type not in schemas:
                    schema = json.dumps(message_schema(msg.type, data)).encode()
                    schemas[msg.type] = writer.register_schema(msg.type, "jsonschema", schema)
                channels[key] = writer.register_channel(msg.topic, "json", schemas[msg.type])
            writer.add_message(channels[key], log_time=msg.log_time, publish_time=msg.publish_time,
                               sequence=msg.sequence, data=json.dumps(to_jsonable(data)).encode())
            result.written += 1
        writer.finish()
    return result

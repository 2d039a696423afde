"""Writes topic messages into an MCAP file: original msgpack bytes, one channel per topic and type.

Each message keeps its payload exactly as received; MCAP `log_time` is the receive time,
`publish_time` the message's own `stamp` and `sequence` its `seq` (mod 2^32). One JSON schema per
message type describes the fields, so standard MCAP tools (`mcap info`, `mcap filter`,
`mcap recover`) and Foxglove's topic list understand the file. Per message, only the header keys
are read (msgspec skips the rest), so recording costs little beyond the mcap writer's own work.
"""
from __future__ import annotations

import json
import os
import time
from collections import Counter
from typing import IO, Iterable

import msgspec
from mcap.writer import CompressionType, Writer

from touch4d.messages.codec import CodecError, unpack
from touch4d.messages.header import peek, peek_any, peek_fast

from .gaps import SeqGaps
from .reader import LogFileError
from .schema import MSGPACK_NOTE, message_schema

PROFILE = "touch4d"
MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
RECORDING_METADATA = "touch4d.recording"


peek_header = peek   # (type, stamp, seq) of a payload; the header is touch4d.messages.header's


class WallClock:
    """Wall-clock nanoseconds that never step backwards (anchored once, advanced by perf_counter)."""

    def __init__(self) -> None:
        self._wall0 = time.time_ns()
        self._perf0 = time.perf_counter_ns()

    def __call__(self) -> int:
        return self._wall0 + (time.perf_counter_ns() - self._perf0)


class LogWriter:
    """An MCAP log being written; `write` one message or `write_many`, `flush` to make it crash-safe."""

    def __init__(self, path: str | os.PathLike, *, chunk_size: int = 1 << 20,
                 compression: str = "zstd", output: IO[bytes] | None = None) -> None:
        self.path = os.fspath(path)
        try:
            self._file = output if output is not None else open(self.path, "wb")
            self._mcap = Writer(self._file, chunk_size=chunk_size, compression=CompressionType[compression.upper()])
            self._mcap.start(profile=PROFILE, library="touch4d")
            self._file.flush()
        except OSError as exc:
            raise LogFileError(f"{self.path}: cannot write a log here ({exc.strerror or exc})") from None
        self._channels: dict[tuple[str, str], int] = {}
        self._topics: dict[int, str] = {}          # channel -> topic
        self._counts: dict[int, int] = {}          # channel -> messages written
        self._schemas: dict[str, int] = {}
        self.malformed: Counter[str] = Counter()
        self.bytes = 0
        self.first_time = self.last_time = 0
        self.gaps = SeqGaps()
        self._closed = False

    @property
    def counts(self) -> Counter[str]:
        """Messages written per topic."""
        out: Counter[str] = Counter()
        for channel, n in self._counts.items():
            out[self._topics[channel]] += n
        return out

    def write(self, topic: str, payload: bytes, log_time: int) -> None:
        """Record `payload` as received on `topic` at `log_time` (ns since the epoch)."""
        self.write_many(((topic, payload, log_time),))

    def write_many(self, messages: Iterable[tuple[str, bytes, int]]) -> None:
        """Record (topic, payload, log_time) messages in order: the recorder's hot path, kept lean so
        that recording costs little beyond the mcap writer's own work."""
        decode, channels, counts, gaps_add = peek_fast, self._channels, self._counts, self.gaps.add
        add_message = self._mcap.add_message
        size, last = 0, self.last_time
        try:
            for topic, payload, log_time in messages:
                try:  # peek_header, inlined: this loop runs once per recorded message
                    header = decode(payload)
                    type_name, stamp, seq = header.type, header.stamp, header.seq
                except msgspec.DecodeError:
                    header = peek_any(payload)
                    if header is None:
                        self.malformed[topic] += 1
                        header = ("", 0.0, -1)
                    type_name, stamp, seq = header
                channel = channels.get((topic, type_name))
                if channel is None:
                    channel = self._add_channel(topic, type_name, payload)
                    self.first_time = self.first_time or log_time
                if seq >= 0:
                    gaps_add(topic, seq)
                add_message(channel, log_time, payload, int(stamp * 1e9) if stamp > 0 else log_time,
                            seq & 0xFFFFFFFF if seq > 0 else 0)
                counts[channel] += 1
                size += len(payload)
                last = log_time
        finally:  # a write error: what was written is accounted for
            self.bytes += size
            self.last_time = last

    def _add_channel(self, topic: str, type_name: str, payload: bytes) -> int:
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            if type_name:
                try:
                    sample = unpack(payload)
                except CodecError:
                    sample = None
                data = json.dumps(message_schema(type_name, sample)).encode()
                schema_id = self._mcap.register_schema(type_name, SCHEMA_ENCODING, data)
            else:
                schema_id = 0  # not a message map: kept as bytes, no schema
            self._schemas[type_name] = schema_id
        channel = self._mcap.register_channel(topic, MESSAGE_ENCODING, schema_id,
                                              metadata={"encoding_note": MSGPACK_NOTE})
        self._channels[(topic, type_name)] = channel
        self._topics[channel], self._counts[channel] = topic, 0
        return channel

    def flush(self) -> None:
        """Close the chunk in progress and hand it to the OS: a crash after this loses nothing written."""
        self._mcap.flush()

    def close(self, metadata: dict[str, str] | None = None) -> None:
        """Write the recording's metadata, the summary and the footer; the file is then complete."""
        if self._closed:
            return
        self._closed = True
        if metadata:
            self._mcap.add_metadata(RECORDING_METADATA, {str(k): str(v) for k, v in metadata.items()})
        self._mcap.finish()
        self._file.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Reads touch4d MCAP logs in recorded order, and recovers what is readable from damaged ones.

Reading streams the file record by record with mcap's `StreamReader` (no index needed), so a file
cut short by a crash reads up to its last complete chunk. Without `recover`, any damage raises a
`LogFileError` naming the file, the byte offset and what is wrong; with it, damaged chunks are
skipped, the reading stops at a truncation, and each problem is listed in `problems`.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from typing import Iterator

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.opcode import Opcode
from mcap.stream_reader import StreamReader, get_chunk_data_stream

from touch4d.errors import Touch4dError
from touch4d.messages.codec import unpack

MAGIC = b"\x89MCAP0\r\n"


class LogFileError(Touch4dError):
    """A log file that cannot be read as asked: the text names the file and what is wrong."""


@dataclass(frozen=True)
class LogMessage:
    """One recorded message: its topic, type, receive and publish times (ns), seq and original bytes."""

    topic: str
    type: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes

    def decode(self):
        """The payload as plain data (dicts, lists, numpy arrays), without message checks."""
        return unpack(self.data)


def _chunk_records(chunk: Chunk) -> Iterator[object]:
    """The records of a chunk, parsed one at a time (so a large chunk costs no long pause).

    Decompression and the CRC check happen here, before the first record: a damaged chunk raises."""
    stream, length = get_chunk_data_stream(chunk, validate_crc=True)

    def parse() -> Iterator[object]:
        while stream.count < length:
            opcode, size = stream.read1(), stream.read8()
            if opcode == Opcode.MESSAGE:
                yield Message.read(stream, size)
            elif opcode == Opcode.CHANNEL:
                yield Channel.read(stream)
            elif opcode == Opcode.SCHEMA:
                yield Schema.read(stream)
            else:
                stream.read(size)
    return parse()


class LogReader:
    """A log file opened for reading; `messages()` may be called again (e.g. to loop a replay)."""

    def __init__(self, path: str | os.PathLike, *, recover: bool = False) -> None:
        self.path = os.fspath(path)
        self.recover = recover
        self.problems: list[str] = []
        if not os.path.isfile(self.path):
            raise LogFileError(f"{self.path}: no such file")
        size = os.path.getsize(self.path)
        with open(self.path, "rb") as f:
            head = f.read(len(MAGIC))
            f.seek(max(0, size - len(MAGIC)))
            tail = f.read(len(MAGIC))
        if head != MAGIC:
            raise LogFileError(f"{self.path}: not an MCAP log (the file does not start with the MCAP magic bytes)")
        self.complete = size >= 2 * len(MAGIC) + 9 and tail == MAGIC
        if not self.complete and not recover:
            raise LogFileError(
                f"{self.path}: the file is truncated at byte {size} (no footer: the recorder did not finish, "
                f"e.g. it was killed); read what is readable with --recover or `touch4d log recover`"
            )
        self.metadata: dict[str, dict[str, str]] = {}
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}

    def _problem(self, text: str) -> None:
        if not self.recover:
            raise LogFileError(f"{self.path}: {text}; read what is readable with --recover or `touch4d log recover`")
        if text not in self.problems:
            self.problems.append(text)

    def records(self) -> Iterator[object]:
        """Schema, Channel, Message and Metadata records in file order, chunks opened and checked."""
        lost_channels: dict[int, int] = {}
        with open(self.path, "rb") as f:
            reader = StreamReader(f, emit_chunks=True, record_size_limit=1 << 31)
            offset = 0
            it = reader.records
            while True:
                try:
                    record = next(it)
                except StopIteration:
                    break
                except EndOfFile:
                    self._problem(f"the file ends inside a record at byte {os.path.getsize(self.path)} "
                                  f"(truncated after byte {offset})")
                    break
                except (McapError, struct.error, UnicodeDecodeError, ValueError, MemoryError) as exc:
                    self._problem(f"unreadable record after byte {offset}: {exc}")
                    break
                if isinstance(record, Chunk):
                    try:
                        inner = _chunk_records(record)
                    except Exception as exc:  # noqa: BLE001 - zstd, lz4, CRC: all mean a damaged chunk
                        self._problem(f"damaged chunk at byte {offset} ({type(exc).__name__}: {exc}); skipped")
                        inner = iter(())
                else:
                    inner = iter((record,))
                chunk_offset, offset = offset, f.tell()
                while True:
                    try:
                        rec = next(inner)
                    except StopIteration:
                        break
                    except Exception as exc:  # noqa: BLE001 - a record that does not parse: the chunk's rest is lost
                        self._problem(f"damaged record in the chunk at byte {chunk_offset} ({exc}); rest of it skipped")
                        break
                    if isinstance(rec, Schema):
                        self.schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        self.channels[rec.id] = rec
                    elif isinstance(rec, Message) and rec.channel_id not in self.channels:
                        lost_channels[rec.channel_id] = lost_channels.get(rec.channel_id, 0) + 1
                        continue
                    elif isinstance(rec, Metadata):
                        self.metadata[rec.name] = dict(rec.metadata)
                    if isinstance(rec, (Schema, Channel, Message, Metadata)):
                        yield rec
                if isinstance(record, (DataEnd, Footer)):
                    break
        for channel_id, count in lost_channels.items():
            self._problem(f"{count} message(s) on channel {channel_id}, whose channel record was lost, skipped")

    def messages(self, topics: set[str] | None = None) -> Iterator[LogMessage]:
        """Every message in recorded order (only `topics`, if given)."""
        for rec in self.records():
            if not isinstance(rec, Message):
                continue
            channel = self.channels[rec.channel_id]
            if topics is not None and channel.topic not in topics:
                continue
            schema = self.schemas.get(channel.schema_id)
            yield LogMessage(channel.topic, schema.name if schema else "", rec.log_time, rec.publish_time,
                             rec.sequence, rec.data)

    def topics(self) -> dict[str, str]:
        """Topic -> type name of every channel in the file (reads the file through)."""
        for _ in self.records():
            pass
        return {c.topic: (self.schemas[c.schema_id].name if c.schema_id in self.schemas else "")
                for c in self.channels.values()}

"""Reads touch4d MCAP logs in recorded order, and recovers what is readable from damaged ones.

Reading streams the file record by record with mcap's `StreamReader` (no index needed), so a file
cut short by a crash reads up to its last complete chunk. A complete file's summary section (its
channels, counts and chunk index) is read on its own when asked (`index`), so a replay can plan and
start without reading the log through, and `messages(start=...)` begins at the chunk that holds
that time. A damaged chunk (bad CRC, undecompressable, unparsable) never stops the reading: it is
skipped, counted (`skipped_chunks`, `skipped_messages`, from the message index that follows it)
and described in `problems`. Without `recover`, a file that is truncated or whose records cannot
be followed raises a `LogFileError` naming the file, the byte offset and what is wrong; with it,
the reading stops there and says so in `problems`.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from typing import Iterator

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, ChunkIndex, DataEnd, Footer, Message, MessageIndex, Metadata, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.summary import Summary

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
        self._skipped: dict[int, int | None] = {}  # byte offset of a damaged chunk -> messages lost (None: unknown)
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
        self._index: Summary | None | bool = False  # False: not looked for yet

    @property
    def skipped_chunks(self) -> int:
        """Damaged chunks skipped so far."""
        return len(self._skipped)

    @property
    def skipped_messages(self) -> int:
        """Messages lost in the damaged chunks skipped so far (those whose count the file records)."""
        return sum(n or 0 for n in self._skipped.values())

    def _problem(self, text: str) -> None:
        """Damage that stops the reading: an error, or with `recover` a problem listed."""
        if not self.recover:
            raise LogFileError(f"{self.path}: {text}; read what is readable with --recover or `touch4d log recover`")
        self._note(text)

    def _note(self, text: str) -> None:
        if text not in self.problems:
            self.problems.append(text)

    def _skip_chunk(self, offset: int, what: str, read: int, listed: int | None) -> None:
        """A damaged chunk, skipped: counted once per file position (a looped replay meets it again)."""
        if offset in self._skipped:
            return
        lost = None if listed is None else max(0, listed - read)
        self._skipped[offset] = lost
        self._note(f"damaged chunk at byte {offset} ({what}): skipped, "
                   + (f"{lost} message(s) lost" if lost is not None else "its messages lost (no message index)"))

    def index(self) -> Summary | None:
        """The summary section of a complete file (channels, schemas, statistics, chunk index), read from
        the end of the file without reading the log through, and its metadata (`metadata`); None when
        the file has none usable."""
        if self._index is False:
            self._index = None
            if self.complete:
                try:
                    with open(self.path, "rb") as f:
                        summary = SeekingReader(f, record_size_limit=1 << 31).get_summary()
                        if summary is not None and summary.statistics is not None and summary.chunk_indexes:
                            for entry in summary.metadata_indexes:  # the recording's report, a few records
                                f.seek(entry.offset)
                                stream = ReadDataStream(f)
                                if stream.read1() == Opcode.METADATA:
                                    stream.read8()
                                    record = Metadata.read(stream)
                                    self.metadata.setdefault(record.name, dict(record.metadata))
                            self._index = summary
                except Exception:  # noqa: BLE001 - an unreadable summary: the file is read through instead
                    self._index = None
        return self._index

    def index_times(self, chunk: ChunkIndex, channel_id: int) -> list[int]:
        """Receive times (ns) of the messages of `channel_id` in `chunk`, from its message index."""
        with open(self.path, "rb") as f:
            f.seek(chunk.message_index_offsets[channel_id])
            stream = ReadDataStream(f)
            if stream.read1() != Opcode.MESSAGE_INDEX:
                raise LogFileError(f"{self.path}: no message index at byte {chunk.message_index_offsets[channel_id]}")
            stream.read8()
            return [t for t, _ in MessageIndex.read(stream).records]

    def _start_offset(self, start: int | None) -> int:
        """Byte offset of the first chunk that may hold a message at or after `start` (ns); 0: the beginning."""
        index = self.index() if start is not None else None
        if index is None:
            return 0
        self.schemas.update(index.schemas)  # their records sit in the chunks skipped over
        self.channels.update(index.channels)
        later = [c.chunk_start_offset for c in index.chunk_indexes if c.message_end_time >= start]
        return min(later) if later else 0

    def records(self, start: int | None = None) -> Iterator[object]:
        """Schema, Channel, Message and Metadata records in file order, chunks opened and checked; with
        `start` (ns), from the chunk holding that receive time on when the file has an index."""
        lost_channels: dict[int, int] = {}
        damaged: list = []  # [offset, what, messages read from it, messages its index lists] of a chunk skipped
        with open(self.path, "rb") as f:
            begin = self._start_offset(start)
            if begin:
                f.seek(begin)
            reader = StreamReader(f, skip_magic=bool(begin), emit_chunks=True, record_size_limit=1 << 31)
            offset = begin or len(MAGIC)
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
                if isinstance(record, MessageIndex):  # the index of the chunk before: counts a damaged one
                    if damaged:
                        damaged[3] = (damaged[3] or 0) + len(record.records)
                    offset = f.tell()
                    continue
                if damaged:
                    self._skip_chunk(*damaged)
                    damaged = []
                read = 0
                if isinstance(record, Chunk):
                    try:
                        inner = _chunk_records(record)
                    except Exception as exc:  # noqa: BLE001 - zstd, lz4, CRC: all mean a damaged chunk
                        damaged = [offset, f"{type(exc).__name__}: {exc}", 0, None]
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
                        damaged = [chunk_offset, f"a record that does not parse: {exc}", 0, None]
                        break
                    if isinstance(rec, Schema):
                        self.schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        self.channels[rec.id] = rec
                    elif isinstance(rec, Message):
                        read += 1
                        if rec.channel_id not in self.channels:
                            lost_channels[rec.channel_id] = lost_channels.get(rec.channel_id, 0) + 1
                            continue
                    elif isinstance(rec, Metadata):
                        self.metadata[rec.name] = dict(rec.metadata)
                    if isinstance(rec, (Schema, Channel, Message, Metadata)):
                        yield rec
                if damaged and damaged[0] == chunk_offset:
                    damaged[2] = read  # delivered before the damage; the message index that follows has them all
                if isinstance(record, (DataEnd, Footer)):
                    break
            if damaged:
                self._skip_chunk(*damaged)
        for channel_id, count in lost_channels.items():
            self._note(f"{count} message(s) on channel {channel_id}, whose channel record was lost, skipped")

    def messages(self, topics: set[str] | None = None, start: int | None = None) -> Iterator[LogMessage]:
        """Every message in recorded order (only `topics`, if given; only those received at or after
        `start` ns, if given, the chunks before it not read when the file has an index)."""
        for rec in self.records(start):
            if not isinstance(rec, Message):
                continue
            if start is not None and rec.log_time < start:
                continue
            channel = self.channels[rec.channel_id]
            if topics is not None and channel.topic not in topics:
                continue
            schema = self.schemas.get(channel.schema_id)
            yield LogMessage(channel.topic, schema.name if schema else "", rec.log_time, rec.publish_time,
                             rec.sequence, rec.data)

    def topics(self) -> dict[str, str]:
        """Topic -> type name of every channel in the file (from its index, else by reading it through)."""
        index = self.index()
        if index is None:
            for _ in self.records():
                pass
        channels, schemas = (index.channels, index.schemas) if index is not None else (self.channels, self.schemas)
        return {c.topic: (schemas[c.schema_id].name if c.schema_id in schemas else "") for c in channels.values()}

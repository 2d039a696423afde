"""`touch4d log recover`: copy everything readable from a damaged or unfinished log into a complete one."""
from __future__ import annotations

from dataclasses import dataclass, field

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from .reader import LogReader
from .writer import PROFILE


@dataclass
class RecoverResult:
    messages: int = 0
    problems: list[str] = field(default_factory=list)
    skipped_chunks: int = 0
    skipped_messages: int = 0


def recover_log(src: str, dst: str) -> RecoverResult:
    """Write every readable schema, channel, message and metadata record of `src` into `dst`."""
    reader = LogReader(src, recover=True)
    result = RecoverResult()
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    with open(dst, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=PROFILE, library="touch4d log recover")
        for rec in reader.records():
            if isinstance(rec, Schema) and rec.id not in schema_ids:
                schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channel_ids:
                channel_ids[rec.id] = writer.register_channel(rec.topic, rec.message_encoding,
                                                              schema_ids.get(rec.schema_id, 0), dict(rec.metadata))
            elif isinstance(rec, Message):
                writer.add_message(channel_ids[rec.channel_id], log_time=rec.log_time,
                                   publish_time=rec.publish_time, sequence=rec.sequence, data=rec.data)
                result.messages += 1
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, dict(rec.metadata))
        writer.finish()
    result.problems = list(reader.problems)
    result.skipped_chunks, result.skipped_messages = reader.skipped_chunks, reader.skipped_messages
    return result

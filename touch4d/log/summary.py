"""`touch4d log info`: what a log holds (topics, types, counts, rates, duration, gaps, problems).

`summarize` reads the log through (sizes and seq gaps need every message); `indexed_summary` reads
only a complete file's index, for a replay that must start at once.
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone

from .gaps import SeqGaps
from .reader import LogReader


@dataclass
class TopicSummary:
    topic: str
    type: str
    count: int = 0
    bytes: int = 0
    first: int = 0          # ns, receive time of the first message
    last: int = 0
    lost: int = 0           # messages missing from the seq sequence(s)
    publishers: int = 0     # seq streams seen

    @property
    def rate(self) -> float:
        span = (self.last - self.first) / 1e9
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


@dataclass
class LogSummary:
    path: str
    size: int
    complete: bool
    topics: list[TopicSummary] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    skipped_chunks: int = 0     # damaged chunks skipped
    skipped_messages: int = 0   # messages lost in them

    @property
    def count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def start(self) -> int:
        return min((t.first for t in self.topics if t.count), default=0)

    @property
    def end(self) -> int:
        return max((t.last for t in self.topics if t.count), default=0)

    @property
    def duration(self) -> float:
        return (self.end - self.start) / 1e9

    def to_dict(self) -> dict:
        out = asdict(self)
        out.update(count=self.count, start=self.start / 1e9, end=self.end / 1e9, duration=self.duration)
        for t, d in zip(self.topics, out["topics"]):
            d["rate"] = t.rate
            d["first"], d["last"] = t.first / 1e9, t.last / 1e9
        return out


def summarize(path: str, *, recover: bool = False) -> LogSummary:
    """Read the whole log and summarize it; damaged files need `recover` (else LogFileError)."""
    reader = LogReader(path, recover=recover)
    topics: dict[str, TopicSummary] = {}
    gaps = SeqGaps()
    for msg in reader.messages():
        t = topics.get(msg.topic)
        if t is None:
            t = topics[msg.topic] = TopicSummary(msg.topic, msg.type, first=msg.log_time)
        t.count += 1
        t.bytes += len(msg.data)
        t.last = msg.log_time
        if msg.type:  # payloads that were not messages carry no seq
            gaps.add(msg.topic, msg.sequence)
    for topic, t in topics.items():
        t.lost = gaps.lost.get(topic, 0)
        t.publishers = gaps.streams(topic)
    return LogSummary(path, os.path.getsize(path), reader.complete, sorted(topics.values(), key=lambda t: t.topic),
                      reader.metadata, reader.problems, reader.skipped_chunks, reader.skipped_messages)


def indexed_summary(reader: LogReader) -> LogSummary | None:
    """Topics, types, counts and first/last receive times from a complete file's index alone, without
    reading its messages (sizes and seq gaps are not in it: 0); None when the file has no usable index."""
    index = reader.index()
    if index is None:
        return None
    counts = index.statistics.channel_message_counts
    topics: dict[str, TopicSummary] = {}
    try:
        for channel in index.channels.values():
            count = counts.get(channel.id, 0)
            chunks = [c for c in index.chunk_indexes if channel.id in c.message_index_offsets]
            if not count:
                continue
            if not chunks:
                return None
            first = min(reader.index_times(min(chunks, key=lambda c: c.message_start_time), channel.id))
            last = max(reader.index_times(max(chunks, key=lambda c: c.message_end_time), channel.id))
            schema = index.schemas.get(channel.schema_id)
            t = topics.setdefault(channel.topic, TopicSummary(channel.topic, schema.name if schema else "",
                                                              first=first, last=last))
            t.count += count
            t.first, t.last = min(t.first, first), max(t.last, last)
    except Exception:  # noqa: BLE001 - a damaged message index: the caller reads the file through instead
        return None
    return LogSummary(reader.path, os.path.getsize(reader.path), True, sorted(topics.values(), key=lambda t: t.topic))


def _when(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat(timespec="milliseconds")


def format_summary(s: LogSummary) -> str:
    """The summary as a text table for a terminal."""
    lines = [
        f"file:      {s.path} ({s.size / 1e6:.2f} MB{'' if s.complete else ', incomplete'})",
        f"messages:  {s.count}",
        f"duration:  {s.duration:.3f} s",
    ]
    if s.count:
        lines.append(f"start:     {_when(s.start)}")
        lines.append(f"end:       {_when(s.end)}")
    width = max([len(t.topic) for t in s.topics] + [5])
    twidth = max([len(t.type or "-") for t in s.topics] + [4])
    lines.append("")
    lines.append(f"{'topic':<{width}}  {'type':<{twidth}}  {'count':>8}  {'rate Hz':>9}  {'lost':>6}  {'size':>10}")
    for t in s.topics:
        lines.append(f"{t.topic:<{width}}  {t.type or '-':<{twidth}}  {t.count:>8}  {t.rate:>9.2f}  "
                     f"{t.lost:>6}  {t.bytes / 1e3:>8.1f}kB")
    recording = s.metadata.get("touch4d.recording")
    if recording:
        lines.append("")
        lines.append("recorder: " + ", ".join(f"{k}={v}" for k, v in sorted(recording.items())))
    for problem in s.problems:
        lines.append(f"problem: {problem}")
    return "\n".join(lines)

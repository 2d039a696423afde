"""`touch4d log info`: what a log holds (topics, types, counts, rates, duration, gaps, problems)."""
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
                      reader.metadata, reader.problems)


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

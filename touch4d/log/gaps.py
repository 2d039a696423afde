"""Per-topic sequence-gap accounting: a gap in `seq` means messages were dropped before the recorder.

Messages carry no publisher id, so a topic with several publishers (node/heartbeat) holds several
interleaved `seq` streams. Each seq continues the stream that expects it; a seq below every
stream's next one starts a new stream (another publisher, or a restarted one); a seq ahead of a
stream continues the nearest stream below it, and the skipped numbers are counted as lost.
A repeated seq (a publisher that does not count) is not a new stream, and at most MAX_STREAMS
streams are tracked per topic (the least recently continued is forgotten), so cost stays bounded.
"""
from __future__ import annotations

from collections import defaultdict

MAX_STREAMS = 32


class SeqGaps:
    """Counts messages missing from each topic's `seq` sequence(s)."""

    def __init__(self) -> None:
        self._next: dict[str, list[int]] = defaultdict(list)  # topic -> next seq expected, per stream
        self.lost: dict[str, int] = defaultdict(int)          # topic -> messages missing
        self.gaps: dict[str, int] = defaultdict(int)          # topic -> number of holes

    def add(self, topic: str, seq: int) -> int:
        """Account one received `seq` on `topic`; returns how many messages it shows were lost."""
        streams = self._next[topic]  # least recently continued first
        if streams and streams[-1] == seq:  # the usual case: the stream continued last goes on
            streams[-1] = seq + 1
            return 0
        if seq in streams:
            streams.remove(seq)
            streams.append(seq + 1)
            return 0
        if seq + 1 in streams:  # the same seq again: not a new publisher
            return 0
        below = [n for n in streams if n < seq]
        if not below:
            streams.append(seq + 1)
            if len(streams) > MAX_STREAMS:
                del streams[0]
            return 0
        nearest = max(below)
        streams.remove(nearest)
        streams.append(seq + 1)
        missing = seq - nearest
        self.lost[topic] += missing
        self.gaps[topic] += 1
        return missing

    def streams(self, topic: str) -> int:
        """How many publishers' sequences were seen on `topic`."""
        return len(self._next.get(topic, ()))

    def total_lost(self) -> int:
        return sum(self.lost.values())

    def report(self) -> dict[str, int]:
        """Topic -> messages lost, for the topics that lost any."""
        return {topic: n for topic, n in sorted(self.lost.items()) if n}

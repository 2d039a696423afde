"""Who publishes and who waits for what on a running bus, from the nodes' heartbeats
(`Heartbeat.publishes`, `Heartbeat.subscribes`: a `?` suffix marks an optional input, `*` a raw
prefix). Used by the launcher and the monitor alike."""
from __future__ import annotations

from typing import Iterable

from touch4d.messages import Heartbeat


def inputs(beat: Heartbeat) -> set[str]:
    """The topics a node waits for: its subscriptions, less the optional ones and raw prefixes."""
    return {t for t in beat.subscribes if not t.endswith(("*", "?"))}


def shared_inputs(beats: Iterable[Heartbeat]) -> dict[str, list[str]]:
    """Topics some node waits for that two or more nodes publish: topic -> the publishers. Their
    streams interleave at every subscriber (a latest-only one takes whichever came last: two
    trackers on hand/pose make the hand jump between them)."""
    beats = list(beats)
    publishers: dict[str, set[str]] = {}
    for beat in beats:
        for topic in beat.publishes:
            publishers.setdefault(topic, set()).add(beat.node)
    wanted = set().union(*(inputs(b) for b in beats)) if beats else set()
    return {t: sorted(nodes) for t, nodes in sorted(publishers.items()) if len(nodes) > 1 and t in wanted}


def shared_text(topic: str, nodes: list[str]) -> str:
    return (f"{topic} has {len(nodes)} publishers ({', '.join(nodes)}): their messages interleave at every "
            "subscriber (a latest-only one takes whichever came last); drop one of them or remap its topic")

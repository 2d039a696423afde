"""Intra-process delivery: a message published by a node to a topic that a node of the same executor
(the same process: a launch file's `group`) subscribes to is handed over in-process, as ROS 2's
intra-process communication does, and still sent to the broker for everyone else (a recorder in
another process, monitors, the study server).

The in-process subscriber gets its own copy decoded from the payload just encoded (the publisher
checked it: no second check) on the executor's next turn, in publishing order; its SUB socket still
receives the broker's copy, which it recognises by its bytes (`LocalCopies.seen`) and skips. What
this saves per message: the broker round trip's latency and the decode's check; per topic with two
subscribers in the process (hand/pose: the page's node and the tactile model), one of the decodes.

A group's private topics (a launch file's `private`, touch4d.bus.launchfile) go no further: nothing
is sent to the broker, no copy comes back, and the process's raw subscribers (a recorder in the
group) get them in-process too. What that saves a served participant's haptic loop (four topics at
the page's rate): 15-20% of the CPU per page input, a third of the study server's (docs/bus.md).
"""
from __future__ import annotations

from collections import deque
from typing import Any, Callable

MAX_AWAITED = 1024   # broker copies awaited per topic; more are lost on the way (broker gone, queue full)


class Inbox:
    """A subscribing node's side of intra-process delivery, so this module needs no Node: `copies`
    (what it awaits from the broker), `call_soon` (its executor's), `deliver(topic, payload,
    msg_type)` (a typed message handed over) and `deliver_raw(topic, payload, subscription)` (a
    private topic's payload to a raw subscription), both called on the executor's next turn."""

    __slots__ = ("copies", "call_soon", "deliver", "deliver_raw")

    def __init__(self, call_soon: Callable[..., Any], deliver: Callable[[bytes, bytes, type | None], Any],
                 deliver_raw: Callable[[bytes, bytes, Any], Any]):
        self.copies = LocalCopies()
        self.call_soon, self.deliver, self.deliver_raw = call_soon, deliver, deliver_raw


class LocalRoutes:
    """Per executor: topic -> the inboxes of its nodes that subscribe (typed) to it; the raw
    subscriptions (prefix, inbox, subscription) of its nodes; the topics kept in the process
    (`private`)."""

    def __init__(self):
        self.by_topic: dict[bytes, list[Inbox]] = {}
        self.raw: list[tuple[bytes, Inbox, object]] = []
        self.private: frozenset[bytes] = frozenset()

    def add(self, topic: bytes, inbox: Inbox) -> None:
        inboxes = self.by_topic.setdefault(topic, [])
        if inbox not in inboxes:
            inboxes.append(inbox)

    def add_raw(self, prefix: bytes, inbox: Inbox, sub) -> None:
        self.raw.append((prefix, inbox, sub))

    def remove(self, inbox: Inbox) -> None:
        """A node shutting down: nothing is handed to its inbox any more."""
        for topic in [t for t, inboxes in self.by_topic.items() if inbox in inboxes]:
            self.by_topic[topic].remove(inbox)
            if not self.by_topic[topic]:
                del self.by_topic[topic]
        self.raw = [entry for entry in self.raw if entry[1] is not inbox]

    def hand_over(self, topic: bytes, payload: bytes, msg_type: type | None, publisher: str) -> None:
        """`payload`, a checked `msg_type` message just published on `topic` (None: a raw publisher's,
        checked on decoding): each subscribing node here decodes its own copy on the executor's next
        turn and skips the broker's when it comes (a private topic: none comes)."""
        broker = topic not in self.private
        for inbox in self.by_topic[topic]:
            inbox.copies.expect(topic, payload, publisher, broker)
            inbox.call_soon(inbox.deliver, topic, payload, msg_type)

    def keep(self, topic: bytes, payload: bytes, msg_type: type | None, publisher: str) -> None:
        """A private topic's message: to this process's subscribers, typed and raw, and no further."""
        if topic in self.by_topic:
            self.hand_over(topic, payload, msg_type, publisher)
        if self.raw:
            self.hand_over_raw(topic, payload)

    def hand_over_raw(self, topic: bytes, payload: bytes) -> None:
        """A private topic's payload to the raw subscribers here whose prefix it has (a recorder)."""
        for prefix, inbox, sub in self.raw:
            if topic.startswith(prefix):
                inbox.call_soon(inbox.deliver_raw, topic, payload, sub)


class LocalCopies:
    """Per subscribing node: the payloads handed over in-process whose broker copy has not come yet."""

    def __init__(self):
        self.awaited: dict[bytes, deque] = {}
        self.queued: dict[bytes, int] = {}   # handed over, not yet delivered (latest-only skips the older)

    def expect(self, topic: bytes, payload: bytes, publisher: str, broker: bool = True) -> None:
        self.queued[topic] = self.queued.get(topic, 0) + 1
        if not broker:
            return    # a private topic: no copy will come
        awaited = self.awaited.get(topic)
        if awaited is None:
            awaited = self.awaited[topic] = deque(maxlen=MAX_AWAITED)
        awaited.append((publisher, payload))

    def seen(self, topic: bytes, payload: bytes) -> bool:
        """Whether the broker's `payload` on `topic` was handed over in-process already (then it is
        forgotten). One publisher's copies come in its publishing order (one socket), so its copies
        awaited before this one never came (lost: a full queue, a broker gone) and are passed over;
        another publisher's may come later still. A payload from another process is none of them."""
        awaited = self.awaited.get(topic)
        if not awaited:
            return False
        if awaited[0][1] == payload:
            awaited.popleft()
            return True
        for i, (publisher, candidate) in enumerate(awaited):
            if candidate == payload:
                break
        else:
            return False
        entries = list(awaited)
        awaited.clear()
        awaited.extend([e for e in entries[:i] if e[0] != publisher] + entries[i + 1:])
        return True

"""Namespaces, as in ROS: a node in namespace `NS` publishes and subscribes `NS/TOPIC` for each
`TOPIC` its code names, so several stacks (participants) share one broker and never hear each other.

What stays global: `node/heartbeat` (every node beats on the one topic, named `NS/ROLE`, its topic
lists relative to its namespace; on the wire a namespaced node's beat carries its namespace, see
`heartbeat_key`) and the broadcast stop: a node that subscribes `safety/stop` hears
both its own `NS/safety/stop` and the global `safety/stop` (a stop published outside any namespace
stops every stack; one published inside stops that stack). A topic written `/TOPIC` is absolute.
"""
from __future__ import annotations

import re

GLOBAL_TOPICS = frozenset({"node/heartbeat"})        # never prefixed
_BEAT = b"node/heartbeat"
HEARTBEAT_IN = _BEAT + b"/"    # the wire topics of namespaced nodes' beats start so (heartbeat_key)
BROADCAST_TOPICS = frozenset({"safety/stop"})        # a namespaced subscriber hears the global one too
_SEGMENT = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*\Z")
EXPECTED = "a namespace: segments of letters, digits, _ . - (starting with a letter or digit) joined by '/'"


def check_namespace(ns: str | None) -> str:
    """`ns` as used ('' for none; surrounding slashes dropped), or ValueError saying what is expected."""
    ns = (ns or "").strip("/")
    if ns and not all(_SEGMENT.match(part) for part in ns.split("/")):
        raise ValueError(f"{EXPECTED}, got {ns!r}")
    if ns.startswith("_bus"):
        raise ValueError(f"{EXPECTED} not starting with '_bus', got {ns!r}")
    return ns


def resolve(topic: str, ns: str) -> str:
    """The bus topic of `topic` named by a node in namespace `ns`."""
    if topic.startswith("/"):
        return topic[1:]
    if not ns or topic in GLOBAL_TOPICS:
        return topic
    return f"{ns}/{topic}"


def relative(topic: str, ns: str) -> str | None:
    """A bus topic as a node in `ns` names it: without the prefix; None when it lies outside `ns`
    (a global topic is itself)."""
    if not ns or topic in GLOBAL_TOPICS or topic in BROADCAST_TOPICS:
        return topic
    prefix = ns + "/"
    return topic[len(prefix):] if topic.startswith(prefix) else None


def heartbeat_key(ns: str) -> bytes:
    """The wire topic of the beats of a node in `ns`: `node/heartbeat`, and in a namespace
    `node/heartbeat/NS/`. ZeroMQ matches a subscription by prefix, so whoever listens to
    node/heartbeat still hears every stack's beats (as `node/heartbeat`: `bus_key`), while a stack's
    own recorder and launcher listen to their namespace's alone: with N stacks on one broker each
    of them was woken by every stack's beats, N² wake-ups a second in all."""
    return b"%s/%s/" % (_BEAT, ns.encode()) if ns else _BEAT


def bus_key(key: bytes) -> bytes:
    """A wire topic as the bus names it: a namespaced heartbeat's is `node/heartbeat`."""
    return _BEAT if key.startswith(HEARTBEAT_IN) else key


def node_name(role: str, ns: str) -> str:
    """A node's name in heartbeats: `NS/ROLE` (the role alone outside namespaces)."""
    return f"{ns}/{role}" if ns else role


def in_namespace(name: str, ns: str) -> bool:
    """Whether a heartbeat's node name belongs to namespace `ns` ('' : outside every namespace)."""
    return name.rpartition("/")[0] == ns


def namespace_of(node: str) -> str:
    """The namespace of a heartbeat's node name ('' outside every namespace)."""
    return node.rpartition("/")[0]


def rebase(topic: str, ns: str, to: str) -> str | None:
    """A topic named by a node in `ns` (a heartbeat's list) as a node in `to` names it; None when
    that node cannot hear it."""
    return relative(resolve(topic, ns), to)

"""What is on the bus: topics and their rates, messages, live nodes (`touch4d topic|node ...`).

Each function joins the bus as a short-lived node without a heartbeat, prints to `out` and stops
after `duration` seconds, `count` messages or Ctrl+C.
"""
from __future__ import annotations

import sys
import time
from collections import defaultdict

import numpy as np
import yaml
import zmq

from touch4d import schema
from touch4d.bus import names, transport
from touch4d.bus.config import BusConfig, BusUnreachable, resolve_bus_config
from touch4d.bus.node import HEARTBEAT_TOPIC, Node
from touch4d.bus.params import suggest
from touch4d.errors import ConfigError
from touch4d.messages import TOPIC_TYPES, TYPES, Heartbeat, Message, MessageError, decode

_ARRAY_SHOWN = 24
CONNECT_TIMEOUT = 3.0  # seconds a tool waits for the broker before saying none answers
SILENCE_NOTICE = 1.5   # seconds of silence on a topic after which echo/hz say whether anyone publishes it


def _tool(bus: BusConfig | None, what: str, namespace: str = "") -> Node:
    """A short-lived node on the bus; BusUnreachable (the one error, no warning before it) when no
    broker answers within CONNECT_TIMEOUT."""
    bus = bus if bus is not None else resolve_bus_config()
    context = zmq.Context.instance()
    probe = transport.publisher(context, bus)
    try:
        if not transport.await_broker(probe, CONNECT_TIMEOUT):
            raise BusUnreachable(f"no broker at {bus.pub_endpoint} (bus config: {bus.source}); "
                                 "is `touch4d launch` running?")
    finally:
        probe.close(linger=0)
    return Node(f"_{what}", bus=bus, heartbeat=False, kind="introspect", connect_timeout=CONNECT_TIMEOUT,
                namespace=namespace)


def _published(node: Node, hb: Heartbeat) -> list[str]:
    """What a heartbeat's node publishes, as `node` names the topics (those it can hear)."""
    ns = names.namespace_of(hb.node)
    return [t for t in (names.rebase(topic, ns, node.namespace) for topic in hb.publishes) if t is not None]


def _spin(node: Node, duration: float | None, done=lambda: False, each=lambda: None) -> None:
    end = None if duration is None else time.monotonic() + duration
    try:
        while not done() and (end is None or time.monotonic() < end):
            node.spin_once(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))
            each()
    except KeyboardInterrupt:
        pass


class PublisherWatch:
    """Which topics are live (messages seen, or published by a node, from heartbeats), so a tool
    waiting on a silent topic can say, after SILENCE_NOTICE s, that nobody publishes it."""

    def __init__(self, node: Node, topic: str, err=None):
        self.topic = topic
        self.err = err or sys.stderr
        self.seen: set[str] = set()
        self.declared: dict[str, set[str]] = defaultdict(set)  # topic -> nodes that publish it
        self.start = time.monotonic()
        self.done = False
        self.node = node
        node.create_raw_subscription("", self._on_any)

    def _on_any(self, topic: str, payload: bytes) -> None:
        self.seen.add(topic)
        if topic == HEARTBEAT_TOPIC:
            try:
                hb = decode(payload, Heartbeat)
            except MessageError:
                return
            for name in _published(self.node, hb):
                self.declared[name].add(hb.node)

    def check(self) -> None:
        """Say once, after SILENCE_NOTICE s without a message on the topic, who (if anyone) publishes it."""
        if self.done or self.topic in self.seen or time.monotonic() - self.start < SILENCE_NOTICE:
            return
        self.done = True
        if self.declared.get(self.topic):
            print(f"# no message on {self.topic} yet; published by {', '.join(sorted(self.declared[self.topic]))}; "
                  "waiting (Ctrl+C to stop)", file=self.err, flush=True)
            return
        live = sorted((self.seen | set(self.declared)) - {self.topic})
        print(f"# nobody publishes {self.topic}{suggest(self.topic, live)}; live topics: "
              f"{', '.join(live) or 'none'}; waiting (Ctrl+C to stop)", file=self.err, flush=True)


def plain(value, full: bool = False):
    """A message field as plain YAML-able data (long arrays shortened unless `full`)."""
    if isinstance(value, np.ndarray):
        if value.size > _ARRAY_SHOWN and not full:
            return f"array {value.dtype} shape {value.shape}: {np.array2string(value.ravel()[:8], precision=4)[:-1]} ...]"
        return value.tolist()
    if isinstance(value, dict):
        return {k: plain(v, full) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v, full) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def message_type(topic: str, type_name: str | None = None) -> type[Message] | None:
    if type_name:
        if type_name not in TYPES:
            raise ConfigError("command line", "--type", f"a message type (one of {', '.join(sorted(TYPES))})", got=type_name)
        return TYPES[type_name]
    return TOPIC_TYPES.get(topic)


def topic_list(bus: BusConfig | None = None, duration: float = 2.0, out=None, namespace: str = "") -> dict[str, dict]:
    """Listen to everything for `duration` s; print each topic with its type, rate and publishers
    (in `namespace`: its topics, named relative to it, and the global ones)."""
    out = out or sys.stdout
    seen: dict[str, dict] = defaultdict(lambda: {"count": 0, "type": "?", "publishers": set()})
    node = _tool(bus, "topic_list", namespace)

    def on_any(topic: str, payload: bytes) -> None:
        entry = seen[topic]
        entry["count"] += 1
        if entry["type"] == "?" or topic == HEARTBEAT_TOPIC:
            try:
                msg = decode(payload)
            except MessageError:
                return
            entry["type"] = msg.TYPE
            if isinstance(msg, Heartbeat):
                for name in _published(node, msg):
                    seen[name]["publishers"].add(msg.node)
                entry["publishers"].add(msg.node)

    node.create_raw_subscription("", on_any)
    start = time.monotonic()
    try:
        _spin(node, duration)
    finally:
        node.shutdown()
    elapsed = max(time.monotonic() - start, 1e-6)
    rows = {t: {"type": TOPIC_TYPES[t].TYPE if e["type"] == "?" and t in TOPIC_TYPES else e["type"],
                "rate": e["count"] / elapsed, "count": e["count"], "publishers": sorted(e["publishers"])}
            for t, e in sorted(seen.items())}
    width = max([len(t) for t in rows] + [5])
    print(f"{'topic'.ljust(width)}  {'type':<16} {'rate Hz':>8}  publishers", file=out)
    for topic, row in rows.items():
        print(f"{topic.ljust(width)}  {row['type']:<16} {row['rate']:8.1f}  {', '.join(row['publishers'])}", file=out)
    return rows


def topic_echo(topic: str, bus: BusConfig | None = None, count: int | None = None, duration: float | None = None,
               type_name: str | None = None, full: bool = False, out=None, err=None, namespace: str = "") -> int:
    """Print each message on `topic` as YAML; returns how many were printed. When nothing comes,
    says on `err` (stderr) whether anyone publishes the topic, and which topics are live."""
    out = out or sys.stdout
    cls = message_type(topic, type_name)
    printed = 0

    def show(msg: Message) -> None:
        nonlocal printed
        if count is not None and printed >= count:
            return
        printed += 1
        out.write("---\n" + yaml.safe_dump(plain(msg.to_dict(), full), sort_keys=False, width=120))
        out.flush()

    def on_raw(name: str, payload: bytes) -> None:
        if name != topic:
            return
        try:
            show(decode(payload))
        except MessageError as exc:
            print(f"# malformed message on {topic}: {exc}", file=out)

    node = _tool(bus, "topic_echo", namespace)
    try:
        watch = PublisherWatch(node, topic, err)
        if cls is None:
            node.create_raw_subscription(topic, on_raw)
        else:
            node.create_subscription(topic, cls, show)
        _spin(node, duration, lambda: count is not None and printed >= count, watch.check)
    finally:
        malformed = sum(s["malformed"] for s in node.stats.values())
        node.shutdown()
    if malformed:
        print(f"# {malformed} malformed message(s) on {topic} were dropped", file=out)
    return printed


def topic_hz(topic: str, bus: BusConfig | None = None, duration: float | None = None, window: float = 1.0,
             out=None, err=None, namespace: str = "") -> float | None:
    """Print the rate of `topic` every `window` s; returns the overall mean rate (None if silent)."""
    out = out or sys.stdout
    arrivals: list[float] = []
    node = _tool(bus, "topic_hz", namespace)
    watch = PublisherWatch(node, topic, err)
    node.create_raw_subscription(topic, lambda name, _: arrivals.append(time.monotonic()) if name == topic else None)
    shown = 0

    def report() -> None:
        nonlocal shown
        recent = arrivals[shown:]
        shown = len(arrivals)
        if len(arrivals) < 2:
            print(f"{topic}: no messages yet" if not arrivals else f"{topic}: 1 message", file=out)
            return
        periods = np.diff(arrivals[-1000:])
        print(f"{topic}: {1.0 / float(np.mean(periods)):.2f} Hz  min {periods.min() * 1e3:.2f} ms  "
              f"max {periods.max() * 1e3:.2f} ms  std {float(np.std(periods)) * 1e3:.2f} ms  "
              f"(+{len(recent)} in the last window, {len(arrivals)} in all)", file=out)
        out.flush()

    node.create_timer(window, report)
    try:
        _spin(node, duration, each=watch.check)
    finally:
        node.shutdown()
    if len(arrivals) < 2:
        return None
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])


def build_message(topic: str, text: str, type_name: str | None = None) -> Message:
    """A message for `topic` from YAML text of its fields (the header is filled on publish)."""
    cls = message_type(topic, type_name)
    if cls is None:
        raise ConfigError("command line", "--type", f"the message type, since {topic!r} is not a standard topic")
    try:
        fields = schema.parse_yaml(text) if text.strip() else {}
    except ConfigError as exc:   # the YAML problem whole, on one line
        raise ConfigError("command line", "YAML", f"a YAML mapping of {cls.TYPE} fields", got=text,
                          detail=exc.detail) from None
    if not isinstance(fields, dict):
        raise ConfigError("command line", "YAML", f"a mapping of {cls.TYPE} fields", got=fields)
    try:
        msg = cls(**fields)
        msg.validate()
    except TypeError as exc:
        raise ConfigError("command line", "YAML", f"fields of {cls.TYPE} ({', '.join(cls.field_docs())})",
                          got=str(exc)) from None
    except MessageError as exc:
        raise ConfigError("command line", "YAML", f"a valid {cls.TYPE}", got=str(exc)) from None
    return msg


def topic_pub(topic: str, text: str, bus: BusConfig | None = None, type_name: str | None = None,
              rate: float | None = None, count: int | None = None, out=None, namespace: str = "") -> int:
    """Publish a message built from YAML once, or at `rate` Hz (`count` times, or until Ctrl+C)."""
    out = out or sys.stdout
    template = build_message(topic, text, type_name)
    node = _tool(bus, "topic_pub", namespace)
    pub = node.create_publisher(topic, type(template))
    sent = 0
    total = count if count is not None else (None if rate else 1)

    def send() -> None:
        nonlocal sent
        if total is not None and sent >= total:
            return
        msg = type(template).from_dict(template.to_dict())
        msg.stamp = msg.source_stamp = 0.0
        pub.publish(msg)
        sent += 1

    try:
        send()
        if rate:
            node.create_timer(1.0 / rate, send)
            _spin(node, None, lambda: total is not None and sent >= total)
    finally:
        node.shutdown()
    print(f"published {sent} {type(template).TYPE} message(s) on {node.resolve_topic(topic)}", file=out)
    return sent


def node_list(bus: BusConfig | None = None, duration: float = 2.5, out=None,
              namespace: str | None = None) -> dict[str, Heartbeat]:
    """Collect heartbeats for `duration` s; print each live node (only those of `namespace`, if given;
    a node in a namespace is named NS/ROLE)."""
    out = out or sys.stdout
    beats: dict[str, Heartbeat] = {}
    node = _tool(bus, "node_list")
    keep = (lambda name: True) if namespace is None else (lambda name: names.in_namespace(name, namespace.strip("/")))
    node.create_subscription(HEARTBEAT_TOPIC, Heartbeat,
                             lambda hb: beats.__setitem__(hb.node, hb) if keep(hb.node) else None)
    try:
        _spin(node, duration)
    finally:
        node.shutdown()
    now = time.time()
    print(f"{'node':<16} {'kind':<20} {'pid':>7} {'age s':>6}  recv/drop/bad/gaps  publishes | subscribes", file=out)
    for name, hb in sorted(beats.items()):
        s = hb.stats
        counters = "/".join(str(int(s.get(k, 0))) for k in ("received", "dropped", "malformed", "gaps"))
        print(f"{name:<16} {hb.kind:<20} {hb.pid:>7} {now - hb.stamp:6.1f}  {counters:<18}  "
              f"{', '.join(hb.publishes) or '-'} | {', '.join(hb.subscribes) or '-'}", file=out)
    if not beats:
        print(f"(no heartbeat within {duration:g} s)", file=out)
    return beats



def request(topic: str, message: Message, reply_topic: str, reply_type: type[Message], done,
            bus: BusConfig | None = None, timeout: float = 3.0) -> list[Message]:
    """Publish `message` on `topic` once and collect what arrives on `reply_topic` (subscribed first, so
    nothing is missed) until `done(replies)` or `timeout` s: what a command that waits for its effect needs."""
    node = _tool(bus, "request")
    replies: list[Message] = []
    try:
        node.create_subscription(reply_topic, reply_type, replies.append)
        pub = node.create_publisher(topic, type(message))
        _spin(node, 0.2)                   # (in force once made); what came before the request is dropped
        replies.clear()
        pub.publish(message)
        _spin(node, timeout, lambda: done(replies))
    finally:
        node.shutdown()
    return replies

"""The node runtime: publishers, subscriptions, timers, parameters, counters, heartbeats, clean shutdown.

A node class declares its parameters (`PARAMS`, see touch4d.bus.params) and builds itself in
`setup()`. Construction and activation are apart: the constructor checks the parameters and makes
the sockets; `start()` (which the constructor calls unless `start=False`) runs `setup`, then
connects to the broker, confirms every subscription `setup` made with one slow-joiner sync and
sends what `setup` published. Whatever happens, `shutdown` closes everything again (also when
`setup` raises).

One thread runs everything (callbacks, timers, `on_shutdown`): the node's executor
(touch4d.bus.executor), its own or one shared by the nodes of one process (a launch file's `group`,
touch4d.bus.process; a container, touch4d.bus.container), so
node code needs no locks. Each node has one publishing socket and one
SUB socket, made and synchronised by touch4d.bus.transport; a subscription made after `start`
returns only once the broker applies it (the transport's `sync`). A message for a node of the same
executor is handed over in-process too (touch4d.bus.local).
"""
from __future__ import annotations

import logging
import os
import time
import uuid
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import zmq

from touch4d.bus import names, transport
from touch4d.bus.config import BusConfig, resolve_bus_config
from touch4d.bus.executor import Executor, Timer
from touch4d.bus.local import Inbox
from touch4d.bus.params import Param, check_params
from touch4d.bus.transport import INTERNAL_PREFIX
from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError
from touch4d.messages import Heartbeat, Message, MessageError, decoder

HEARTBEAT_TOPIC = "node/heartbeat"
HEARTBEAT_PERIOD = 1.0
_HEARTBEAT_KEY = HEARTBEAT_TOPIC.encode()
_MAX_BATCH = 4096
_MAX_RAW_NAMES = 4096   # topic names kept decoded for raw subscribers (a flood of new topics is not kept)
_SNDMORE, _NOBLOCK, _RCVMORE = zmq.SNDMORE, zmq.NOBLOCK, zmq.RCVMORE
_MAX_LOGGED_CAUSES = 200


class Publisher:
    """Publishes one message type on one topic; `publish` fills the header."""

    def __init__(self, node: "Node", topic: str, msg_type: type[Message], wire_key: bytes | None = None):
        self.node = node
        self.topic = topic
        self.msg_type = msg_type
        self._topic = topic.encode() if wire_key is None else wire_key   # on the wire (the heartbeat's differs)

    def publish(self, msg: Message) -> None:
        """Check, stamp (if 0), number and send `msg` (Message.publish_payload); raises MessageError,
        and sends nothing, if a field is invalid."""
        if msg.__class__ is not self.msg_type and not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.topic}: expected a {self.msg_type.TYPE}, got {type(msg).__name__}")
        node, topic = self.node, self._topic
        seq = node._seq.get(topic, 0)
        try:
            payload = msg.publish_payload(seq)
        except MessageError as exc:
            raise MessageError(f"publishing on {self.topic}: {exc}") from None
        node._seq[topic] = seq + 1
        node._route(topic, payload, self.msg_type)


class RawPublisher:
    """Publishes already-encoded payloads on one topic, as they are (e.g. a log being replayed)."""

    def __init__(self, node: "Node", topic: str):
        self.node = node
        self.topic = topic
        self._topic = topic.encode()

    def publish(self, payload: bytes) -> None:
        self.node._send_raw(self._topic, payload)


@dataclass
class Subscription:
    """A callback on one topic (typed) or on every topic under a prefix (raw)."""

    topic: str
    msg_type: type[Message] | None
    callback: Callable
    latest_only: bool = False
    raw: bool = False
    active: bool = True
    optional: bool = False  # the node works without a publisher (commands, stops): never reported missing
    decode: Callable[[bytes], Message] | None = field(default=None, repr=False)  # payload -> msg_type message

    def __post_init__(self):
        if self.msg_type is not None and self.decode is None:
            self.decode = decoder(self.msg_type)


class _Held:
    """Where a node's messages go before it is connected: kept whole (up to `limit`, like the
    socket's queue), sent once `start` has connected."""

    def __init__(self, limit: int):
        self.limit = limit
        self.messages: list[list[bytes]] = []
        self._partial: list[bytes] = []

    def send(self, frame: bytes, flags: int = 0) -> None:
        self._partial.append(frame)
        if not flags & _SNDMORE:
            if len(self.messages) < self.limit:
                self.messages.append(self._partial)
            self._partial = []


@dataclass
class _TopicState:
    last_seq: int | None = None
    stale_since_last: int = 0
    stats: dict = field(default_factory=lambda: {"received": 0, "dropped": 0, "malformed": 0, "gaps": 0})


class Node:
    """Base class of every node; see docs/contracts.md for the API.

    Subclasses set `PARAMS` (name -> Param) and `default_name`, and override `setup()` (subscribe,
    publish, open devices) and `on_shutdown()`; they need no `__init__` of their own.
    """

    PARAMS: ClassVar[dict[str, Param]] = {}
    default_name: ClassVar[str] = "node"

    def __init__(
        self,
        name: str | None = None,
        params: dict | None = None,
        bus: BusConfig | None = None,
        *,
        role: str | None = None,
        kind: str | None = None,
        params_source: str | None = None,
        heartbeat: bool = True,
        connect_timeout: float = 5.0,
        context: zmq.Context | None = None,
        start: bool = True,
        namespace: str | None = None,
        executor: Executor | None = None,
    ):
        """Check the parameters and make the sockets; then `start()` unless `start=False` (set
        attributes a test needs, e.g. a device to use, between the two). `namespace`: every topic
        this node names lies under `NAMESPACE/` (touch4d.bus.names; '' or None: none). `executor`:
        one shared with other nodes of this process (their thread is this node's; whoever made it
        spins and closes it); None: the node's own."""
        self.name = role or name or self.default_name
        try:
            self.namespace = names.check_namespace(namespace)
        except ValueError as exc:
            raise ConfigError(f"node '{self.name}'", "namespace", str(exc).split(", got")[0], got=namespace) from None
        self.kind = kind or type(self).__module__.rsplit(".", 1)[-1]
        self._params_source = params_source
        given = dict(params or {})
        self.given: frozenset[str] = frozenset(given)  # the parameters set explicitly (not defaults)
        self.params: dict[str, Any] = check_params(self.PARAMS, given, self.param_error, f"node {self.kind}")
        for pname, param in self.PARAMS.items():
            if param.path and self.params[pname]:  # "" or null: no file (the node's default, if any)
                # The launcher hands absolute paths (found against the file that set each one);
                # a node run alone finds a relative one here, the same way.
                source, key = self.param_where(pname)
                self.params[pname] = resolve_path(self.params[pname], source, key=key, what=param.path_what)
        self.bus = bus if bus is not None else resolve_bus_config()
        self.log = logging.getLogger(names.node_name(self.name, self.namespace))   # NS/ROLE: a container's groups apart
        self.group_stop: Callable[[], Any] | None = None   # set by a container: request_shutdown stops this group alone
        self.pid = os.getpid()
        self.connect_timeout = connect_timeout
        self.connected = False
        self._warned: dict = {}
        self._cleanups: list[Callable[[], Any]] = []
        self._set_up = False
        self._started = False
        self._heartbeat = heartbeat
        self._heartbeat_key = names.heartbeat_key(self.namespace)   # its beats on the wire (names)
        self._seq: dict[bytes, int] = {}  # next seq per published topic = messages published on it
        self._publishes: set[str] = set()
        self._subs: dict[bytes, list[Subscription]] = {}
        self._raw_subs: list[tuple[bytes, Subscription]] = []
        self._latest_only_topics: set[bytes] = set()
        self._zmq_topics: set[bytes] = set()
        self._topics: dict[bytes, _TopicState] = {}
        self._pending: list[list[bytes]] = []
        self._logged: set = set()
        self._counters: dict[str, int] = {"errors": 0}
        self._stat_sources: list[Callable[[], dict]] = []
        self._uid = uuid.uuid4().hex[:12]
        self._closed = False
        self._shutdown_called = False
        # One shared context per process: a node left to the garbage collector then only has its
        # sockets closed, never a context terminated from a finalizer (which can block forever).
        ctx = context or zmq.Context.instance()
        # The publisher lingers: on_shutdown's last messages (e.g. a stop) reach the broker.
        self._pub = transport.publisher(ctx, self.bus, connect=False, linger=1000)
        try:
            self._sub = transport.subscriber(ctx, self.bus, connect=False)
        except BaseException:
            self._pub.close(linger=0)
            raise
        self._owns_executor = executor is None
        self._raw_names: dict[bytes, str] = {}
        self._timers: list[Timer] = []   # on a shared executor: cancelled when this node shuts down
        self.executor = Executor(on_error=self._callback_failed) if executor is None else executor
        self._local_routes = self.executor.local
        # What this process's other nodes hand this one (touch4d.bus.local): delivered on its executor.
        self._inbox = Inbox(self.executor.call_soon, self._deliver_local, self._deliver_raw_local)
        self._local_copies = self._inbox.copies
        self.executor.add_reader(self._sub, self._on_messages)
        self.executor.add_reader(self._pub, self._on_broker)
        # What publishing writes to: a holder until start() has connected, then the socket. (An
        # attribute swapped, never deleted: the instance keeps its fast attribute lookups.)
        self._out: zmq.Socket | _Held = _Held(self.bus.hwm)
        if start:
            self.start()

    def start(self) -> "Node":
        """Activate the node: `setup()`, then connect to the broker (up to `connect_timeout`), confirm
        the subscriptions `setup` made, send what it published meanwhile and start the heartbeat.
        If `setup` raises, `shutdown` runs and the error propagates."""
        if self._started:
            return self
        self._started = True
        try:
            self.setup()
            self._set_up = True
            self._connect()
        except BaseException:
            self.shutdown()  # a node that cannot start leaves no socket, thread or device open
            raise
        return self

    def _connect(self) -> None:
        self._pub.connect(self.bus.pub_endpoint)
        self._sub.connect(self.bus.sub_endpoint)
        self.connected = transport.await_broker(self._pub, self.connect_timeout)
        if not self.connected:
            self.log.warning("broker not reached at %s within %.1f s; messages published before it "
                             "connects are lost", self.bus.pub_endpoint, self.connect_timeout)
        if self._zmq_topics:
            self._sync()   # one probe for every subscription setup made
        held, self._out = self._out, self._pub   # publishing goes straight to the socket from now on
        for frames in held.messages:
            self._pub.send_multipart(frames)
        if self._heartbeat:
            self._heartbeat_pub = Publisher(self, HEARTBEAT_TOPIC, Heartbeat, self._heartbeat_key)
            self._timers.append(self.executor.create_timer(HEARTBEAT_PERIOD, self._send_heartbeat,
                                                           first_due=time.monotonic(), on_error=self._callback_failed))

    # ---- what subclasses write -----------------------------------------------------------------

    def setup(self) -> None:
        """Override: build the node (publishers, subscriptions, timers, devices) from `self.params`.
        If it raises, `shutdown` runs the cleanups added so far and closes the sockets."""

    def on_shutdown(self) -> None:
        """Override to act on shutdown (e.g. send a stop); runs once, while sockets are still open,
        and only for a node whose `setup` finished."""

    # ---- parameters, errors, warnings, cleanups -------------------------------------------------

    def param_where(self, name: str) -> tuple[str, str]:
        """(source, key) of parameter `name` for a ConfigError: the launch file and
        `nodes.ROLE.params.NAME` when the parameters came from one, else the node and NAME."""
        if self._params_source:
            return self._params_source, f"nodes.{self.name}.params.{name}"
        return f"parameters of node '{self.name}'", name

    def param_error(self, name: str, expected: str, got: Any = ...) -> ConfigError:
        """A ConfigError for parameter `name` (see `param_where`); `got` defaults to the value given."""
        source, key = self.param_where(name)
        if got is ...:
            got = self.params.get(name) if hasattr(self, "params") else None
        return ConfigError(source, key, expected, got=got)

    def warn_once(self, cause, text: str, *, every: float | None = None) -> bool:
        """Log `text` as a warning the first time `cause` occurs (again after `every` seconds, if
        given); returns whether it was logged. Repeats in between are the caller's to count."""
        now = time.monotonic()
        last = self._warned.get(cause)
        if last is not None and (every is None or now - last < every):
            return False
        if last is None and len(self._warned) >= _MAX_LOGGED_CAUSES:
            return False
        self._warned[cause] = now
        self.log.warning("%s%s", text, "" if every is not None else " (further identical problems are only counted)")
        return True

    def add_cleanup(self, callback: Callable[[], Any]) -> None:
        """Call `callback()` at shutdown, after `on_shutdown`, also when `setup` failed later on;
        the last added runs first (like contextlib.ExitStack)."""
        self._cleanups.append(callback)

    # ---- topics and timers -------------------------------------------------------------------

    def resolve_topic(self, name: str) -> str:
        """The bus topic this node means by `name`: under its namespace, unless global (touch4d.bus.names)."""
        return names.resolve(name, self.namespace)

    def create_publisher(self, topic: str, msg_type: type[Message]) -> Publisher:
        _check_topic(topic)
        self._publishes.add(topic)
        return Publisher(self, self.resolve_topic(topic), msg_type)

    def create_raw_publisher(self, topic: str) -> RawPublisher:
        """A publisher of encoded payloads, sent unchanged (no header filled, no check)."""
        _check_topic(topic)
        self._publishes.add(topic)
        return RawPublisher(self, self.resolve_topic(topic))

    def create_subscription(
        self, topic: str, msg_type: type[Message], callback: Callable[[Message], Any], latest_only: bool = False,
        optional: bool = False,
    ) -> Subscription:
        """Call `callback(msg)` for each `msg_type` message on exactly `topic`. With `latest_only`, a
        backlog is skipped: only the newest queued message is handled (the rest count as dropped).
        `optional`: the node does not expect a publisher (commands, stops; see the monitor)."""
        _check_topic(topic)
        sub = Subscription(topic, msg_type, callback, latest_only, optional=optional)
        keys = [self.resolve_topic(topic)]
        if self.namespace and topic in names.BROADCAST_TOPICS:
            keys.append(topic)      # the broadcast stop: this namespace's and everyone's
        for key in (k.encode() for k in keys):
            self._subs.setdefault(key, []).append(sub)
            if latest_only:
                self._latest_only_topics.add(key)
            self._state(key)
            if key not in self._local_routes.private:   # a private topic never comes from the broker
                self._subscribe(key)
            self._local_routes.add(key, self._inbox)
        return sub

    def create_raw_subscription(self, prefix: str, callback: Callable[[str, bytes], Any]) -> Subscription:
        """Call `callback(topic, payload_bytes)` for every message whose topic starts with `prefix`
        ("" = all), undecoded (for recorders and introspection). In a namespace: the topics under it,
        named relative to it, and with "" the global ones too (heartbeats, the broadcast stop)."""
        sub = Subscription(prefix, None, callback, raw=True)
        keys = [self.resolve_topic(prefix) if prefix else (f"{self.namespace}/" if self.namespace else "")]
        if self.namespace and not prefix:
            keys += sorted(names.GLOBAL_TOPICS | names.BROADCAST_TOPICS)
        for key in (k.encode() for k in keys):
            self._raw_subs.append((key, sub))
            self._local_routes.add_raw(key, self._inbox, sub)   # the process's private topics
            self._subscribe(key)
        return sub

    def endpoints(self) -> dict[str, int]:
        """What this node serves outside the bus: a name -> the TCP port it bound (a port 0 asked for
        is known only here). A container says them in its ready file, for whoever placed the group."""
        return {}

    def tap_private(self, callback: Callable[[str, bytes], Any]) -> None:
        """Call `callback(topic, payload_bytes)` for every message of this process's private topics
        (a launch file's `private`; touch4d.bus.local), which no socket hears: how a recorder in the
        group logs them. Topics named as for a raw subscription; nothing when there are none. In a
        container, only those of this node's namespace (another group's are theirs)."""
        for key in sorted(self._local_routes.private):
            if self.namespace and names.relative(key.decode(), self.namespace) is None:
                continue
            self._local_routes.add_raw(key, self._inbox, Subscription(key.decode(), None, callback, raw=True))

    def create_timer(self, period: float, callback: Callable[[], Any]) -> Timer:
        """Call `callback()` every `period` seconds (fixed rate) on the node's thread."""
        timer = self.executor.create_timer(period, callback, on_error=self._callback_failed)
        self._timers.append(timer)
        return timer

    def call_later(self, delay: float, callback: Callable[[], Any]) -> Timer:
        """Call `callback()` once, `delay` s from now, on the node's thread; `cancel()` the timer to
        call nothing."""
        timer = self.executor.call_later(delay, callback, on_error=self._callback_failed)
        self._timers = [t for t in self._timers if not t.cancelled] + [timer]   # fired ones go
        return timer

    def set_timer_period(self, timer: Timer, period: float) -> None:
        """Change a timer's period; a shorter one takes effect at once (the next tick at most
        `period` from now), a longer one after the tick already due."""
        self.executor.set_timer_period(timer, period)

    # ---- counters ----------------------------------------------------------------------------

    def count(self, name: str, n: int = 1) -> None:
        """Add `n` to the node's counter `name` (created at 0 on first use; `count(name, 0)` declares
        it): sent in every heartbeat's stats and shown by `touch4d node list --live`."""
        self._counters[name] = self._counters.get(name, 0) + n

    def add_stats(self, source: Callable[[], dict]) -> None:
        """Add what `source()` returns (name -> number, e.g. a server's connected clients) to every
        heartbeat's stats; called on the node's thread once per heartbeat."""
        self._stat_sources.append(source)

    @property
    def stats(self) -> dict[str, dict]:
        """Per subscribed topic: received, dropped (stale, latest-only), malformed, gaps (from seq)."""
        return {key.decode(): state.stats for key, state in self._topics.items()}

    def stats_flat(self) -> dict[str, int]:
        """Totals plus "topic:counter" entries, the node's counters (`count`) and added stats
        (`add_stats`), as sent in the heartbeat."""
        out: dict[str, int] = {"received": 0, "dropped": 0, "malformed": 0, "gaps": 0}
        for topic, counters in self.stats.items():
            for name, value in counters.items():
                out[name] += value
                out[f"{topic}:{name}"] = value
        out["published"] = sum(n for t, n in self._seq.items() if t != self._heartbeat_key)
        out.update(self._counters)
        for source in self._stat_sources:
            out.update(source())
        return out

    # ---- spinning ----------------------------------------------------------------------------

    def spin_once(self, timeout: float = 0.1) -> int:
        """Wait up to `timeout` s for messages or a due timer and handle them; returns how many."""
        return self.executor.spin_once(timeout)

    def spin(self, duration: float | None = None) -> None:
        """Handle messages and timers until `request_shutdown()` (or for `duration` seconds)."""
        self.executor.spin(duration)

    def call_soon_threadsafe(self, callback: Callable, *args) -> None:
        """Run `callback(*args)` on the node's thread at its next spin; safe from any thread (e.g. a
        server's event loop handing over what a client sent). The poll wakes at once."""
        self.executor.call_soon_threadsafe(self._call, callback, args, getattr(callback, "__name__", "call_soon"))

    def request_shutdown(self) -> None:
        """Ask `spin` to return; safe from signal handlers and other threads. On a shared executor
        this stops every node of the process (which the launcher then restarts as a whole); in a
        container (touch4d.bus.container), every node of this node's group (which it loads again)."""
        if self.group_stop is not None:
            self.group_stop()
        else:
            self.executor.request_shutdown()

    @property
    def stopping(self) -> bool:
        return self.executor.stopping

    def shutdown(self) -> None:
        """Call `on_shutdown` once (if set up), then the cleanups, then close the sockets (flushing
        what was published)."""
        if self._closed:
            return
        if self._owns_executor:
            self.executor.request_shutdown()
        if not self._shutdown_called:
            self._shutdown_called = True
            steps = ([self.on_shutdown] if self._set_up else []) + self._cleanups[::-1]
            self._cleanups = []
            for step in steps:
                try:
                    step()
                except Exception:  # noqa: BLE001 - shutdown must finish and close the sockets
                    self.log.exception("%s failed during shutdown", getattr(step, "__qualname__", step))
        self._closed = True
        self._local_routes.remove(self._inbox)
        if self._owns_executor:
            self.executor.close()
        else:   # the other nodes of the process spin on: take this node's sockets and timers out
            self.executor.remove_reader(self._sub)
            self.executor.remove_reader(self._pub)
            for timer in self._timers:
                timer.cancel()
        self._sub.close(linger=0)
        self._pub.close()

    close = shutdown

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.shutdown()

    # ---- internals ---------------------------------------------------------------------------

    def _state(self, key: bytes) -> _TopicState:
        state = self._topics.get(key)
        if state is None:
            state = self._topics[key] = _TopicState()
        return state

    def _send_payload(self, topic: bytes, payload: bytes) -> None:
        """Send one message; the caller has counted it in `_seq`."""
        # Two sends, not send_multipart: its per-frame Python work costs more than the ZeroMQ calls.
        out = self._out
        out.send(topic, _SNDMORE)
        out.send(payload)

    def _send_raw(self, topic: bytes, payload: bytes) -> None:
        self._seq[topic] = self._seq.get(topic, 0) + 1
        self._route(topic, payload, None)

    def _route(self, topic: bytes, payload: bytes, msg_type: type[Message] | None) -> None:
        """Where a published message goes (touch4d.bus.local): a private topic's stays in this process;
        any other goes to the broker and, when `msg_type` says its publisher checked it, is handed
        over to this process's subscribers (a raw publisher's come back through the broker)."""
        local = self._local_routes
        if topic in local.private:
            local.keep(topic, payload, msg_type, self._uid)
            return
        self._send_payload(topic, payload)
        if msg_type is not None and topic in local.by_topic:
            local.hand_over(topic, payload, msg_type, self._uid)

    def _on_messages(self) -> int:
        return self._dispatch(self._drain())

    def _on_broker(self) -> int:
        """The broker's subscribe-all on the publisher: it (re)connected."""
        if transport.drain_broker_subscriptions(self._pub) and not self.connected:
            self.connected = True
            self.log.info("broker reached at %s", self.bus.pub_endpoint)
        return 0

    def _subscribe(self, key: bytes) -> None:
        if key in self._zmq_topics:
            return
        self._zmq_topics.add(key)
        self._sub.subscribe(key)
        if self._set_up:
            self._sync()   # made after start: in force once this returns

    def _sync(self) -> None:
        """Block until the broker has applied this node's subscriptions (touch4d.bus.transport.sync)."""
        if not self.connected:
            return  # nothing to confirm with; ZeroMQ subscribes again once the broker is there
        if not transport.sync(self._sub, self._pub, self.connect_timeout, owner=self._uid, other=self._pending.append):
            self.log.warning("subscription not confirmed by the broker at %s within %.1f s",
                             self.bus.sub_endpoint, self.connect_timeout)
        if self._pending:
            self.executor.call_soon(self._dispatch_pending)

    def _dispatch_pending(self) -> None:
        pending, self._pending = self._pending, []
        self._dispatch(pending)

    def _drain(self) -> list[list[bytes]]:
        """Everything queued on the SUB socket now (up to _MAX_BATCH messages)."""
        sock = self._sub
        recv, more = sock.recv, sock.getsockopt
        batch = []
        # recv until EAGAIN, frame by frame: recv_multipart and an EVENTS query per message cost
        # more than the receiving itself. The frames of one message arrive together (ZeroMQ).
        while len(batch) < _MAX_BATCH:
            try:
                frames = [recv(_NOBLOCK)]
            except zmq.Again:
                break
            while more(_RCVMORE):
                frames.append(recv())
            batch.append(frames)
        return batch

    def _dispatch(self, batch: list[list[bytes]]) -> int:
        last: dict[bytes, int] = {}
        latest_only = self._latest_only_topics
        if latest_only and len(batch) > 1:
            for i, frames in enumerate(batch):
                last[frames[0]] = i
        handled = 0
        i = -1
        while (i := i + 1) < len(batch):   # the batch may grow: see below
            frames = batch[i]
            topic = frames[0]
            if topic.startswith(INTERNAL_PREFIX):
                continue
            subs = self._subs.get(topic)
            if subs is None and (bus_key := names.bus_key(topic)) is not topic:
                topic, subs = bus_key, self._subs.get(bus_key)   # a namespaced node's beat
            if subs is not None and self._local_copies.awaited and len(frames) == 2 \
                    and self._local_copies.seen(topic, frames[1]):
                subs = None   # handed over in-process already (touch4d.bus.local)
            if subs is not None:
                if handled and topic in latest_only and last.get(topic, i) == i:
                    # Callbacks ran since the drain: a newer message may have come meanwhile, and
                    # then this one is stale before its callback even starts (a pose replaced while
                    # a scene was being built): read what came, in order, after this batch.
                    start = len(batch)
                    batch.extend(self._drain())
                    for j in range(start, len(batch)):
                        last[batch[j][0]] = j
                handled += self._deliver(topic, frames, subs, last.get(topic, i) == i)
            if self._raw_subs and len(frames) == 2:
                for prefix, sub in self._raw_subs:
                    if sub.active and topic.startswith(prefix):
                        self._call(sub.callback, (self._raw_name(topic), frames[1]), sub.topic)
                        handled += 1
        return handled

    def _raw_name(self, topic: bytes) -> str:
        """A topic as a raw subscriber of this node sees it: relative to its namespace (worked out once
        per topic: a recorder's tap asks for every message)."""
        name = self._raw_names.get(topic)
        if name is None:
            text = topic.decode(errors="replace")
            name = (names.relative(text, self.namespace) or text) if self.namespace else text
            if len(self._raw_names) < _MAX_RAW_NAMES:
                self._raw_names[topic] = name
        return name

    def _deliver_raw_local(self, topic: bytes, payload: bytes, sub: Subscription) -> None:
        """A private topic's message published in this process, to a raw subscriber (touch4d.bus.local)."""
        if sub.active and not self._closed:
            self._call(sub.callback, (self._raw_name(topic), payload), sub.topic)

    def _deliver_local(self, topic: bytes, payload: bytes, msg_type: type[Message]) -> None:
        """A message published in this process (touch4d.bus.local), in publishing order; with
        latest-only, skipped when a newer one is already handed over."""
        queued = self._local_copies.queued
        queued[topic] -= 1
        subs = self._subs.get(topic)
        if subs and not self._closed:
            self._deliver(topic, [topic, payload], subs, queued[topic] == 0, checked=msg_type)

    def _deliver(self, topic: bytes, frames: list[bytes], subs: list[Subscription], newest: bool,
                 checked: type[Message] | None = None) -> int:
        """`checked`: the payload is a message of that type its publisher checked (no second check)."""
        state = self._topics[topic]
        stats = state.stats
        stats["received"] += 1
        if newest and len(subs) == 1 and len(frames) == 2 and subs[0].active:
            # The usual case (one subscription, the newest message) without the general case's lists.
            sub = subs[0]
            try:
                msg = sub.msg_type._decode(frames[1]) if sub.msg_type is checked else sub.decode(frames[1])
            except MessageError as exc:
                stats["malformed"] += 1
                self._log_once(topic, str(exc))
                return 0
            self._track_seq(state, msg.seq)
            try:
                sub.callback(msg)
            except Exception as exc:  # noqa: BLE001 - a failing callback must not stop the node
                self._callback_failed(sub.topic, exc)
            return 1
        takers = [s for s in subs if s.active and (newest or not s.latest_only)]
        if not takers:
            stats["dropped"] += 1
            state.stale_since_last += 1
            return 0
        if len(frames) != 2:
            stats["malformed"] += 1
            self._log_once(topic, f"expected 2 frames [topic, payload], got {len(frames)}")
            return 0
        decoded: dict[type, Message] = {}
        handled = 0
        for sub in takers:
            msg = decoded.get(sub.msg_type)
            if msg is None:
                try:
                    msg = decoded[sub.msg_type] = (sub.msg_type._decode(frames[1]) if sub.msg_type is checked
                                                   else sub.decode(frames[1]))
                except MessageError as exc:
                    stats["malformed"] += 1
                    self._log_once(topic, str(exc))
                    return handled
                if handled == 0:
                    self._track_seq(state, msg.seq)
            self._call(sub.callback, (msg,), sub.topic)
            handled += 1
        return handled

    @staticmethod
    def _track_seq(state: _TopicState, seq: int) -> None:
        if state.last_seq is not None and seq > state.last_seq + 1:
            missing = seq - state.last_seq - 1 - state.stale_since_last
            if missing > 0:
                state.stats["gaps"] += missing
        # A seq that does not advance means another publisher or a restarted one: start over.
        state.last_seq = seq
        state.stale_since_last = 0

    def _call(self, callback: Callable, args: tuple, where) -> None:
        try:
            callback(*args)
        except Exception as exc:  # noqa: BLE001 - a failing callback must not stop the node
            self._callback_failed(where, exc)

    def _callback_failed(self, where, exc: Exception) -> None:
        """Count a callback's exception and log it (with its traceback: call it in the `except`)
        the first time its cause is seen."""
        if isinstance(where, Timer):
            where = f"timer {where.period:g} s"
        self._counters["errors"] += 1
        cause = (where, type(exc).__name__, str(exc)[:120])
        if cause not in self._logged and len(self._logged) < _MAX_LOGGED_CAUSES:
            self._logged.add(cause)
            self.log.exception("callback for %s failed (further identical failures are only counted)", where)

    def _log_once(self, topic: bytes, cause: str) -> None:
        key = (topic, cause)
        if key not in self._logged and len(self._logged) < _MAX_LOGGED_CAUSES:
            self._logged.add(key)
            self.log.warning("dropped a malformed message on %s: %s", topic.decode(errors="replace"), cause)

    def _send_heartbeat(self) -> None:
        self._heartbeat_pub.publish(Heartbeat(
            node=names.node_name(self.name, self.namespace),
            pid=self.pid,
            kind=self.kind,
            publishes=sorted(t for t in self._publishes if t != HEARTBEAT_TOPIC),
            # topics as the node names them (relative to its namespace, which its name carries)
            subscribes=sorted({self._relative(k) + ("?" if all(s.optional for s in subs) else "")
                               for k, subs in self._subs.items()}
                              | {self._relative(k) + "*" for k, _ in self._raw_subs}),
            stats=self.stats_flat(),
        ))


    def _relative(self, key: bytes) -> str:
        name = key.decode()
        if not self.namespace:
            return name
        if name == f"{self.namespace}/":
            return ""
        return names.relative(name, self.namespace) or name


def _check_topic(topic: str) -> None:
    if not isinstance(topic, str) or not topic or topic.encode().startswith(INTERNAL_PREFIX) \
            or topic.lstrip("/").encode().startswith(names.HEARTBEAT_IN):
        raise ValueError("topic must be a non-empty string not starting with '_bus/' nor 'node/heartbeat/' "
                         f"(the heartbeats' wire topics, names.heartbeat_key), got {topic!r}")


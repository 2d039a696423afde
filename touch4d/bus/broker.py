"""The bus broker: an XSUB/XPUB proxy that every node connects to.

Publishers connect to the XSUB side, subscribers to the XPUB side. The XSUB side subscribes to
every topic up front, so a publisher sends everything to the broker as soon as it is connected
and filtering happens once, at the XPUB side, per subscriber. With CurveZMQ keys in the config,
both sides are CURVE servers and a ZAP handler admits only the allow-listed client keys.
"""
from __future__ import annotations

import logging
import signal
import threading
import time

import zmq
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils.monitor import recv_monitor_message

from touch4d.bus import transport
from touch4d.bus.config import BusConfig
from touch4d.bus.realtime import raise_thread_priority
from touch4d.bus.transport import bus_context
from touch4d.errors import ConfigError

log = logging.getLogger("touch4d.bus.broker")
ZAP_DOMAIN = "touch4d"


class _AllowList:
    """ZAP credentials provider: a client key is admitted when it is on the list."""

    def __init__(self, keys):
        self.keys = {k.encode() if isinstance(k, str) else k for k in keys}

    def callback(self, domain, key: bytes) -> bool:
        allowed = key in self.keys
        if not allowed:
            log.warning("refused a peer with an unknown CURVE key %s", key.decode(errors="replace"))
        return allowed


class Broker:
    """Runs the proxy in a background thread (`start`/`stop`) or in the caller's thread (`run`)."""

    def __init__(self, config: BusConfig, context: zmq.Context | None = None, realtime: bool = False):
        """`realtime`: run the proxy and I/O threads with SCHED_FIFO when permitted, because every
        message of the haptic loop crosses the broker twice (pose -> tactile -> motors)."""
        self.config = config
        self.realtime = realtime
        self._own_context = context is None
        self.context = context or bus_context(realtime)
        self._thread: threading.Thread | None = None
        self._auth: ThreadAuthenticator | None = None
        self._control_endpoint = f"inproc://touch4d-broker-{id(self)}"
        self._frontend = self._backend = self._control = None
        self.endpoints: BusConfig | None = None

    def _bind(self) -> BusConfig:
        cfg = self.config
        curve = cfg.curve
        if curve is not None:
            if not curve.server_secret:
                raise ConfigError(cfg.source, "curve.server_secret", "the broker's secret key file on the broker machine")
            self._auth = ThreadAuthenticator(self.context)
            self._auth.start()
            self._auth.configure_curve_callback(ZAP_DOMAIN, credentials_provider=_AllowList(curve.authorized))
        frontend = transport.server_socket(self.context, zmq.XSUB, cfg, ZAP_DOMAIN.encode())
        backend = transport.server_socket(self.context, zmq.XPUB, cfg, ZAP_DOMAIN.encode())
        for sock, port, key in ((frontend, cfg.pub_port, "broker.pub_port"), (backend, cfg.sub_port, "broker.sub_port")):
            try:
                sock.bind(cfg.bind_endpoint(port))
            except zmq.ZMQError as exc:
                frontend.close()
                backend.close()
                self._stop_auth()
                if exc.errno == zmq.EADDRINUSE:
                    raise ConfigError(cfg.source, key, f"a free port on {cfg.bind_host}", got=port, detail=(
                        f"in use (another touch4d launch or broker?): join the running broker with --no-broker, "
                        f"or give this one other ports with --bus FILE (a bus config with broker: "
                        f"{{pub_port: ..., sub_port: ...}})")) from None
                raise ConfigError(cfg.source, key, f"a port to bind on {cfg.bind_host}", got=port, detail=str(exc)) from None
        # Subscribe to everything: publishers then forward all topics to the broker at once.
        frontend.send(transport.SUBSCRIBE_ALL)
        self._frontend, self._backend = frontend, backend
        self._control = self.context.socket(zmq.PAIR)
        self._control.bind(self._control_endpoint)
        pub_port = int(frontend.last_endpoint.decode().rsplit(":", 1)[1])
        sub_port = int(backend.last_endpoint.decode().rsplit(":", 1)[1])
        self.endpoints = cfg.with_ports(pub_port, sub_port)
        return self.endpoints

    def _proxy(self) -> None:
        if self.realtime:
            raise_thread_priority()
        try:
            zmq.proxy_steerable(self._frontend, self._backend, None, self._control)
        except zmq.ContextTerminated:
            pass
        finally:
            for sock in (self._frontend, self._backend, self._control):
                sock.close(linger=0)

    def start(self) -> BusConfig:
        """Bind and proxy in a daemon thread; returns the config with the ports actually bound."""
        endpoints = self._bind()
        self._thread = threading.Thread(target=self._proxy, name="touch4d-broker", daemon=True)
        self._thread.start()
        log.debug("broker up: pub %s sub %s", endpoints.pub_endpoint, endpoints.sub_endpoint)
        return endpoints

    def stop(self) -> None:
        if self._thread is not None:
            ctl = self.context.socket(zmq.PAIR)
            ctl.linger = 0
            ctl.connect(self._control_endpoint)
            ctl.send(b"TERMINATE")
            self._thread.join(timeout=2.0)
            ctl.close()
            self._thread = None
        self._stop_auth()
        if self._own_context:
            self.context.term()

    def _stop_auth(self) -> None:
        if self._auth is not None:
            self._auth.stop()
            self._auth = None

    def run(self) -> None:
        """Serve until SIGINT or SIGTERM (the `touch4d bus broker` command)."""
        done = threading.Event()
        previous = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        endpoints = self.start()
        print(f"broker: publishers connect to {endpoints.pub_endpoint}, subscribers to {endpoints.sub_endpoint}"
              + (" (CURVE)" if endpoints.curve else ""), flush=True)
        try:
            while not done.wait(0.5):
                pass
        finally:
            self.stop()
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def __enter__(self) -> BusConfig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


class BrokerWatch:
    """Whether the broker a launch relies on is still there.

    It holds one connection to the broker's subscriber side (subscribed to nothing) and watches it with
    a ZeroMQ socket monitor: when the broker dies, its kernel closes the connection and the monitor
    says so at once. `lost(now)` names the broker once the connection has been down `grace` seconds
    (ZeroMQ reconnects by itself, so a broker back within `grace` is no loss). A broker not yet up
    (started after the launch) is waited for, not lost.
    """

    # Connected = the ZMTP (and CURVE) handshake done: a broker that refuses this machine's key is
    # never "there", so it is not reported as gone (the nodes say why they cannot connect).
    EVENTS = zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_DISCONNECTED

    def __init__(self, bus: BusConfig, grace: float = 1.0, context: zmq.Context | None = None):
        self.endpoint = bus.sub_endpoint
        self.grace = grace
        self._own_context = context is None
        self.context = context or zmq.Context()
        try:
            self.sock = transport.subscriber(self.context, bus, connect=False)   # raises without client keys
        except BaseException:
            if self._own_context:
                self.context.term()
            raise
        self.monitor = self.sock.get_monitor_socket(self.EVENTS)
        self.sock.connect(self.endpoint)
        self.connected = False
        self.down_since: float | None = None

    def lost(self, now: float | None = None) -> str | None:
        """None while the broker is there (or not yet seen), else what happened to it."""
        now = time.monotonic() if now is None else now
        while self.monitor.poll(0):
            event = recv_monitor_message(self.monitor)["event"]
            if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self.connected, self.down_since = True, None
            elif event == zmq.EVENT_DISCONNECTED and self.connected:
                self.connected, self.down_since = False, now
        if self.down_since is not None and now - self.down_since >= self.grace:
            return (f"the broker at {self.endpoint} went away (its connection closed {now - self.down_since:.1f} s "
                    "ago and did not come back)")
        return None

    def close(self) -> None:
        self.sock.disable_monitor()
        self.monitor.close(linger=0)
        self.sock.close(linger=0)
        if self._own_context:
            self.context.term()

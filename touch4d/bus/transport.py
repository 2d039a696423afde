"""The transport: every ZeroMQ socket of touch4d is made, configured and synchronised here.

A message is a multipart `[topic, payload]`. Clients (nodes, the recorder, replay, the
introspection tools) publish through an XPUB connected to the broker's XSUB port and subscribe
through a SUB connected to its XPUB port; the broker binds the two (`server_socket`). With
CurveZMQ keys in the bus config, the broker's sockets are CURVE servers and every client socket a
CURVE client, set up here only.

- **Publishing starts when the broker is there**: the broker's XSUB subscribes to everything, so a
  client's XPUB receives that subscribe-all once connected (`await_broker`).
- **Slow joiner** (`sync`): a subscription is in force once the broker applies it. The client
  subscribes to a private `_bus/sync/...` topic last and publishes probes on it through the broker
  until one comes back; subscriptions on one connection are applied in order, so every message the
  broker forwards after that point reaches the client.
- Topics starting with `_bus/` (`INTERNAL_PREFIX`) belong to the transport and are never delivered.
"""
from __future__ import annotations

import itertools
import os
import time
from typing import Callable

import zmq

from touch4d.bus.config import BusConfig
from touch4d.bus.realtime import bus_context
from touch4d.errors import ConfigError

INTERNAL_PREFIX = b"_bus/"          # topics of the transport itself, never delivered to callbacks
SYNC_PREFIX = INTERNAL_PREFIX + b"sync/"
SUBSCRIBE_ALL = b"\x01"            # what an XPUB receives when the broker's XSUB subscribes to everything
_tokens = itertools.count(1)

__all__ = ["INTERNAL_PREFIX", "SUBSCRIBE_ALL", "SYNC_PREFIX", "await_broker", "bus_context", "client_socket",
           "drain_broker_subscriptions", "publisher", "server_socket", "subscriber", "sync", "sync_token"]


def client_socket(context: zmq.Context, kind: int, bus: BusConfig, *, hwm: int | None = None,
                  linger: int = 0) -> zmq.Socket:
    """A socket of `kind` with the bus's queue limits (`hwm`: 0 = unbounded) and, when the bus has
    keys, this machine's CURVE client keys; not connected."""
    sock = context.socket(kind)
    try:
        sock.sndhwm = sock.rcvhwm = bus.hwm if hwm is None else hwm
        sock.linger = linger
        curve = bus.curve
        if curve is not None:
            if not (curve.client_public and curve.client_secret):
                raise ConfigError(bus.source, "curve.client_secret", "this machine's key pair (touch4d bus keygen)")
            sock.curve_serverkey = curve.server_public.encode()
            sock.curve_publickey = curve.client_public.encode()
            sock.curve_secretkey = curve.client_secret.encode()
    except BaseException:
        sock.close(linger=0)
        raise
    return sock


def publisher(context: zmq.Context, bus: BusConfig, *, connect: bool = True, hwm: int | None = None,
              linger: int = 0) -> zmq.Socket:
    """An XPUB (it sends like a PUB, and hears the broker subscribe) for the broker's XSUB port."""
    sock = client_socket(context, zmq.XPUB, bus, hwm=hwm, linger=linger)
    if connect:
        sock.connect(bus.pub_endpoint)
    return sock


def subscriber(context: zmq.Context, bus: BusConfig, *, connect: bool = True, hwm: int | None = None,
               topics=()) -> zmq.Socket:
    """A SUB for the broker's XPUB port, subscribed to `topics` (bytes prefixes) before it connects."""
    sock = client_socket(context, zmq.SUB, bus, hwm=hwm)
    for topic in topics:
        sock.subscribe(topic)
    if connect:
        sock.connect(bus.sub_endpoint)
    return sock


def server_socket(context: zmq.Context, kind: int, bus: BusConfig, zap_domain: bytes | None = None) -> zmq.Socket:
    """One of the broker's two sockets: the bus's queue limits and, with keys, a CURVE server
    whose peers the ZAP handler of `zap_domain` admits."""
    sock = context.socket(kind)
    sock.linger = 0
    sock.sndhwm = sock.rcvhwm = bus.hwm
    if bus.curve is not None:
        if not bus.curve.server_secret:
            sock.close()
            raise ConfigError(bus.source, "curve.server_secret", "the broker's secret key file on the broker machine")
        sock.curve_server = True
        sock.curve_secretkey = bus.curve.server_secret.encode()
        if zap_domain:
            sock.zap_domain = zap_domain
    return sock


def await_broker(pub: zmq.Socket, timeout: float) -> bool:
    """Wait up to `timeout` s until the broker subscribes to the XPUB `pub` (publishing reaches it)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or not pub.poll(max(1, int(left * 1000))):
            return False
        if pub.recv() == SUBSCRIBE_ALL:
            return True


def drain_broker_subscriptions(pub: zmq.Socket) -> bool:
    """Read what the broker sent the XPUB `pub` without blocking; True if it subscribed to
    everything again (it (re)connected)."""
    seen = False
    while True:
        try:
            seen = pub.recv(zmq.NOBLOCK) == SUBSCRIBE_ALL or seen
        except zmq.Again:
            return seen


def sync_token(owner: str) -> bytes:
    """A private topic for one `sync`, unique on the bus (owner, process, counter)."""
    return SYNC_PREFIX + b"%s/%d/%d" % (owner.encode(), os.getpid(), next(_tokens))


def sync(sub: zmq.Socket, pub: zmq.Socket, timeout: float, *, owner: str = "client",
         other: Callable[[list[bytes]], None] | None = None) -> bool:
    """Block until the broker applies every subscription made on `sub` so far (see the module
    doc); False after `timeout` s. Messages that arrive meanwhile go to `other(frames)` (except
    the transport's own), so none is lost."""
    token = sync_token(owner)
    sub.subscribe(token)
    deadline = time.monotonic() + timeout
    interval = 0.002
    try:
        while time.monotonic() < deadline:
            pub.send_multipart((token, b""))
            until = time.monotonic() + interval
            while (left := until - time.monotonic()) > 0 and sub.poll(int(left * 1000) + 1):
                frames = sub.recv_multipart()
                if frames[0] == token:
                    return True
                if other is not None and not frames[0].startswith(INTERNAL_PREFIX):
                    other(frames)
            interval = min(interval * 2, 0.1)
        return False
    finally:
        sub.unsubscribe(token)

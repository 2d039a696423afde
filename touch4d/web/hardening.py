"""What every touch4d web server does before and around its handlers, written once for the page
server (touch4d.web.server) and the study server (touch4d.web.studyserver), both open to the internet:

- each TCP connection counted per client address before anything else (a TLS handshake included),
  at most `max_per_address` at once (loopback clients, e.g. a reverse proxy, exempt unless
  `limit_loopback`); the file limit raised to its hard limit (a few hundred idle sockets must not
  starve real clients nor the server's own files);
- a request header whole within `header_timeout_s` (a slow trickle is closed), an idle kept-alive
  connection closed after KEEPALIVE_S;
- only the Host names served (loopback names, the LAN addresses of a wildcard bind, the configured
  `names`; else 421: DNS rebinding);
- the security headers on every answer (errors included; one already set, e.g. a proxied page's,
  is kept) and no Server banner;
- aiohttp's own log filtered: a malformed request counted, not logged with a traceback; a handler's
  failure logged with its traceback once per kind of exception, then in one line; control and
  bidirectional characters escaped in every line (`escaped`), so a request path cannot forge lines.

    hardening = Hardening(host, names)
    app = hardening.application(middlewares=[...])
    runner = hardening.runner(app)             # every site of it (TCPSite, SockSite) guarded
    hardening.take(transport, protocol)        # a spliced connection leaves aiohttp, still counted
"""
from __future__ import annotations

import asyncio
import collections
import ipaddress
import logging
import resource
import unicodedata
from typing import Iterable
from urllib.parse import urlsplit

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from .access import is_loopback, lan_addresses

MAX_PER_ADDRESS = 16         # TCP connections at once from one client address (a browser opens ~6)
HEADER_TIMEOUT_S = 10.0      # a request's header must arrive whole within this (slow trickle: closed)
KEEPALIVE_S = 15.0           # an idle HTTP connection is closed after this
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
SECURITY_HEADERS = {
    # The page may talk to this server only: no other host, no inline script, no framing.
    "Content-Security-Policy": ("default-src 'self'; connect-src 'self'; img-src 'self' data:; "
                                "frame-ancestors 'none'; base-uri 'none'; form-action 'none'"),
    "Referrer-Policy": "no-referrer",       # nothing of the page's address leaves in Referer headers
    "Cache-Control": "no-store",
    "X-Content-Type-Options": "nosniff",
}


def escaped(text: str) -> str:
    """`text` with every control, format (bidi: U+202E, U+2066...) and line-separator character
    written as its escape (\\x1b, \\r, \\u202e): one log line stays one line, shown as it is."""
    return "".join(c if unicodedata.category(c)[0] != "C" and unicodedata.category(c) not in ("Zl", "Zp")
                   else c.encode("unicode_escape").decode("ascii") for c in text)


class EscapedLines(logging.Filter):
    """A logger's lines with their control and bidi characters escaped (their arguments formatted first)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        clean = escaped(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True


ESCAPED = EscapedLines()


class ServerErrors(EscapedLines):
    """aiohttp's log of a server: a malformed request (answered 400) counted, not logged; a
    handler's exception logged with its traceback the first time its kind is seen, in one line after
    (a client repeating a request that fails must not fill the log)."""

    def __init__(self):
        super().__init__()
        self.count = 0           # malformed requests
        self.errors = 0          # handlers' exceptions
        self._seen: set[type] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            self.count += 1
            return False
        if exc is not None:
            self.errors += 1
            if type(exc) in self._seen:
                record.msg, record.args = f"{record.getMessage()}: {type(exc).__name__}: {exc}", None
                record.exc_info, record.exc_text = None, None
            self._seen.add(type(exc))
        return super().filter(record)


# aiohttp's own loggers, for what it logs there rather than through a server's (a WebSocket's offered
# protocols, say): filtered and escaped alike.
AIOHTTP_LOG = ServerErrors()
for _name in ("aiohttp.server", "aiohttp.access", "aiohttp.web", "aiohttp.websocket"):
    logging.getLogger(_name).addFilter(AIOHTTP_LOG)


def raise_file_limit() -> int:
    """This process's open-file limit raised to its hard limit (systemd's soft 1,024 is a few hundred
    idle sockets); returns the limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return soft


def host_name(name: str) -> str:
    """A host name as a Host header's is compared: lower case, without scheme, port or brackets
    (a user may write `touch4d.example:443` or `https://touch4d.example/`); a bare IPv6 address as it is."""
    try:
        return str(ipaddress.ip_address(name))
    except ValueError:
        return (urlsplit(name if "://" in name else f"//{name}").hostname or name).lower()


def served_names(host: str, names: Iterable[str] = ()) -> set[str]:
    """The Host names a server bound to `host` answers: loopback names, `names`, and beyond loopback
    the address bound (or, bound to every address, this machine's LAN addresses)."""
    served = {host_name(n) for n in (*LOOPBACK_NAMES, *names) if n}
    if not is_loopback(host):
        served |= {a.lower() for a in lan_addresses(host)} | ({host.lower()} if host not in ("", "0.0.0.0", "::") else set())
    return served


class Hardening:
    """One server's bounds (see the module doc) and what they refused."""

    def __init__(self, host: str, names: Iterable[str] = (), *, ssl_context=None,
                 max_per_address: int = MAX_PER_ADDRESS, limit_loopback: bool = False,
                 header_timeout_s: float = HEADER_TIMEOUT_S, headers: dict[str, str] = SECURITY_HEADERS,
                 log: logging.Logger | None = None):
        self.names = served_names(host, names)
        self.ssl_context = ssl_context
        self.max_per_address, self.limit_loopback = max_per_address, limit_loopback
        self.header_timeout_s, self.headers = header_timeout_s, dict(headers)
        self.refused_host = 0       # Host names not served (421)
        self.over_address = 0       # connections closed at once: max_per_address from that address
        self.header_timeouts = 0    # connections closed: no whole request header in time
        self.tls_failed = 0         # connections closed: no TLS handshake, or a failed one, in time
        self.errors = ServerErrors()
        parent = log or logging.getLogger(__name__)
        self.http_log = logging.Logger(f"{parent.name}.http")   # aiohttp's lines, filtered, then the parent's handlers
        self.http_log.parent = parent
        self.http_log.addFilter(self.errors)
        self.per_address: collections.Counter = collections.Counter()
        self.guards: dict = {}      # transport -> its _Guard

    def counts(self) -> dict[str, int]:
        return {"wrong_host": self.refused_host, "over_address": self.over_address,
                "header_timeout": self.header_timeouts, "tls_failed": self.tls_failed,
                "bad_request": self.errors.count, "handler_error": self.errors.errors}

    # ---- aiohttp -----------------------------------------------------------------------------------

    def application(self, middlewares: Iterable = (), **kwargs) -> web.Application:
        """An aiohttp app whose requests pass the Host check first, and whose answers carry the headers."""
        app = web.Application(middlewares=[self.check_host, *middlewares], **kwargs)
        app.on_response_prepare.append(self.prepare_headers)
        return app

    def runner(self, app: web.Application) -> "_GuardedRunner":
        """The app's runner: its sites' connections guarded, idle kept-alive ones closed, aiohttp's log
        filtered, no access log. The file limit is raised here, once the server is made."""
        raise_file_limit()
        return _GuardedRunner(self, app, access_log=None, handle_signals=False, keepalive_timeout=KEEPALIVE_S,
                              logger=self.http_log)

    async def prepare_headers(self, request: web.Request, response: web.StreamResponse) -> None:
        """Every answer, the router's 404 and 405 and a gate's 403 included."""
        for name, value in self.headers.items():
            response.headers.setdefault(name, value)
        response.headers.pop("Server", None)   # no banner naming the software and its version

    def host_served(self, request: web.Request) -> bool:
        host = request.headers.get("Host")
        try:
            name = urlsplit(f"//{host}").hostname if host else None
        except ValueError:
            name = None
        return name is not None and name in self.names

    @web.middleware
    async def check_host(self, request: web.Request, handler):
        # DNS rebinding: a page of another site, its name pointed at this address, must get nothing.
        if not self.host_served(request):
            self.refused_host += 1
            raise web.HTTPMisdirectedRequest(text="touch4d: this server does not serve that host name\n")
        return await handler(request)

    # ---- connections ---------------------------------------------------------------------------------

    def upgraded(self, transport) -> None:
        """A connection became a WebSocket: no header timeout from now on."""
        guard = self.guards.get(transport)
        if guard is not None:
            guard.upgrade()

    def take(self, transport, protocol: asyncio.BaseProtocol) -> None:
        """`protocol` reads `transport` from now on (a splice takes a connection from aiohttp): through its
        guard, which keeps counting it, or directly where it has none."""
        guard = self.guards.get(transport)
        if guard is None:
            transport.set_protocol(protocol)
            return
        guard.upgrade()
        guard.inner = protocol

    def admit(self, address: str) -> bool:
        if (self.limit_loopback or not is_loopback(address)) and self.per_address[address] >= self.max_per_address:
            self.over_address += 1
            return False
        self.per_address[address] += 1
        return True

    def release(self, address: str) -> None:
        self.per_address[address] -= 1
        if self.per_address[address] <= 0:
            del self.per_address[address]


class _GuardedRunner(web.AppRunner):
    """An AppRunner whose protocol factory (what its sites listen with) puts a _Guard in front."""

    def __init__(self, hardening: Hardening, app: web.Application, **kwargs):
        super().__init__(app, **kwargs)
        self.hardening = hardening

    @property
    def server(self):
        inner = self._server
        return None if inner is None else (lambda: _Guard(self.hardening, inner()))


class _Guard(asyncio.Protocol):
    """One TCP connection in front of aiohttp's handler: counted per client address before anything
    else (a TLS handshake included: connections that never finish one are capped too), TLS started
    over it if the server has a certificate, closed if a request header does not arrive whole within
    the header timeout; passes through after a WebSocket upgrade."""

    def __init__(self, hardening: Hardening, inner: asyncio.Protocol):
        self.hardening, self.inner = hardening, inner
        self.address: str | None = None
        self.transport = None            # what the handler uses: the TCP connection, or TLS over it
        self.early: list[bytes] = []     # data decrypted before the handler has its transport
        self.early_eof = False
        self.handshake: asyncio.Future | None = None
        self.timer: asyncio.TimerHandle | None = None
        self.tail = b""
        self.upgraded = False

    def connection_made(self, transport) -> None:
        peer = transport.get_extra_info("peername")
        address = peer[0] if peer else "?"
        if not self.hardening.admit(address):
            transport.abort()
            return
        self.address = address
        if self.hardening.ssl_context is None:
            self._attach(transport)
        else:
            self.handshake = asyncio.ensure_future(self._start_tls(transport))   # (held: a task is weakly kept)

    async def _start_tls(self, raw) -> None:
        try:
            transport = await asyncio.get_running_loop().start_tls(
                raw, self, self.hardening.ssl_context, server_side=True,
                ssl_handshake_timeout=self.hardening.header_timeout_s)
        except Exception:  # noqa: BLE001 - a failed or timed-out handshake: start_tls closed the connection
            self.hardening.tls_failed += 1
            self._forget()
            return
        if self.address is None:          # lost in between
            transport.abort()
            return
        self._attach(transport)

    def _attach(self, transport) -> None:
        self.transport = transport
        self.hardening.guards[transport] = self
        self.inner.connection_made(transport)
        self._arm()
        for data in self.early:
            self.data_received(data)
        self.early = []
        if self.early_eof:
            self.inner.eof_received()

    def _forget(self) -> None:
        """Release the connection's place in its address's count (once)."""
        if self.address is not None:
            self.hardening.release(self.address)
            self.address = None

    def _arm(self) -> None:
        self.tail = b""
        self.timer = asyncio.get_running_loop().call_later(self.hardening.header_timeout_s, self._expired)

    def _expired(self) -> None:
        self.hardening.header_timeouts += 1
        self.transport.abort()

    def data_received(self, data: bytes) -> None:
        if self.transport is None:       # TLS: the request right after the handshake, before _attach
            self.early.append(data)
            return
        if not self.upgraded:
            if self.timer is None:
                self._arm()              # the next request on a kept-alive connection
            seen = self.tail + data
            if b"\r\n\r\n" in seen:      # the header is whole: its handler takes it from here
                self.timer.cancel()
                self.timer = None
                after = seen.rsplit(b"\r\n\r\n", 1)[1]
                if after:                # pipelined: the next header has begun
                    self._arm()
                    self.tail = after[-3:]
            else:
                self.tail = seen[-3:]
        self.inner.data_received(data)

    def upgrade(self) -> None:
        self.upgraded = True
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def eof_received(self):
        if self.transport is None:
            self.early_eof = self.address is not None
            return None
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        if self.transport is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.transport is not None:
            self.inner.resume_writing()

    def connection_lost(self, exc) -> None:
        if self.timer is not None:
            self.timer.cancel()
        attached = self.transport is not None and self.address is not None
        self._forget()
        if attached:
            self.hardening.guards.pop(self.transport, None)
            self.inner.connection_lost(exc)

"""The page's server: aiohttp on an asyncio loop, serving the page and its files from the package
and one WebSocket per open page. The loop is the node's (`loop`: its executor's, which then runs the
node and the server on one thread, touch4d.bus.executor), or one in a thread of its own.

It holds no touch4d state: what pages send goes to `on_message(conn, data, arrival)` (data: the
text, the bytes, or the WebSocket error that closed the connection, e.g. a message over the page
message limit; with `on_connect(conn)` / `on_close(conn)`). Each page's messages pass through its
`Inbox` (paced inputs, the latest kept; other messages bounded): with `on_pending(conn)` the server
only says that a page has something, and the node's thread calls `deliver(conn)`, which calls
`on_message` there; without it, `on_message` is called on the server's thread. What the node sends
goes out through `send` and `broadcast`, safe from any thread. Per page, frames marked `latest`
replace one not yet sent (a slow Wi-Fi link gets the newest state, never a backlog); the others
(setup, geometry) are sent in order, never dropped: a page with `max_queued` of them unsent, or
whose socket takes `send_timeout_s` to take one frame, is closed (counted in `send_overflow`).

Bounds for the internet (touch4d.web.hardening, shared with the study server): only the Host names it
serves (loopback names, its LAN addresses, the configured `names`; else 421, page and WebSocket alike:
DNS rebinding), `max_per_address` TCP connections per client address (counted before any TLS
handshake; loopback clients, e.g. a reverse proxy, are exempt unless `limit_loopback`), a request
header whole within `header_timeout_s`, no Server banner, the security headers on every answer,
errors included. Its own: WebSockets from its own origin only, `max_pages` pages at once, under
/static/ the page's files only (static_names). With an `Access` (touch4d.web.access) every path but
the page's own files needs a token or cookie; with a `secret`, every such path needs it in the
X-Touch4d-Secret header (a participant's page node behind the study server).
"""
from __future__ import annotations

import asyncio
import collections
import hmac
import itertools
import logging
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Callable, Iterable

import msgspec
from aiohttp import WSMsgType, web

from touch4d.eventloop import new_event_loop

from .access import COOKIE, HOLDER, Access, CookieGate, cross_site
from .hardening import ESCAPED, HEADER_TIMEOUT_S, MAX_PER_ADDRESS, Hardening
from .inbox import MAX_INPUT_HZ, OTHER_BURST, Inbox
from .protocol import MAX_PAGE_MESSAGE, message_type

log = logging.getLogger(__name__)
log.addFilter(ESCAPED)

STATIC_DIR = Path(str(resources.files("touch4d.web") / "static"))
SECRET_HEADER = "X-Touch4d-Secret"   # with a `secret`: what a proxy in front (the study server) sends
WS_HEARTBEAT_S = 2.0         # a page that answers no ping within this is closed (it does not read)
MAX_PAGES = 64               # pages connected at once: one more is refused (HTTP 503)
SEND_TIMEOUT_S = 5.0         # one frame not taken by the page's socket within this: the page is closed
MAX_QUEUED = 32              # in-order frames waiting for one page; one more closes it


class PageBounds(msgspec.Struct, frozen=True, kw_only=True):
    """What one page server allows its pages (see the module doc): its defaults are the page node's."""
    max_pages: int = MAX_PAGES               # pages connected at once: the server's memory and send work
    max_per_address: int = MAX_PER_ADDRESS   # TCP connections per client address: one host cannot take every slot
    limit_loopback: bool = False             # count loopback clients too (else exempt: a reverse proxy's)
    header_timeout_s: float = HEADER_TIMEOUT_S   # a request header whole within this: slow senders hold no slot
    send_timeout_s: float = SEND_TIMEOUT_S   # one frame taken by a page's socket within this, else it is closed
    max_queued: int = MAX_QUEUED             # in-order frames unsent to one page; one more closes it (memory)
    input_hz: float = MAX_INPUT_HZ           # a page's inputs delivered at most this often (the node's CPU)
    other_burst: int = OTHER_BURST           # a page's other messages over this burst are dropped (a flood)
    secure_cookie: bool = True               # the access cookie only over HTTPS (False: plain-HTTP tests)


def static_names(directory: Path) -> frozenset[str]:
    """The page's files: the regular files of `directory` (no folder, no symlink). Only these are
    served under /static/ (any other name, an over-long one included, is 404 before any file
    system call) and only these does the study server forward."""
    return frozenset(p.name for p in Path(directory).iterdir() if p.is_file() and not p.is_symlink())


class _Client:
    """One page's WebSocket and what waits to be sent to it."""

    def __init__(self, ws: web.WebSocketResponse, transport, holder: str | None, inbox: Inbox, peer: str = ""):
        self.ws = ws
        self.transport = transport
        self.peer = peer         # the page's address (host:port), for the log only (never sent to pages)
        self.dropped = False
        self.holder = holder     # who opened it (the Access holder), None without access control
        self.inbox = inbox
        self.queue: collections.deque = collections.deque()
        self.latest: bytes | None = None
        self.wake = asyncio.Event()
        self.ready = False   # set by the node's first frame to this page: broadcasts reach it after
        self.release: asyncio.TimerHandle | None = None   # the held input's time


class PageServer:
    """HTTP + WebSocket server for the WebXR page, running until `stop()`."""

    def __init__(self, host: str, port: int, access: Access | None = None, ssl_context=None, *,
                 bounds: PageBounds = PageBounds(), names: Iterable[str] = (),
                 on_connect: Callable[[int], None] = lambda conn: None,
                 on_message: Callable[[int, object, float], None] = lambda conn, data, arrival: None,
                 on_close: Callable[[int], None] = lambda conn: None,
                 on_pending: Callable[[int], None] | None = None, static_dir: Path = STATIC_DIR,
                 secret: str | None = None, loop: asyncio.AbstractEventLoop | None = None,
                 hardening: Hardening | None = None):
        self.host, self.port, self.access, self.ssl_context = host, port, access, ssl_context
        self.on_connect, self.on_message, self.on_close = on_connect, on_message, on_close
        self.on_pending = on_pending
        self.static_dir = Path(static_dir)
        self.bounds = bounds
        self.secret = secret
        self.hardening = hardening or Hardening(host, names, ssl_context=ssl_context,
                                                max_per_address=bounds.max_per_address,
                                                limit_loopback=bounds.limit_loopback,
                                                header_timeout_s=bounds.header_timeout_s, log=log)
        self.names = self.hardening.names
        self.gate = CookieGate(access, secure=bounds.secure_cookie, open_prefixes=("/static/",)) if access else None
        # counted refusals and closes
        self.refused_origin = 0     # WebSockets from another site
        self.refused_secret = 0     # requests without the secret (with a `secret`)
        self.over_limit = 0         # connections refused because max_pages pages were connected
        self.send_overflow = 0      # pages closed: they did not take what was sent to them
        self.inputs_replaced = 0    # of closed pages: inputs superseded by a newer one (paced)
        self.flooded = 0            # of closed pages: other messages over their rate, dropped
        self.clients: dict[int, _Client] = {}
        self._per_address = self.hardening.per_address   # connections per client address, open now
        self._guards = self.hardening.guards
        self._inboxes: dict[int, Inbox] = {}     # until the last delivery after a page closed
        self._ids = itertools.count(1)
        self._given_loop = loop            # its owner runs it; None: a thread of the server's own
        self._closing: asyncio.Task | None = None   # a stop from a callback on the given loop
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._listener: asyncio.base_events.Server | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None
        if access is not None:
            access.on_revoke(self._revoked)

    @property
    def refused(self) -> int:
        """Requests refused: no valid token, cookie or secret, another origin, or a Host not served."""
        return (self.gate.refused if self.gate else 0) + self.refused_origin + self.refused_secret + self.refused_host

    # the hardening's counts (touch4d.web.hardening), as the server's own
    refused_host = property(lambda self: self.hardening.refused_host)
    over_address = property(lambda self: self.hardening.over_address)
    header_timeouts = property(lambda self: self.hardening.header_timeouts)
    tls_failed = property(lambda self: self.hardening.tls_failed)

    # ---- lifecycle (any thread) ------------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> int:
        """Bind and serve; returns the port (useful with port 0). Raises OSError if it cannot bind.
        On a given loop: before its owner runs it (it serves once the owner spins)."""
        if self._given_loop is not None:
            if self._given_loop.is_running():
                raise RuntimeError("a page server on a given loop starts before the loop runs")
            self._loop = self._given_loop
            try:
                self._given_loop.run_until_complete(self._serve())
            except BaseException:
                self._loop = None
                raise
            return self.port
        self._thread = threading.Thread(target=self._run, name="webxr-server", daemon=True)
        self._thread.start()
        if not self._started.wait(timeout):
            raise TimeoutError("the page server did not start")
        if self._error is not None:
            raise self._error
        return self.port

    def stop(self, timeout: float = 3.0) -> None:
        loop = self._loop
        if self._given_loop is not None:
            if loop is None or loop.is_closed():
                return
            if loop.is_running():     # from a callback on it: the rest happens on its next turns
                self._closing = loop.create_task(self._shutdown())   # kept: a task only weakly held may vanish
            else:
                try:
                    loop.run_until_complete(asyncio.wait_for(self._shutdown(), timeout))
                except Exception as exc:  # noqa: BLE001 - stopping must finish whatever the loop says
                    log.debug("page server shutdown: %s", exc)
            self._loop = None
            return
        if loop is None or self._thread is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout)
        except Exception as exc:  # noqa: BLE001 - stopping must finish whatever the loop says
            log.debug("page server shutdown: %s", exc)
        loop.call_soon_threadsafe(loop.stop)
        self._thread.join(timeout)

    def mount(self, loop: asyncio.AbstractEventLoop) -> None:
        """Serve pages' WebSockets through another server's route (`websocket`, on `loop`: the study
        server's /ws), with this one's bounds, queues and callbacks; no listener of its own."""
        self._loop = loop

    def send(self, conn: int, data: bytes, latest: bool = False) -> None:
        """Queue a frame for one page: in order, never dropped; `latest`: replacing one not yet sent."""
        self._on_loop(self._enqueue, conn, data, latest, True)

    def close(self, conn: int) -> None:
        """Close one page's WebSocket (its session ended); it may reconnect."""
        client = self.clients.get(conn)
        if client is not None:
            self._on_loop(lambda: asyncio.ensure_future(client.ws.close(code=1001, message=b"session ended")))

    def peer(self, conn: int) -> str:
        """The address (host:port) of a connected page, for the log; '' once it has gone."""
        client = self.clients.get(conn)
        return client.peer if client is not None else ""

    def holder(self, conn: int) -> str | None:
        """Who opened a connected page (its Access holder); None without access control or once gone."""
        client = self.clients.get(conn)
        return client.holder if client is not None else None

    def broadcast(self, data: bytes, latest: bool = False) -> None:
        """Queue a frame for every page; `latest` frames replace an unsent one."""
        self._on_loop(self._enqueue_all, data, latest)

    def _on_loop(self, callback: Callable, *args) -> None:
        """Run `callback(*args)` on the server's loop: at once from the loop's own thread (the node's,
        on a given loop), else handed over (any other thread)."""
        loop = self._loop
        if loop is None:
            return
        try:
            here = asyncio.get_running_loop() is loop
        except RuntimeError:
            here = False
        if here:
            callback(*args)
        else:
            loop.call_soon_threadsafe(callback, *args)

    def deliver(self, conn: int) -> None:
        """Call `on_message` for what the page has sent since (the node's thread, after `on_pending`;
        once more after the page closed, before `on_close`, for its last messages)."""
        inbox = self._inboxes.get(conn)
        if inbox is None:
            return
        if conn not in self.clients:
            self._inboxes.pop(conn, None)
        for data, arrival in inbox.take():
            self.on_message(conn, data, arrival)

    def counts(self) -> dict:
        """What the server refused, closed and dropped, for the node's stats."""
        return {"page_refused": self.refused, "page_over_limit": self.over_limit,
                "page_wrong_host": self.refused_host, "page_over_address": self.over_address,
                "page_header_timeout": self.header_timeouts, "page_tls_failed": self.tls_failed,
                "page_send_overflow": self.send_overflow,
                "page_bad_request": self.hardening.errors.count, "page_handler_error": self.hardening.errors.errors,
                "page_inputs_replaced": self.inputs_replaced + sum(c.inbox.replaced for c in list(self.clients.values())),
                "page_flooded": self.flooded + sum(c.inbox.dropped for c in list(self.clients.values()))}

    # ---- the server's thread ---------------------------------------------------------------------

    def _run(self) -> None:
        loop = new_event_loop(serves_tls=self.ssl_context is not None)
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start()'s caller
            self._error, self._loop = exc, None
            loop.close()
            self._started.set()
            return
        self._started.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _serve(self) -> None:
        middlewares = ([self._check_secret] if self.secret else []) + ([self.gate.middleware] if self.gate else [])
        app = self.hardening.application(middlewares, client_max_size=MAX_PAGE_MESSAGE)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        self._static_names = static_names(self.static_dir)
        app.router.add_get("/static/{name}", self._static)
        self._runner = self.hardening.runner(app)
        await self._runner.setup()
        # TLS, if any, is started by each connection's guard once it is counted (touch4d.web.hardening)
        self._listener = await asyncio.get_running_loop().create_server(
            self._runner.server, self.host or None, self.port)
        self.port = self._listener.sockets[0].getsockname()[1]
        if self.gate is not None:
            # a browser keeps cookies per host, not per port: another server of this machine must not overwrite it
            self.gate.cookie = f"{COOKIE}-{self.port}"

    async def _shutdown(self) -> None:
        if self._listener is not None:
            self._listener.close()
        for client in list(self.clients.values()):
            await client.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    @web.middleware
    async def _check_secret(self, request: web.Request, handler):
        """Only the proxy in front knows the secret (the study server: a page node on loopback is
        reachable by every user of the machine); the page's own files need none."""
        given = request.headers.get(SECRET_HEADER, "")
        if not request.path.startswith("/static/") and not hmac.compare_digest(given.encode(), self.secret.encode()):
            self.refused_secret += 1
            raise web.HTTPForbidden(text="touch4d: this page is served through the study server only\n")
        return await handler(request)

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(self.static_dir / "index.html")

    async def _static(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if name not in self._static_names:
            raise web.HTTPNotFound()
        return web.FileResponse(self.static_dir / name)

    async def websocket(self, request: web.Request) -> web.StreamResponse:
        """A page's WebSocket, until it closes (the route of /ws, this server's or a mounting one's)."""
        return await self._websocket(request)

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        # A page from another site must not drive the hand through this browser (cross-site
        # WebSocket hijacking): a browser always sends Origin, and it must be this server (access.cross_site,
        # the study server's rule too).
        if cross_site(request):
            self.refused_origin += 1
            return web.Response(status=403, text="touch4d: WebSocket from another origin refused\n")
        if len(self.clients) >= self.bounds.max_pages:
            # Each page costs a setup frame and a send queue: a flood of connections must not take
            # the node's memory or its thread. A page that does not read is closed by the heartbeat.
            self.over_limit += 1
            return web.Response(status=503, text=f"touch4d: {self.bounds.max_pages} pages are connected already "
                                                 "(the webxr node's max_pages); close one and reload\n")
        # A page's pings are not answered (a browser never sends them): answering, the reading would wait
        # for the pongs to leave, and a page that reads nothing would hold its place for ever.
        ws = web.WebSocketResponse(max_msg_size=MAX_PAGE_MESSAGE, compress=False, heartbeat=WS_HEARTBEAT_S,
                                   autoping=False)
        await ws.prepare(request)
        self.hardening.upgraded(request.transport)
        conn = next(self._ids)
        peer = request.transport.get_extra_info("peername") if request.transport else None
        inbox = self._inboxes[conn] = Inbox(input_hz=self.bounds.input_hz, burst=self.bounds.other_burst)
        client = self.clients[conn] = _Client(ws, request.transport, request.get(HOLDER), inbox,
                                              f"{peer[0]}:{peer[1]}" if peer else (request.remote or "?"))
        sender = asyncio.ensure_future(self._sender(client))
        self.on_connect(conn)
        try:
            async for msg in ws:
                arrival = time.time()
                if msg.type == WSMsgType.TEXT:
                    self._offer(conn, client, msg.data, arrival)
                elif msg.type == WSMsgType.BINARY:
                    self._offer(conn, client, bytes(msg.data), arrival)
                elif msg.type == WSMsgType.ERROR:
                    self._offer(conn, client, msg.data, arrival, final=True)   # the error, counted
                    break
        finally:
            if client.release is not None:
                client.release.cancel()
            client.inbox.release(time.time())   # a held input goes too: its page's last word
            self.clients.pop(conn, None)
            self.inputs_replaced += inbox.replaced
            self.flooded += inbox.dropped
            self._pending(conn)                  # the last delivery (it forgets the inbox), then the close
            sender.cancel()
            self.on_close(conn)
        return ws

    def _offer(self, conn: int, client: _Client, data, arrival: float, final: bool = False) -> None:
        wake, release_at = client.inbox.offer(data, arrival, not final and message_type(data) == "input",
                                              always=final)
        if release_at is not None and client.release is None:
            loop = asyncio.get_running_loop()
            client.release = loop.call_at(loop.time() + max(0.0, release_at - time.time()),
                                          self._release_input, conn, client)
        if wake:
            self._pending(conn)

    def _release_input(self, conn: int, client: _Client) -> None:
        client.release = None
        if client.inbox.release(time.time()):
            self._pending(conn)

    def _pending(self, conn: int) -> None:
        if self.on_pending is None:
            self.deliver(conn)
        else:
            self.on_pending(conn)

    def _revoked(self, holder: str) -> None:
        """A holder's access ended: its open pages close too (any thread)."""
        self._on_loop(self._close_holder, holder)

    def _close_holder(self, holder: str) -> None:
        for client in list(self.clients.values()):
            if client.holder == holder:
                asyncio.ensure_future(client.ws.close(code=1008, message=b"access revoked"))

    async def _sender(self, client: _Client) -> None:
        ws = client.ws
        try:
            while not ws.closed:
                await client.wake.wait()
                client.wake.clear()
                # asyncio.timeout, not wait_for: no task per frame (a send that needs no drain
                # completes in this step; wait_for's task cost a loop turn and a Task each time)
                while client.queue:
                    async with asyncio.timeout(self.bounds.send_timeout_s):
                        await ws.send_bytes(client.queue.popleft())
                if client.latest is not None:
                    data, client.latest = client.latest, None
                    async with asyncio.timeout(self.bounds.send_timeout_s):
                        await ws.send_bytes(data)
        except (asyncio.TimeoutError, TimeoutError):
            self._drop(client, f"its socket took no frame within {self.bounds.send_timeout_s:g} s")
        except (ConnectionError, RuntimeError):
            pass   # the page went away; the receive loop sees the close

    def _drop(self, client: _Client, why: str) -> None:
        """Close a page that does not keep up with what is sent to it (counted); it may reconnect."""
        if client.dropped:
            return
        client.dropped = True
        self.send_overflow += 1
        log.warning("closed the page at %s: %s (it may reconnect)", client.peer, why)
        client.queue.clear()
        if client.transport is not None:
            client.transport.abort()

    def _enqueue(self, conn: int, data: bytes, latest: bool, direct: bool = False) -> None:
        client = self.clients.get(conn)
        if client is None or not (direct or client.ready):
            return
        client.ready = True
        if latest:
            client.latest = data
        elif len(client.queue) >= self.bounds.max_queued:
            self._drop(client, f"{self.bounds.max_queued} frames were waiting for it")
            return
        else:
            client.queue.append(data)
        client.wake.set()

    def _enqueue_all(self, data: bytes, latest: bool) -> None:
        for conn in list(self.clients):
            self._enqueue(conn, data, latest)

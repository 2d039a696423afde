"""The page's server: aiohttp on an asyncio loop in a thread of its own, serving the page and its
files from the package and one WebSocket per open page.

It holds no touch4d state: what pages send goes to `on_message(conn, data, arrival)` (data: the
text, the bytes, or the WebSocket error that closed the connection, e.g. a message over 1 MiB; with
`on_connect(conn)` / `on_close(conn)`), called on the server's thread (the node hands them to its
own); what the node sends goes out through `send` and `broadcast`, safe from any thread. Per page,
frames marked `latest` replace one not yet sent (a slow Wi-Fi link gets the newest state, never a
backlog); the others (setup, geometry) are sent in order, never dropped. A new page hears broadcasts
only after the node's first frame to it (its setup): no page sees a frame before its setup.
"""
from __future__ import annotations

import asyncio
import collections
import itertools
import logging
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Callable
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from .access import token_matches

log = logging.getLogger(__name__)

STATIC_DIR = Path(str(resources.files("touch4d.web") / "static"))
WS_MAX_MESSAGE = 1 << 20     # larger WebSocket messages close the connection (the page reconnects)
WS_HEARTBEAT_S = 2.0         # a page that answers no ping within this is closed (it does not read)
MAX_PAGES = 64               # pages connected at once: one more is refused (HTTP 503)
REFUSED = ("touch4d: this page needs the token that the webxr node printed (its URL or QR code in "
           "the terminal where touch4d runs).\n")


class _Client:
    """One page's WebSocket and what waits to be sent to it."""

    def __init__(self, ws: web.WebSocketResponse, peer: str = ""):
        self.ws = ws
        self.peer = peer     # the page's address (host:port), to name it in the log
        self.queue: collections.deque = collections.deque()
        self.latest: bytes | None = None
        self.wake = asyncio.Event()
        self.ready = False   # set by the node's first frame to this page: broadcasts reach it after


class PageServer:
    """HTTP + WebSocket server for the WebXR page, running until `stop()`."""

    def __init__(self, host: str, port: int, token: str | None, ssl_context=None, max_pages: int = MAX_PAGES,
                 on_connect: Callable[[int], None] = lambda conn: None,
                 on_message: Callable[[int, object, float], None] = lambda conn, data, arrival: None,
                 on_close: Callable[[int], None] = lambda conn: None, static_dir: Path = STATIC_DIR):
        self.host, self.port, self.token, self.ssl_context = host, port, token, ssl_context
        self.on_connect, self.on_message, self.on_close = on_connect, on_message, on_close
        self.static_dir = Path(static_dir)
        self.refused = 0
        self.max_pages = max_pages
        self.over_limit = 0      # connections refused because max_pages pages were connected
        self.clients: dict[int, _Client] = {}
        self._ids = itertools.count(1)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._runner: web.AppRunner | None = None
        self._started = threading.Event()
        self._error: BaseException | None = None

    # ---- lifecycle (any thread) ------------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> int:
        """Bind and serve; returns the port (useful with port 0). Raises OSError if it cannot bind."""
        self._thread = threading.Thread(target=self._run, name="webxr-server", daemon=True)
        self._thread.start()
        if not self._started.wait(timeout):
            raise TimeoutError("the page server did not start")
        if self._error is not None:
            raise self._error
        return self.port

    def stop(self, timeout: float = 3.0) -> None:
        loop = self._loop
        if loop is None or self._thread is None:
            return
        try:
            asyncio.run_coroutine_threadsafe(self._shutdown(), loop).result(timeout)
        except Exception as exc:  # noqa: BLE001 - stopping must finish whatever the loop says
            log.debug("page server shutdown: %s", exc)
        loop.call_soon_threadsafe(loop.stop)
        self._thread.join(timeout)

    def send(self, conn: int, data: bytes) -> None:
        """Queue a frame for one page (in order, never dropped)."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._enqueue, conn, data, False, True)

    def peer(self, conn: int) -> str:
        """The address (host:port) of a connected page; '' once it has gone."""
        client = self.clients.get(conn)
        return client.peer if client is not None else ""

    def broadcast(self, data: bytes, latest: bool = False) -> None:
        """Queue a frame for every page; `latest` frames replace an unsent one."""
        if self._loop is not None:
            self._loop.call_soon_threadsafe(self._enqueue_all, data, latest)

    # ---- the server's thread ---------------------------------------------------------------------

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
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
        app = web.Application(middlewares=[self._headers])
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_static("/static/", self.static_dir, follow_symlinks=False)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, ssl_context=self.ssl_context)
        await site.start()
        self.port = self._runner.addresses[0][1]

    async def _shutdown(self) -> None:
        for client in list(self.clients.values()):
            await client.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    @web.middleware
    async def _headers(self, request: web.Request, handler):
        response = await handler(request)
        # The page may talk to this server only: no other host, no inline script, no framing.
        response.headers["Content-Security-Policy"] = (
            "default-src 'self'; connect-src 'self' ws: wss:; img-src 'self' data:; frame-ancestors 'none'")
        response.headers["Referrer-Policy"] = "no-referrer"   # the token stays out of Referer headers
        response.headers["Cache-Control"] = "no-store"
        response.headers["X-Content-Type-Options"] = "nosniff"
        return response

    def _allowed(self, request: web.Request) -> bool:
        if self.token and not token_matches(request.query.get("token"), self.token):
            self.refused += 1
            return False
        return True

    async def _index(self, request: web.Request) -> web.StreamResponse:
        if not self._allowed(request):
            return web.Response(status=403, text=REFUSED)
        return web.FileResponse(self.static_dir / "index.html")

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        if not self._allowed(request):
            return web.Response(status=403, text=REFUSED)
        # A page from another site must not drive the hand through this browser (cross-site
        # WebSocket hijacking): a browser always sends Origin, and it must be this server.
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.host:
            self.refused += 1
            return web.Response(status=403, text="touch4d: WebSocket from another origin refused\n")
        if len(self.clients) >= self.max_pages:
            # Each page costs a setup frame and a send queue: a flood of connections must not take
            # the node's memory or its thread. A page that does not read is closed by the heartbeat.
            self.over_limit += 1
            return web.Response(status=503, text=f"touch4d: {self.max_pages} pages are connected already "
                                                 "(the webxr node's max_pages); close one and reload\n")
        ws = web.WebSocketResponse(max_msg_size=WS_MAX_MESSAGE, compress=False, heartbeat=WS_HEARTBEAT_S)
        await ws.prepare(request)
        conn = next(self._ids)
        transport_peer = request.transport.get_extra_info("peername") if request.transport else None
        peer = f"{transport_peer[0]}:{transport_peer[1]}" if transport_peer else (request.remote or "?")
        client = self.clients[conn] = _Client(ws, peer)
        sender = asyncio.ensure_future(self._sender(client))
        self.on_connect(conn)
        try:
            async for msg in ws:
                arrival = time.time()
                if msg.type == WSMsgType.TEXT:
                    self.on_message(conn, msg.data, arrival)
                elif msg.type == WSMsgType.BINARY:
                    self.on_message(conn, bytes(msg.data), arrival)
                elif msg.type == WSMsgType.ERROR:
                    self.on_message(conn, msg.data, arrival)   # the error, counted; the socket closes
                    break
        finally:
            self.clients.pop(conn, None)
            sender.cancel()
            self.on_close(conn)
        return ws

    async def _sender(self, client: _Client) -> None:
        ws = client.ws
        try:
            while not ws.closed:
                await client.wake.wait()
                client.wake.clear()
                while client.queue:
                    await ws.send_bytes(client.queue.popleft())
                if client.latest is not None:
                    data, client.latest = client.latest, None
                    await ws.send_bytes(data)
        except (ConnectionError, RuntimeError):
            pass   # the page went away; the receive loop sees the close

    def _enqueue(self, conn: int, data: bytes, latest: bool, direct: bool = False) -> None:
        client = self.clients.get(conn)
        if client is None or not (direct or client.ready):
            return
        client.ready = True
        if latest:
            client.latest = data
        else:
            client.queue.append(data)
        client.wake.set()

    def _enqueue_all(self, data: bytes, latest: bool) -> None:
        for conn in self.clients:
            self._enqueue(conn, data, latest)

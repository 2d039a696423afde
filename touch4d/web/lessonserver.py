"""`touch4d lesson serve`: the lesson (touch4d.web.lesson) on the page server (touch4d.web.server,
with its bounds: touch4d.web.hardening, one origin, max pages, each page's paced inbox), on one
asyncio loop.

Links (touch4d.web.invites, DIR/invites.json, its owner's alone): the teacher's, the class's, and the
terminal's (`touch4d lesson command`, on this machine). Opening the class link makes a student of the
browser: a holder of its own (touch4d.web.access: its cookie, revocable alone), then the lesson page.
Each link's page loads and WebSockets are paced by a TokenBucket of its own (a flood through one link
slows no other: HTTP 429). A link replaced in the file (`touch4d lesson revoke`) ends its pages within
a second, a class link's students with it. DIR/lesson.json says where the lesson is served;
DIR/lesson.mcap records it (the command's recording: `touch4d replay` plays it).
"""
from __future__ import annotations

import asyncio
import itertools
import json
import logging
import os
import signal
import stat
import time
from dataclasses import dataclass
from typing import Callable
from pathlib import Path
from urllib.parse import quote, urlsplit

from aiohttp import web

from touch4d.configfile import COMMAND_LINE
from touch4d.errors import ConfigError
from touch4d.eventloop import new_event_loop
from touch4d.geometry.scene import Scene
from touch4d.tactile.glove import Glove
from touch4d.tracking.calibration import Calibration, Placement

from .access import HOLDER, Access, cross_site, is_loopback, lan_addresses
from .hardening import ESCAPED, host_name
from .inbox import TokenBucket
from .invites import Invites
from .lesson import CLASS, HEARTBEAT_S, TEACHER, TERMINAL, Lesson
from .server import PageBounds, PageServer

log = logging.getLogger(__name__)
log.addFilter(ESCAPED)

SERVED = "lesson.json"          # DIR/lesson.json: where the lesson is served (for `touch4d lesson command`)
RECORDING = "lesson.mcap"
PAGE = "lesson.html"            # the lesson's page (static/lesson.html: the WebXR page and static/lesson.js)
MAX_STUDENTS = 30
# each link's page loads and WebSocket connections: a class arrives at once, a reload now and then
LINK_RATE = {TEACHER: (2.0, 20), CLASS: (5.0, 90), TERMINAL: (20.0, 40)}
STUDENT = "s"                    # a student's holder: s1, s2, ... (made when the class link is opened)
INPUT_HZ = 30.0                  # each page's inputs handed to the lesson at most this often (the driver's too)


@dataclass(frozen=True)
class LessonOptions:
    host: str = "127.0.0.1"
    port: int = 0
    public_url: str | None = None
    max_students: int = MAX_STUDENTS


class LessonServer(PageServer):
    """The page server with the lesson's links: who a page is (teacher, student, terminal) decides
    what "/" serves and whether its WebSocket is taken (each link's budget, the class's size)."""

    def __init__(self, host: str, port: int, access: Access, max_students: int, *, ssl_context=None,
                 names=(), secure_cookie: bool = True, loop=None):
        bounds = PageBounds(max_pages=max_students + 8, input_hz=INPUT_HZ, secure_cookie=secure_cookie)
        super().__init__(host, port, access, ssl_context, bounds=bounds, names=names, loop=loop)
        self.max_students = max_students
        self.buckets = {link: TokenBucket(rate, burst) for link, (rate, burst) in LINK_RATE.items()}
        self.over_budget = 0
        self.full = 0
        self._students = itertools.count(1)

    @staticmethod
    def link_of(holder: str | None) -> str | None:
        return CLASS if holder is not None and holder.startswith(STUDENT) and holder[1:].isdigit() else holder

    def _spend(self, holder: str | None) -> None:
        bucket = self.buckets.get(self.link_of(holder))
        if bucket is not None and not bucket.spend(time.monotonic()):
            self.over_budget += 1
            raise web.HTTPTooManyRequests(text="touch4d: too many requests through this link; wait a second\n",
                                          headers={"Retry-After": "1"})

    def students(self) -> int:
        return sum(1 for c in self.clients.values() if self.link_of(c.holder) == CLASS)

    async def _index(self, request: web.Request) -> web.StreamResponse:
        holder = request.get(HOLDER)
        self._spend(holder)
        if holder == CLASS:
            # the class link makes a student: a holder (and cookie) of its own, then the lesson page
            student = f"{STUDENT}{next(self._students)}"
            token = self.access.issue(student)
            raise web.HTTPFound(f"/?token={token}")
        if holder == TERMINAL or holder is None:
            raise web.HTTPForbidden(text="touch4d: this link opens no page\n")
        return web.FileResponse(self.static_dir / PAGE)

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        holder = request.get(HOLDER)
        self._spend(holder)
        if holder == CLASS:
            raise web.HTTPForbidden(text="touch4d: open the class link in a browser first\n")
        if cross_site(request):        # refused as the page server refuses it, before the class's size says anything
            return await super()._websocket(request)
        if self.link_of(holder) == CLASS and self.students() >= self.max_students:
            self.full += 1
            return web.Response(status=503, text=f"touch4d: the class is full ({self.max_students} students)\n")
        return await super()._websocket(request)

    def send_latest(self, conn: int, data: bytes) -> None:
        """A frame for one page that replaces one not yet sent to it (the server's per-tick frames)."""
        self._on_loop(self._enqueue, conn, data, True, True)

    def close_students(self) -> None:
        """Every student's page closed, their access ended (the class link was replaced)."""
        for holder in {c.holder for c in self.clients.values() if self.link_of(c.holder) == CLASS}:
            self.access.revoke(holder)


def prepare_dir(out: Path) -> Path:
    """DIR made (mode 0700) or checked: it holds the links, writable by its owner alone."""
    out = Path(out)
    out.mkdir(mode=0o700, parents=True, exist_ok=True)
    mode = stat.S_IMODE(out.stat().st_mode)
    if mode & 0o022:
        raise ConfigError(out, "--out", f"a folder only its owner may write to (it holds the lesson's links: "
                          f"chmod go-w {out})", got=f"mode {mode:04o}")
    return out


def lesson_links(base: str, tokens: dict[str, str]) -> tuple[str, str]:
    """(teacher link, class link)."""
    return f"{base}/?token={quote(tokens[TEACHER])}", f"{base}/?token={quote(tokens[CLASS])}"


class LessonRun:
    """One served lesson: `run()` serves until SIGINT/SIGTERM (or `stop()`)."""

    def __init__(self, scene: Scene, glove: Glove, calibration: Calibration, placement: Placement, out: Path,
                 options: LessonOptions = LessonOptions(), recording: Callable[[Path], object] | None = None):
        """`recording(path)`: the lesson's log, a `record(topic, msg)` callable with a `close()`
        (touch4d.log's, which this layer does not import), or None."""
        self.options = options
        self.make_recording = recording
        self.out = prepare_dir(out)
        self.invites = Invites(self.out)
        for holder in (TEACHER, CLASS, TERMINAL):
            self.invites.issue(holder, keep=True)
        self.tokens: dict[str, str] = {}
        self._signature = None
        self.access = Access()
        self.scene, self.glove, self.calibration, self.placement = scene, glove, calibration, placement
        self._stopping: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def _follow_invites(self) -> None:
        """Adopt DIR/invites.json: a link replaced or removed there ends its holder's access (and the
        class link's students)."""
        signature = self.invites.signature()
        if signature == self._signature:
            return
        self._signature = signature
        try:
            tokens = self.invites.load()
        except ValueError as exc:
            log.warning("%s; keeping the links read before", exc)
            return
        for holder in (TEACHER, CLASS, TERMINAL):
            token = tokens.get(holder)
            if token == self.tokens.get(holder):
                continue
            if holder in self.tokens:
                self.access.revoke(holder)
                if holder == CLASS:
                    self.server.close_students()
                print(f"lesson: the {holder} link was {'replaced' if token else 'revoked'}", flush=True)
            if token:
                self.access.issue(holder, token=token)
        self.tokens = {h: t for h, t in tokens.items() if h in (TEACHER, CLASS, TERMINAL)}

    def base_url(self, port: int) -> str:
        if self.options.public_url:
            return self.options.public_url.rstrip("/")
        scheme = "https" if self.ssl_context is not None else "http"
        address = lan_addresses(self.options.host)[0] if not is_loopback(self.options.host) else self.options.host
        host = f"[{address}]" if ":" in address else address
        return f"{scheme}://{host}:{port}"

    def _ssl(self):
        """https beyond loopback (a headset grants WebXR only to a secure context), unless a proxy in
        front serves --public-url."""
        if is_loopback(self.options.host) or self.options.public_url:
            return None
        from .tls import ensure_certificate, server_ssl_context
        cert, key, self.fingerprint = ensure_certificate(self.out / "tls", lan_addresses(self.options.host))
        return server_ssl_context(cert, key)

    def run(self) -> int:
        os.umask(0o077)            # what it writes (the recording of the class's hands) is its owner's alone
        self.fingerprint = None
        self.ssl_context = self._ssl()
        loop = self._loop = new_event_loop(serves_tls=self.ssl_context is not None)
        public = self.options.public_url
        secure = (public or "").startswith("https://") or self.ssl_context is not None
        self.server = LessonServer(self.options.host, self.options.port, self.access, self.options.max_students,
                                   ssl_context=self.ssl_context, names=[host_name(public)] if public else [],
                                   secure_cookie=secure, loop=loop)
        self.recording = self.make_recording(self.out / RECORDING) if self.make_recording else None
        self.lesson = Lesson(self.scene, self.glove, self.calibration, self.placement, self.server.send,
                             self.server.send_latest, self.recording, revoke=self.access.revoke)
        self.server.on_connect = lambda conn: self.lesson.connected(conn, self.server.holder(conn),
                                                                    self.server.peer(conn))
        self.server.on_message = self.lesson.message
        self.server.on_close = self.lesson.closed
        self._follow_invites()
        self.lesson.warm()
        try:
            try:
                port = self.server.start()
            except OSError as exc:
                raise ConfigError(COMMAND_LINE, "--port", f"a port free to listen on at {self.options.host}",
                                  got=self.options.port, detail=exc.strerror) from None
            loop.run_until_complete(self._serve(port))
        finally:
            self.server.stop()
            if self.recording is not None:
                self.recording.close()
            loop.close()
        return 0

    async def _serve(self, port: int) -> None:
        self._stopping = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._loop.add_signal_handler(sig, self._stopping.set)
        base = self.base_url(port)
        local = f"{'https' if self.ssl_context else 'http'}://127.0.0.1:{port}" if not ":" in self.options.host \
            else f"{'https' if self.ssl_context else 'http'}://[::1]:{port}"
        served = {"url": base, "local": local, "pid": os.getpid()}
        (self.out / SERVED).write_text(json.dumps(served) + "\n")
        teacher, klass = lesson_links(base, self.tokens)
        print(f"lesson: serving {base}/ for up to {self.options.max_students} students; recording in "
              f"{self.out / RECORDING if self.recording else 'nothing'}", flush=True)
        if self.fingerprint:
            print(f"its certificate (self-signed; compare in the browser before accepting): SHA-256 "
                  f"{self.fingerprint}", flush=True)
        print(f"teacher link: {teacher}", flush=True)
        print(f"class link: {klass}", flush=True)
        ticks = 0
        while not self._stopping.is_set():
            try:
                await asyncio.wait_for(self._stopping.wait(), HEARTBEAT_S)
            except (asyncio.TimeoutError, TimeoutError):
                pass
            self.lesson.heartbeat()
            ticks += 1
            if ticks % 10 == 0:
                self._follow_invites()
        print("lesson: stopped", flush=True)

    def stop(self) -> None:
        if self._loop is not None and self._stopping is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)


# ---- the terminal's side ---------------------------------------------------------------------------


def served(out: Path) -> dict:
    """DIR/lesson.json, or ConfigError saying to serve the lesson first."""
    path = Path(out) / SERVED
    try:
        data = json.loads(path.read_text())
        if not isinstance(data.get("local"), str):
            raise ValueError
        return data
    except (OSError, ValueError, AttributeError):
        raise ConfigError(path, "local", "the address of a lesson served from this folder (touch4d lesson serve "
                          f"SCENE --out {out})", got="no such file" if not path.exists() else "unreadable") from None


async def send_command(out: Path, verb: str, argument: str, timeout_s: float = 10.0) -> tuple[bool, str]:
    """A command to the lesson served from `out`, through its WebSocket with the terminal's link:
    (carried out, what the lesson answered)."""
    import aiohttp

    from .protocol import frame_header

    where = served(out)
    token = Invites(out).load().get(TERMINAL)
    if token is None:
        raise ConfigError(Path(out) / "invites.json", TERMINAL, "the terminal's link (made by touch4d lesson serve)")
    url = where["local"].replace("http", "ws", 1) + f"/ws?token={quote(token)}"
    async with aiohttp.ClientSession() as session:
        try:
            async with asyncio.timeout(timeout_s), session.ws_connect(url, ssl=False) as ws:
                await ws.send_str(json.dumps({"type": "command", "verb": verb, "argument": argument}))
                async for msg in ws:
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        header = frame_header(msg.data)
                        if header.get("kind") == "result":
                            return bool(header["ok"]), str(header["text"])
                    elif msg.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                        break
        except (aiohttp.ClientError, OSError, TimeoutError) as exc:
            raise ConfigError(Path(out) / SERVED, "local", f"a lesson that answers at {urlsplit(where['local']).netloc}",
                              got=str(exc) or type(exc).__name__) from None
    return False, "the lesson closed the connection without an answer"

"""The study server (`touch4d study serve`): participants join a study from their own headset's
browser by a link, many at once, each in a namespace of their own on one bus.

A link is `URL/?participant=P07&token=...` (`invites.Invites`, kept in OUT/invites.json). Opening
it shows the study's consent and instructions (and takes the token out of the address bar: the
cookie carries on); Join starts that participant's stack
(launch/study-serve.yaml under the namespace P07: the WebXR page's node, scene, tactile, study,
recorder, writing OUT/P07/ as `touch4d study run` does) and the page comes through this server:
every request and the WebSocket of the participant's cookie go to their node on loopback, so the
page is today's page and the second page on a link is refused by today's rule. When the last page
of a participant closes, their trial pauses (`study/command` pause); the page back within
`leave_after_s` resumes it, else the stack stops and the link's next opening starts it again,
resuming at the first trial without a row (a server killed and started again on the same OUT
resumes everyone the same way; a join whose page never connects stops so too, after `page_grace_s` at
least). More running participants than `max_participants` (by default as many as this machine's
cores keep within the touch's latency budget, `default_max_participants`): a page that says so, HTTP 503. A forged, expired or revoked token: 403 (access.CookieGate), logged once; a link
revoked or replaced in OUT/invites.json ends its cookies and stops its stack. A
participant id in the link that is not its token's: 403. The experimenter's link opens
/experimenter: every participant's state, trial, last message heard; pause or resume their
trial, or revoke a link.
"""
from __future__ import annotations

import asyncio
import ctypes
import errno
import html
import json
import logging
import os
import secrets
import signal
import stat
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable
from urllib.parse import quote

import aiohttp
import msgspec
from aiohttp import web

from touch4d.atomic import write_atomic
from touch4d.bus import Broker, BusConfig, Node
from touch4d.bus.heap import freeze_startup_heap
from touch4d.bus.launchfile import group_entries, load_launch, processes
from touch4d.bus.logfiles import open_log
from touch4d.bus.pool import ContainerPool
from touch4d.bus.realtime import LOOP_PRIORITY, NOT_PERMITTED, raise_loop_priority
from touch4d.configfile import COMMAND_LINE
from touch4d.errors import ConfigError, Touch4dError
from touch4d.eventloop import new_event_loop
from touch4d.messages import StudyCommand, StudyTrial, decode
from touch4d.study.design import Study
from touch4d.study.lock import SERVE, SessionLock
from touch4d.study.participation import PAUSE, Life, State
from touch4d.study.plan import plan_session, quick_plan
from touch4d.study.session import session_dir, session_overrides
from touch4d.study.store import PARTICIPANT_ID, rows_written

from .access import HOLDER, Access, CookieGate, cross_site
from .inbox import TokenBucket
from .hardening import ESCAPED, SECURITY_HEADERS, Hardening, host_name
from .invites import EXPERIMENTER, Invites, check_participant
from .server import SECRET_HEADER, STATIC_DIR, static_names
from .splice import Splice
from .wiretrace import WireTrace

log = logging.getLogger("study-serve")
log.addFilter(ESCAPED)   # a request path in a line: its control and bidi characters escaped

LAUNCH = "launch/study-serve.yaml"
SERVED = "serve.json"             # OUT/serve.json: the address served, for `touch4d study invite`
PAGE_GRACE_S = 60.0           # after a join, its page connects within this (or leave_after_s if longer)
PER_PROCESS = 8               # participants' stacks per process at most (a container: docs/bus.md)
CONTAINERS = "containers"     # OUT/containers/NAME.log: each container's output
READY_TIMEOUT_S = 90.0        # a participant's stack starts within this (a loaded machine: tens of seconds)
PAGE_ROLE = "tracker"         # the node of a participant's stack that serves its page (launch/study-serve.yaml)
# Participants at once by default: as many as keep pose -> pulse within the touch's budget (p99 <= 15
# ms, server-side) at 72 Hz each, with room to spare (a session's study node and trials come on
# top). bench/bench_serve.py on a quiet 2-core machine, recorder included: p99 3.7-4.8 ms at 8
# participants (4.6 through 50 ms of round trip), 8-14 ms at 12, 13-48 ms at 16 (each costs about
# an eighth of a core; 16 fill the two cores): more would slow everyone's touch.
PARTICIPANTS_PER_CORE = 4
ACTIONS = ("pause", "resume", "revoke")   # the experimenter's buttons on each participant's row
HANDSHAKE_HEADERS = ("Sec-WebSocket-Key", "Sec-WebSocket-Version", "Sec-WebSocket-Protocol")
UPSTREAM_TIMEOUT_S = 10.0     # a participant's page server answers a WebSocket upgrade within this, else 502
# The experimenter's pages: participants' states, never cached; their address (once with the token) sent nowhere.
NO_STORE = {"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"}
HOLDER_RATE = 20.0            # requests per second and link, on average (a page's load is ~15 files once)
HOLDER_BURST = 60             # and at most this many at once
PROXIED_HEADERS = ("Content-Security-Policy", "Referrer-Policy", "Cache-Control", "X-Content-Type-Options")
# The page server's headers on every answer, but forms post here (join, the experimenter's); scripts
# are this server's files only (the welcome page's, the experimenter page's: no inline script).
STUDY_HEADERS = {**SECURITY_HEADERS, "Content-Security-Policy": (
    SECURITY_HEADERS["Content-Security-Policy"].replace("form-action 'none'", "form-action 'self'")
    + "; script-src 'self'")}
MAX_DEVICE_BODY = 1024        # the welcome page's device report: two booleans
# What a participant whose browser cannot vibrate reads before consent (and why).
NO_VIBRATION = ("This browser cannot vibrate: no VR headset (WebXR) and no gamepad with rumble were found. "
                "This study's touch is felt as vibration. With a gamepad, press one of its buttons, then reload.")
NO_VIBRATION_REFUSED = NO_VIBRATION + " Please join from a VR headset's browser (a Quest) or with a gamepad."
NO_VIBRATION_ALLOWED = NO_VIBRATION + " You may take part: in the trials with touch you will feel nothing."
STATIC_NAMES = static_names(STATIC_DIR)   # /static/ names forwarded to a participant's page: its files only


def _cores() -> int:
    """The cores this process may run on (its CPU affinity)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_max_participants() -> int:
    """Participants at once when the experimenter does not say: PARTICIPANTS_PER_CORE per core this
    process may run on, at least 2."""
    return max(2, PARTICIPANTS_PER_CORE * _cores())


def _upgrade_request(request: web.Request, port: int, secret: str | None = None) -> bytes | None:
    """The WebSocket upgrade sent to a participant's page server: its own Host and Origin (the study
    server checked the browser's), and of the browser's headers only the WebSocket handshake's (no
    cookie, no compression offered). None when the request is not a WebSocket upgrade."""
    if request.headers.get("Upgrade", "").lower() != "websocket":
        return None
    lines = ["GET /ws HTTP/1.1", f"Host: 127.0.0.1:{port}", f"Origin: http://127.0.0.1:{port}",
             "Upgrade: websocket", "Connection: Upgrade", *([f"{SECRET_HEADER}: {secret}"] if secret else [])]
    for name in HANDSHAKE_HEADERS:
        value = request.headers.get(name)
        if value is not None:
            if not (value.isascii() and value.isprintable()):   # no header of the browser's own smuggled in
                return None
            lines.append(f"{name}: {value}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def _heard(p: Participant, feed: Callable[[bytes], None] | None) -> Callable[[bytes], None]:
    """Called with each chunk the page sends: when it was last heard (and the wire trace's feed)."""
    if feed is None:
        def heard(data: bytes) -> None:
            p.last_heard = time.time()
    else:
        def heard(data: bytes) -> None:
            p.last_heard = time.time()
            feed(data)
    return heard


def _page_port(ready: str) -> int | None:
    """The page server's port in a container's ready file (`ready {"tracker": {"page": PORT}}`), or None."""
    if not ready.startswith("ready"):
        return None
    try:
        port = json.loads(ready[len("ready"):].strip() or "{}").get(PAGE_ROLE, {}).get("page")
    except (ValueError, AttributeError):
        return None
    return port if isinstance(port, int) and 0 < port < 65536 else None


def _die_with_server() -> None:
    """In a participant's launch process: SIGTERM when the server dies (it then stops its nodes)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except OSError:
        pass


@dataclass
class Participant:
    """One participant's stack and what the experimenter page shows of it."""

    id: str
    life: Life = field(default_factory=Life)   # invited, starting, running (paused by whom), left, done, revoked
    port: int = 0                      # its page server's, on loopback (as its container's ready file said)
    pages: int = 0                     # its pages connected now
    last_heard: float = 0.0            # wall clock of the last bytes its page sent
    trial: StudyTrial | None = None    # its study node's latest state
    leave: asyncio.TimerHandle | None = field(default=None, repr=False)
    # what its page server wants with every request (its page node, on loopback, is every local user's to reach)
    secret: str = field(default_factory=lambda: secrets.token_urlsafe(16), repr=False)
    starting: asyncio.Future | None = field(default=None, repr=False)   # a join waiting for its stack
    vibration: str | None = None       # what its welcome page found: headset, gamepad, none (None: not told)


class ServeOptions(msgspec.Struct, kw_only=True, frozen=True):
    """How a study is served (`touch4d study serve`'s flags), declared once."""

    host: str = "127.0.0.1"
    port: int = 8095                         # 0: any free one
    max_participants: int | None = None      # None: default_max_participants()
    public_url: str | None = None            # a reverse proxy's address (https: Secure cookies)
    leave_after_s: float = 30.0              # a participant without a page this long has left
    quick: bool = False                      # one repetition per task x condition cell, no practice
    secure: bool | None = None               # Secure cookies (None: from public_url's scheme)
    overrides: tuple[str, ...] = ()          # each stack's launch overrides
    page_grace_s: float = PAGE_GRACE_S       # after a join, its page connects within this
    wire_trace: Path | None = None           # a CSV of when each page input arrives and each frame leaves
    launch: str = LAUNCH                     # each participant's stack
    per_process: int = PER_PROCESS           # participants' stacks per container process


class StudyServer:
    """The server; `run()` serves until SIGINT/SIGTERM (or `stop()`)."""

    def __init__(self, study: Study, study_path: Path, out: Path, options: ServeOptions | None = None):
        o = ServeOptions() if options is None else options
        self.options = o
        self.study, self.study_path, self.out = study, Path(study_path), Path(out)
        self.host, self.port = o.host, o.port
        self.max_participants = default_max_participants() if o.max_participants is None else o.max_participants
        self._cap_note = (f" ({PARTICIPANTS_PER_CORE} per core here; --max-participants N to change)"
                          if o.max_participants is None else "")
        self.public_url = o.public_url
        self.leave_after_s, self.quick, self.overrides = o.leave_after_s, o.quick, list(o.overrides)
        self.page_grace_s = o.page_grace_s
        self.wire_trace = o.wire_trace
        self.launch = o.launch   # each participant's stack
        self.per_process = o.per_process   # participants' stacks per process (touch4d.bus.container)
        self.pool: ContainerPool | None = None   # made at the first join
        self.tmp: Path | None = None             # the ready files' folder, while it serves
        self._trace: WireTrace | None = None
        self._splices: set[Splice] = set()     # the pages' WebSockets, spliced to their page servers
        # Cookies marked Secure when participants come over https (a reverse proxy's certificate):
        # this server speaks plain http, on loopback or behind that proxy.
        self.secure = (o.public_url or "").startswith("https://") if o.secure is None else o.secure
        self.invites = Invites(self.out)
        self.access = Access()
        self.gate = CookieGate(self.access, secure=self.secure, cookie="touch4d-study")
        # the internet's bounds, as the page server's (touch4d.web.hardening); the public name served too
        self.hardening = Hardening(o.host, [host_name(o.public_url)] if o.public_url else [], headers=STUDY_HEADERS,
                                   log=log)
        self.participants: dict[str, Participant] = {}
        self.counts = {"full": 0, "forged": 0, "mismatched": 0, "joined": 0, "resumed": 0, "left": 0,
                       "over budget": 0, "no vibration": 0}
        self._logged: set[str] = set()
        self._plan_lengths: dict[str, int] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._tokens: dict[str, str] | None = None    # OUT/invites.json as last adopted
        self._invites_signature: tuple | None = None   # and its file's (Invites.signature) then
        self._budgets: dict[str, TokenBucket] = {}   # each holder's requests (a flood of one slows no one else)
        self.experimenter_token: str | None = None   # issued when it serves (run), not before
        self.node: Node | None = None     # the server's own on the bus (_start_bus)
        self._socket: socket.socket | None = None   # bound by run() before OUT is written
        self._load_invites()

    # ---- links ---------------------------------------------------------------------------------

    def base_url(self) -> str:
        if self.public_url:
            return self.public_url.rstrip("/")
        return f"http://{self.host}:{self.port}"

    def _load_invites(self) -> None:
        """Adopt OUT/invites.json (written by `touch4d study invite` too, while this runs): a link
        revoked or replaced there ends its holder's cookies and stops its stack. A file that cannot be read as
        links keeps the links adopted before (logged once)."""
        signature = self.invites.signature()
        if self._tokens is not None and signature == self._invites_signature:
            return     # unchanged since read (every request asks: one stat, not a parse)
        self._invites_signature = signature
        try:
            tokens = self.invites.load()
        except ValueError as exc:
            self._log_once("invites", f"{exc}; keeping the links read before")
            return
        if tokens == self._tokens:
            return
        before, self._tokens = self._tokens or {}, tokens
        # A link revoked, or replaced by a new one (a leaked link is cut off with what it opened).
        ended = set(self.access.holders()) - set(tokens)
        ended |= {h for h, token in tokens.items() if before.get(h, token) != token}
        for holder in ended:
            self.access.revoke(holder)
            p = self.participants.get(holder)
            if p is not None:
                if self._running(p):
                    self._say(f"{holder}: link {'replaced' if holder in tokens else 'revoked'}; its stack stops")
                    self._stop_stack(p)
                if holder not in tokens:
                    p.life.revoke()
            elif holder == EXPERIMENTER and holder in tokens:
                self._say("the experimenter's link was replaced: the old one and its browsers are refused")
        for holder, token in tokens.items():
            if self.access.check(token) != holder:
                self.access.issue(holder, token=token)
            if holder == EXPERIMENTER:
                self.experimenter_token = token
            elif holder not in self.participants:
                self._add_participant(holder)
            else:
                self.participants[holder].life.invited(self._rows(holder), self._planned(holder))

    def _add_participant(self, holder: str) -> "Participant":
        """A participant the server learns of (a link, or a folder of data): its life as its data say."""
        life = Life.from_data(self._rows(holder), self._planned(holder), invited=holder in (self._tokens or {}))
        p = self.participants[holder] = Participant(holder, life=life)
        if self.node is not None:   # else _start_bus follows it
            self.node.call_soon_threadsafe(self._follow, holder)
        return p

    def _follow(self, holder: str) -> None:
        """Hear `holder`'s study/trial (the node's thread). Only that topic: every other message of
        every stack (poses, fields, frames at 72 Hz) would cost this process a receive for nothing."""
        self.node.create_raw_subscription(f"/{holder}/study/trial", self._on_bus)

    # ---- the bus -------------------------------------------------------------------------------

    def _start_bus(self, tmp: Path) -> None:
        self.broker = Broker(BusConfig(bind_host="127.0.0.1", connect_host="127.0.0.1", pub_port=0, sub_port=0,
                                       source="<study server>"))
        bus = self.broker.start()
        self.bus_file = tmp / "bus.yaml"
        self.bus_file.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {bus.pub_port}, sub_port: {bus.sub_port}}}\n"
                                 "connect: 127.0.0.1\n")
        self.node = Node("study-serve", bus=bus.for_clients())
        for holder in list(self.participants):
            self._follow(holder)
        self._commands: dict[str, object] = {}
        def spin():
            try:
                self.node.spin()
            finally:
                self.node.shutdown()
        self._bus_thread = threading.Thread(target=spin, name="study-serve-bus", daemon=True)
        self._bus_thread.start()

    def _on_bus(self, topic: str, payload: bytes) -> None:
        """A participant's study/trial (the node's thread): the experimenter page's state."""
        ns, _, name = topic.partition("/")
        if name != "study/trial" or ns not in self.participants:
            return
        p = self.participants[ns]
        try:
            p.trial = decode(payload, StudyTrial)
        except Exception:  # noqa: BLE001 - a malformed message is not the experimenter page's to show
            return
        if p.trial.phase == "done" and p.life.state is State.RUNNING and self._loop is not None:
            self._loop.call_soon_threadsafe(self._finished, p)

    def _finished(self, p: Participant) -> None:
        if p.life.state is State.RUNNING:
            p.life.finished()
            self._say(f"{p.id} is done: every trial has its row")

    def _tell(self, p: Participant, command: str | None, reason: str) -> None:
        """Send its study node the command a life event returned (None: nothing to send)."""
        if command is not None:
            self.command(p.id, command, reason)

    def command(self, participant: str, command: str, reason: str) -> None:
        """Send `study/command` to a participant's study node (from any thread)."""
        def send():
            pub = self._commands.get(participant)
            if pub is None:
                pub = self._commands[participant] = self.node.create_publisher(f"/{participant}/study/command",
                                                                                StudyCommand)
            pub.publish(StudyCommand(command=command, reason=reason))
        self.node.call_soon_threadsafe(send)

    # ---- participants' stacks ------------------------------------------------------------------

    def _start_stack(self, p: Participant) -> bool:
        """Place the participant's stack in a container (touch4d.bus.container); False when its
        launch cannot be made (said in its serve.log)."""
        p.port = 0     # its page server binds any free port and its container's ready file says which
        if self.pool is None:
            self.pool = ContainerPool(self.per_process, self.bus_file, self.out / CONTAINERS, spread=_cores(),
                                      prefix="participants",
                                      popen={"start_new_session": True, "preexec_fn": _die_with_server})
        self.pool.unload(p.id)   # a stack that said it failed is still placed: out first
        try:
            self.pool.load(p.id, lambda: self._stack_command(p))
        except Touch4dError as exc:   # its launch cannot be made (the file changed since the start)
            session_dir(self.out, p.id).mkdir(parents=True, exist_ok=True)
            with open_log(session_dir(self.out, p.id) / "serve.log") as f:
                f.write(f"{p.id}: {exc}\n")
            return False
        return True

    def _stack_command(self, p: Participant) -> dict:
        """The participant's group as its container loads it: launch/study-serve.yaml under its namespace,
        its session's overrides (the recorder's next segment: made anew at each load)."""
        group = self.stack_group(p.id, self._secret_file(p))
        directory = session_dir(self.out, p.id)
        directory.mkdir(parents=True, exist_ok=True)
        self._ready_file(p).unlink(missing_ok=True)
        return {"namespace": p.id, "nodes": group_entries(group), "ready_file": str(self._ready_file(p)),
                "log": str(directory / "serve.log")}

    def _secret_file(self, p: Participant) -> Path:
        """Its page server's secret, in the server's private folder (the node reads it; a command line
        or a log would show it)."""
        path = self.tmp / f"{p.id}.secret"
        write_atomic(path, p.secret, mode=0o600)
        return path

    def _ready_file(self, p: Participant) -> Path:
        """Where its container writes "ready" (or "failed: ...") at each load."""
        return self.tmp / f"{p.id}.ready"

    def stack_group(self, participant: str, secret_file: Path | None = None) -> list:
        """A participant's stack: the launch file's one group (its NodeSpecs) under their namespace,
        its page served on a port the page server picks (a port picked here and bound there later
        could be taken meanwhile: any connection's own end may get it). Raises ConfigError when the
        launch cannot be made or is not one group (checked at start too)."""
        overrides = [*session_overrides(self.study_path, participant, self.out, quick=self.quick),
                     f"{PAGE_ROLE}.port:=0",
                     *([f"{PAGE_ROLE}.secret_file:={json.dumps(str(secret_file))}"] if secret_file else []),
                     *self.overrides]
        specs = processes(load_launch(self.launch, overrides, namespace=participant))
        (group, *more) = specs.values()
        if more or not group[0].group:
            raise ConfigError(self.launch, "nodes", "every node in one `group` (a participant's stack is one "
                              "group in a container)", got=", ".join(specs))
        return group

    async def _wait_ready(self, p: Participant) -> bool:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if not self._running(p):
                return False
            try:
                said = self._ready_file(p).read_text()
            except OSError:
                said = ""
            if said.startswith("failed"):
                return False
            if said.startswith("ready"):
                port = _page_port(said)
                if port is None:
                    log.error("%s: its stack started but names no page port (its ready file says %r; expected "
                              "the launch's %s node's, as ready {\"%s\": {\"page\": PORT}})",
                              p.id, said.strip(), PAGE_ROLE, PAGE_ROLE)
                    return False
                p.port = port
                try:   # and its page is served
                    async with self.client.get(f"http://127.0.0.1:{p.port}/", headers={SECRET_HEADER: p.secret}) as response:
                        if response.status == 200:
                            return True
                except aiohttp.ClientError:
                    pass
            await asyncio.sleep(0.1)
        return False

    def _stop_stack(self, p: Participant) -> None:
        if p.leave is not None:
            p.leave.cancel()
            p.leave = None
        p.life.stopped()
        if self.pool is not None:
            self.pool.unload(p.id)   # its nodes shut down (the study keeps its rows)

    def _running(self, p: Participant) -> bool:
        return self.pool is not None and self.pool.running(p.id)

    def _placed(self, p: Participant) -> bool:
        """Its stack is in a container, running or being loaded again after its container died."""
        return self.pool is not None and self.pool.container_of(p.id) is not None

    def running(self) -> int:
        return sum(1 for p in self.participants.values() if self._running(p))

    async def _watch_stacks(self, period_s: float = 0.5) -> None:
        """A container that died is started again with its participants' stacks: each study node
        resumes at its first trial without a row, and each page reconnects to the same port."""
        while True:
            await asyncio.sleep(period_s)
            if self.pool is None:
                continue
            try:
                back = self.pool.check()
            except Exception:  # noqa: BLE001 - the watch must go on (the dead ones are tried again)
                log.exception("starting a dead container again failed; trying again in %g s", period_s)
                continue
            for participant, how in back.items():
                log.warning("%s: its stack's process died; %s", participant,
                            {"again": "started again", "alone": "started again, alone in a process (its processes "
                             "kept dying)", "given up": "not started again (its processes kept dying)"}.get(
                                how, "its stack cannot be made again (see its serve.log)"))
                asyncio.ensure_future(self._back(self.participants[participant]))

    async def _back(self, p: Participant) -> None:
        """A stack loaded again after its container died: if it does not come up, its place is
        given back (the link starts it again)."""
        if not await self._wait_ready(p):
            log.warning("%s: its stack did not start again; see %s", p.id, session_dir(self.out, p.id) / "serve.log")
            self._stop_stack(p)
            return
        if p.life.held:   # a new study node starts unpaused: the experimenter's pause again
            self.command(p.id, PAUSE, "the experimenter (its stack started again)")
        if p.pages == 0:
            self._await_page(p)   # its page gone with the container: back within the grace, or it has left

    # ---- HTTP ----------------------------------------------------------------------------------

    def _say(self, text: str) -> None:
        """One line on the terminal (and the log) for what the experimenter follows: joins, leaves,
        pauses, refusals for a full study, shutdown."""
        print(f"{time.strftime('%H:%M:%S')} {text}", flush=True)
        log.info("%s", text)

    def _log_once(self, cause: str, text: str) -> None:
        if cause not in self._logged:
            self._logged.add(cause)
            log.warning("%s (further ones are only counted)", text)

    @web.middleware
    async def _refusals(self, request: web.Request, handler):
        """The gate's 403 (a forged, expired or revoked token) counted and logged once."""
        self._load_invites()
        try:
            return await handler(request)
        except web.HTTPForbidden:
            if HOLDER in request:
                raise   # a holder refused something further (a mismatched id): counted there
            self.counts["forged"] += 1
            self._log_once("forged", f"refused a request with a forged, expired or revoked link ({request.path})")
            raise

    @web.middleware
    async def _budget(self, request: web.Request, handler):
        """Each link's requests within HOLDER_RATE per second (HOLDER_BURST at once): more get 429."""
        holder = request.get(HOLDER)
        if holder is not None:
            bucket = self._budgets.get(holder)
            if bucket is None:
                bucket = self._budgets[holder] = TokenBucket(HOLDER_RATE, HOLDER_BURST)
            if not bucket.spend(time.monotonic()):
                self.counts["over budget"] += 1
                self._log_once(f"budget {holder}", f"{holder}: over {HOLDER_RATE:g} requests a second; "
                               "answering 429 for the rest")
                raise web.HTTPTooManyRequests(text="touch4d: too many requests; wait a second\n",
                                              headers={"Retry-After": "1"})
        return await handler(request)

    def _participant(self, request: web.Request) -> Participant:
        holder = request[HOLDER]
        wanted = request.query.get("participant")
        if wanted is not None and wanted != holder:
            self.counts["mismatched"] += 1
            self._log_once("mismatched", f"refused a link whose participant id ({wanted[:32]!r}) is not its token's")
            raise web.HTTPForbidden(text="touch4d: this link's participant id does not match its token.\n")
        if holder == EXPERIMENTER:
            raise web.HTTPFound("/experimenter")
        p = self.participants.get(holder)
        if p is None:   # a holder the access layer knows is invited
            p = self._add_participant(holder)
        return p

    async def _index(self, request: web.Request) -> web.StreamResponse:
        p = self._participant(request)
        if self._running(p) and p.life.state in (State.RUNNING, State.DONE):
            return await self._proxy_http(request, p)
        return web.Response(text=self._welcome(p), content_type="text/html")

    def _welcome(self, p: Participant) -> str:
        study = self.study
        rows = self._rows(p.id)
        paragraphs = lambda text: "".join(f"<p>{html.escape(t.strip())}</p>" for t in text.split("\n\n") if t.strip())  # noqa: E731
        go = "Continue" if rows else "Join"
        return (f"<!doctype html><html lang=en><head><meta charset=utf-8><meta name=viewport "
                f"content='width=device-width, initial-scale=1'><title>{html.escape(study.name)}</title></head><body>"
                f"<h1>{html.escape(study.description or study.name)}</h1>"
                + (f"<p>Welcome back: {rows} trials are done, the next one follows.</p>" if rows else "")
                + f"<h2>Consent</h2>{paragraphs(study.consent)}<h2>Instructions</h2>{paragraphs(study.instructions)}"
                "<p id=vibration role=alert hidden></p>"
                f"<form method=post action=/join><button id=join type=submit>{go}</button></form>"
                # the link's token out of the address bar; whether this browser can vibrate, before consent
                "<script src=/welcome.js></script></body></html>")

    async def _welcome_script(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC_DIR / "welcome.js")

    async def _device(self, request: web.Request) -> web.StreamResponse:
        """The welcome page's report of what this browser can vibrate (before consent): kept for the
        experimenter's page; the answer says what to tell the participant and whether Join is open."""
        p = self._participant(request)
        if cross_site(request):
            raise web.HTTPForbidden(text="touch4d: from another site refused\n")
        if (request.content_length or 0) > MAX_DEVICE_BODY:
            raise web.HTTPRequestEntityTooLarge(MAX_DEVICE_BODY, request.content_length)
        try:
            said = json.loads(await request.content.read(MAX_DEVICE_BODY + 1))
            immersive, rumble = said["immersive"], said["rumble"]
            if not (isinstance(immersive, bool) and isinstance(rumble, bool)):
                raise TypeError
        except (ValueError, KeyError, TypeError):
            raise web.HTTPBadRequest(text='touch4d: /device takes {"immersive": bool, "rumble": bool}\n') from None
        vibration = "headset" if immersive else "gamepad" if rumble else "none"
        if vibration != p.vibration:
            p.vibration = vibration
            if vibration == "none":
                self._say(f"{p.id}: its browser cannot vibrate ({'refused' if self.study.without_vibration == 'refuse' else 'allowed'} by the study's without_vibration)")
        refused = vibration == "none" and self.study.without_vibration == "refuse"
        text = "" if vibration != "none" else NO_VIBRATION_REFUSED if refused else NO_VIBRATION_ALLOWED
        return web.json_response({"vibration": vibration, "refused": refused, "text": text})

    def _rows(self, participant: str) -> int:
        return rows_written(session_dir(self.out, participant))

    async def _join(self, request: web.Request) -> web.StreamResponse:
        p = self._participant(request)
        if p.vibration == "none" and self.study.without_vibration == "refuse":
            self.counts["no vibration"] += 1
            return web.Response(status=403, content_type="text/html", text=(
                "<!doctype html><html lang=en><meta charset=utf-8><title>Cannot vibrate</title><body><h1>This "
                f"browser cannot take part</h1><p>{html.escape(NO_VIBRATION_REFUSED)}</p></body></html>"))
        if self._running(p) and p.life.state in (State.RUNNING, State.DONE):
            raise web.HTTPSeeOther("/")    # its stack runs and was seen ready: no probe of its node again
        if p.starting is None:             # else a join already waits for its stack: wait with it
            p.starting = asyncio.ensure_future(self._start(p))   # on, even if this request's browser goes
            p.starting.add_done_callback(lambda _: setattr(p, "starting", None))
        refusal = await asyncio.shield(p.starting)
        if refusal is not None:
            status, text = refusal
            return web.Response(status=status, text=text, content_type="text/html" if status != 500 else "text/plain")
        raise web.HTTPSeeOther("/")

    async def _start(self, p: Participant) -> tuple[int, str] | None:
        """Start a participant's stack and wait until its page is served (one at a time per participant):
        None, or the status and page that say why not."""
        if not self._running(p):
            if p.life.has_stack:    # its stack went without the server seeing it go: it has left
                p.life.stopped()
            if p.life.state is State.DONE:
                return 200, ("<!doctype html><html lang=en><meta charset=utf-8><title>Done</title><body><h1>Every "
                             "trial is done</h1><p>Thank you for taking part.</p></body></html>")
            if self.running() >= self.max_participants:
                self.counts["full"] += 1
                self._say(f"{p.id}: refused, the study is full ({self.running()} of {self.max_participants} "
                          "running; --max-participants to change)")
                return 503, ("<!doctype html><html lang=en><meta charset=utf-8><title>Full</title><body><h1>The "
                             "study is full right now</h1><p>Every place is taken. Please open your link again in a "
                             "few minutes.</p></body></html>")
            self.counts["resumed" if self._rows(p.id) else "joined"] += 1
            p.life.join()      # revoked links never get here (the gate refused them)
            if self._start_stack(p):
                self._say(f"{p.id} {'is back' if self._rows(p.id) else 'joined'}: starting its stack "
                          f"({self.pool.container_of(p.id)}); {self.running()} of {self.max_participants} running")
        if not await self._wait_ready(p):
            self._stop_stack(p)
            # the log's path is the experimenter's: this page faces the internet
            log.warning("%s: its stack did not start; see %s", p.id, session_dir(self.out, p.id) / "serve.log")
            return 500, f"touch4d: the session of {p.id} could not start; please tell the experimenter\n"
        if p.life.state is State.STARTING:
            self._tell(p, p.life.ready(), "the experimenter")   # held before: paused again at once
            self._await_page(p)
        return None

    def _current_port(self, p: Participant) -> int:
        """Its page server's port now: its container, started again, says a new one."""
        try:
            port = _page_port(self._ready_file(p).read_text()) if self.tmp is not None else None
        except OSError:
            port = None
        if port is not None:
            p.port = port
        return p.port

    async def _proxy_http(self, request: web.Request, p: Participant, path: str = "/") -> web.StreamResponse:
        url = f"http://127.0.0.1:{self._current_port(p)}{path}"
        try:
            async with self.client.get(url, headers={SECRET_HEADER: p.secret}) as upstream:
                body = await upstream.read()
                response = web.Response(body=body, status=upstream.status)
                if upstream.content_type:
                    response.content_type = upstream.content_type
                for name in PROXIED_HEADERS:
                    if name in upstream.headers:
                        response.headers[name] = upstream.headers[name]
                return response
        except aiohttp.ClientError:
            return web.Response(status=502, text=f"touch4d: the session of {p.id} is not answering; reload\n")

    async def _static(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["path"]
        if name not in STATIC_NAMES:   # an over-long name, a folder, a `..`: never forwarded
            raise web.HTTPNotFound(text="touch4d: no such file\n")
        p = self._participant(request)
        if not self._running(p):
            raise web.HTTPNotFound(text="touch4d: join first\n")
        return await self._proxy_http(request, p, f"/static/{name}")

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        """The page's WebSocket, spliced byte for byte to its participant's page server once that
        answered the upgrade 101 (touch4d.web.splice): this server parses no frame. The page server
        enforces its limits (message size, flood, its heartbeat closing a page that vanished); either
        side closing ends both, and the participant's page with them."""
        p = self._participant(request)
        if cross_site(request):
            raise web.HTTPForbidden(text="touch4d: WebSocket from another origin refused\n")
        if not self._running(p):
            raise web.HTTPNotFound(text="touch4d: join first\n")
        port = self._current_port(p)
        upgrade = _upgrade_request(request, port, p.secret)
        if upgrade is None or request.transport is None:
            raise web.HTTPBadRequest(text="touch4d: /ws takes a WebSocket upgrade\n")
        trace = self._trace
        splice = Splice(_heard(p, None if trace is None else trace.page_bytes(p.id)),
                        None if trace is None else trace.frame_bytes(p.id))
        try:
            status, headers, body = await splice.upgrade("127.0.0.1", port, upgrade, UPSTREAM_TIMEOUT_S)
        except (OSError, TimeoutError):
            raise web.HTTPBadGateway(text=f"touch4d: the session of {p.id} is not answering\n") from None
        if status != 101:   # the page server's refusal (over its max_pages: 503), passed on
            if not 400 <= status < 600:
                raise web.HTTPBadGateway(text=f"touch4d: the session of {p.id} did not take the WebSocket\n")
            return web.Response(status=status, body=body,
                                headers={"Content-Type": headers.get("Content-Type", "text/plain")})
        # A browser sends nothing before the 101 (RFC 6455 4.1): the connection has no bytes of its
        # own left with aiohttp when it is taken. Its transport is read again: the browser may have
        # gone while the page server answered.
        if splice.join(request.transport, self.hardening.take):
            self._page_opened(p)
            self._splices.add(splice)
            try:
                await splice.finish(request.protocol)
            finally:
                self._splices.discard(splice)
                self._page_closed(p)
        return web.Response()

    def _await_page(self, p: Participant) -> None:
        """A stack just started: if no page of its participant connects within `leave_after_s` (at
        least `page_grace_s`, for a page loading on a slow headset), they have left (a place is not
        held forever by a join whose page never came)."""
        if p.pages == 0 and p.leave is None:
            p.leave = self._loop.call_later(max(self.leave_after_s, self.page_grace_s), self._left, p)

    def _page_opened(self, p: Participant) -> None:
        p.pages += 1
        p.last_heard = time.time()
        if p.leave is not None:
            p.leave.cancel()
            p.leave = None
        if p.life.page_gone:   # the server's own pause (no page): the page back undoes it, not the experimenter's
            self._tell(p, p.life.page_opened(), "the participant's page is back")
            self._say(f"{p.id}: its page is back; " + ("its trial stays paused (by the experimenter)" if p.life.held
                                                         else "trial resumed"))

    def _page_closed(self, p: Participant) -> None:
        p.pages -= 1
        if p.pages > 0 or not self._placed(p):   # placed: its container may be dead and loading it again
            return
        self._tell(p, p.life.page_closed(), "the participant's page closed")
        self._say(f"{p.id}: its page closed; paused (its stack stops in {self.leave_after_s:g} s unless it comes back)")
        p.leave = self._loop.call_later(self.leave_after_s, self._left, p)

    def _left(self, p: Participant) -> None:
        p.leave = None
        if p.pages == 0 and self._running(p):
            self.counts["left"] += 1
            self._say(f"{p.id} left: its stack stops (its link resumes it)")
            self._stop_stack(p)

    # ---- the experimenter's page ---------------------------------------------------------------

    def _experimenter_only(self, request: web.Request) -> None:
        if request[HOLDER] != EXPERIMENTER:
            raise web.HTTPForbidden(text="touch4d: the experimenter's link only\n")

    def _planned(self, participant: str) -> int:
        """How many trials the participant's session has (its plan: a pure function of study and id)."""
        if participant not in self._plan_lengths:
            plan = (quick_plan if self.quick else plan_session)(self.study, participant)
            self._plan_lengths[participant] = len(plan)
        return self._plan_lengths[participant]

    def status(self) -> list[dict]:
        """Every participant: state (and who paused it), trials done of planned, the trial now, seconds
        since its page was last heard."""
        now = time.time()
        out = []
        for p in sorted(self.participants.values(), key=lambda p: p.id):
            t = p.trial if self._running(p) else None
            rows = self._rows(p.id)
            out.append({"participant": p.id, "state": p.life.shown(), "paused_by": p.life.paused_by,
                        "vibration": p.vibration, "pages": p.pages,
                        "rows": rows, "planned": self._planned(p.id),
                        "trial": None if t is None or t.index < 0 else t.index + 1,
                        "of": None if t is None else t.total, "phase": None if t is None else t.phase,
                        "last_heard_s": None if not p.last_heard else round(now - p.last_heard, 1)})
        return out

    def _adopt_folders(self) -> None:
        """Participants with a session folder in OUT but no link now (revoked before a restart) are
        still shown, with their data's state."""
        try:
            folders = [d.name for d in self.out.iterdir() if d.is_dir() and not d.is_symlink()]
        except OSError:
            return
        for name in folders:
            if name not in self.participants and PARTICIPANT_ID.match(name) and name != EXPERIMENTER \
                    and any((self.out / name / f).exists() for f in ("manifest.json", "trials.csv")):
                self._add_participant(name)

    def _table(self) -> str:
        """The participants' table (the experimenter's page, and what its script fetches each second)."""
        cell = lambda value, unit="": "-" if value is None else f"{html.escape(str(value))}{unit}"  # noqa: E731
        buttons = lambda who: "".join(  # noqa: E731
            f"<form method=post action=/experimenter/{action}><input type=hidden name=participant "
            f"value='{html.escape(who, quote=True)}'><button>{action}</button></form>" for action in ACTIONS)
        rows = "".join(
            f"<tr data-state={s['state']}><td>{html.escape(s['participant'])}</td>"
            f"<td>{s['state']}{'' if s['paused_by'] is None else ' by ' + html.escape(s['paused_by'])}</td>"
            f"<td>{s['rows']} of {s['planned']}</td><td>{cell(s['trial'])} of {cell(s['of'])}</td>"
            f"<td>{cell(s['phase'])}</td><td>{cell(s['vibration'])}</td><td>{cell(s['last_heard_s'], ' s')}</td>"
            f"<td>{'' if s['state'] == 'revoked' else buttons(s['participant'])}</td></tr>"
            for s in self.status())
        return (f"<p id=summary>{self.running()} of {self.max_participants} running; refused while full: "
                f"{self.counts['full']}; refused, cannot vibrate: {self.counts['no vibration']}</p><table "
                "id=participants><tr><th>participant</th><th>state</th><th>trials done</th><th>trial now</th>"
                f"<th>phase</th><th>vibration</th><th>last heard</th><th></th></tr>{rows}</table>")

    async def _experimenter(self, request: web.Request) -> web.StreamResponse:
        self._experimenter_only(request)
        form = request.query.get("format")
        if form == "json":
            return web.json_response({"participants": self.status(), "counts": self.counts,
                                      "running": self.running(), "max_participants": self.max_participants})
        if form == "table":
            return web.Response(content_type="text/html", text=self._table(), headers=NO_STORE)
        name = html.escape(self.study.name)
        return web.Response(content_type="text/html", headers=NO_STORE, text=(
            f"<!doctype html><html lang=en><meta charset=utf-8><meta name=referrer content=no-referrer>"
            f"<title>{name}: participants</title><body><h1>{name}: participants</h1><div id=live>{self._table()}</div>"
            f"<form method=post action=/experimenter/invite><input name=participant placeholder=P07>"
            f"<button>invite</button></form><script src=/experimenter.js></script></body></html>"))

    async def _experimenter_script(self, request: web.Request) -> web.StreamResponse:
        self._experimenter_only(request)
        return web.FileResponse(STATIC_DIR / "experimenter.js", headers=NO_STORE)

    async def _experimenter_action(self, request: web.Request) -> web.StreamResponse:
        self._experimenter_only(request)
        if cross_site(request):   # a form on another site posting with the experimenter's cookie
            self._log_once("cross-site", "refused an experimenter action posted from another site")
            raise web.HTTPForbidden(text="touch4d: actions from another site refused\n")
        form = await request.post()
        participant = str(form.get("participant", ""))
        action = request.match_info["action"]
        if action == "invite":
            try:
                token = self.invites.issue(check_participant(participant))   # never the experimenter's
            except ValueError as exc:
                raise web.HTTPBadRequest(text=f"touch4d: {exc}\n") from None
            self._load_invites()
            link = self.link(participant, token)
            return web.Response(content_type="text/html", text=f"<!doctype html><p>{html.escape(link)}</p>"
                                                                 "<p><a href=/experimenter>back</a></p>")
        p = self.participants.get(participant)
        if p is None:
            raise web.HTTPNotFound(text="touch4d: no such participant\n")
        if action in ("pause", "resume"):
            self._tell(p, p.life.experimenter(action), "the experimenter")
        elif action == "revoke":
            self.invites.revoke(p.id)
            self._load_invites()       # ends its cookies, stops its stack (it shows as revoked)
            self._say(f"{p.id}: link revoked by the experimenter")
        raise web.HTTPSeeOther("/experimenter")

    def link(self, participant: str, token: str) -> str:
        return participant_link(self.base_url(), participant, token)

    # ---- running -------------------------------------------------------------------------------

    async def _serve(self) -> None:
        sock = self._socket or self._listen()     # bound before OUT is written
        self.experimenter_token = self.invites.issue(EXPERIMENTER, keep=True)
        self._load_invites()
        self._adopt_folders()
        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._loop.add_signal_handler(sig, self._stopping.set)
        app = self.hardening.application([self._refusals, self.gate.middleware, self._budget])
        app.router.add_get("/", self._index)
        app.router.add_post("/join", self._join)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/static/{path:.*}", self._static)
        app.router.add_get("/experimenter", self._experimenter)
        app.router.add_get("/experimenter.js", self._experimenter_script)
        app.router.add_get("/welcome.js", self._welcome_script)
        app.router.add_post("/device", self._device)
        app.router.add_post("/experimenter/{action:%s}" % "|".join((*ACTIONS, "invite")), self._experimenter_action)
        self.client = aiohttp.ClientSession()
        if self.wire_trace is not None:
            self._trace = WireTrace(self.wire_trace)
        runner = self.hardening.runner(app)
        await runner.setup()
        site = web.SockSite(runner, sock)
        await site.start()
        freeze_startup_heap()   # its 90k objects: a full collection over them stalled every participant ~50 ms
        (self.out / SERVED).write_text(json.dumps({"url": self.base_url()}) + "\n")
        print(f"study {self.study.name}: serving {self.base_url()}/ for up to {self.max_participants} participants"
              f"{self._cap_note}; data in {self.out}", flush=True)
        print(f"experimenter page: {self.base_url()}/experimenter?token={self.experimenter_token}", flush=True)
        watch = asyncio.ensure_future(self._watch_invites())
        stacks = asyncio.ensure_future(self._watch_stacks())
        try:
            await self._stopping.wait()
        finally:
            watch.cancel()
            stacks.cancel()
            self._say(f"stopping: {self.running()} running participants' stacks stop (each resumes at its next "
                      "trial when its link is opened again)")
            for p in self.participants.values():
                self._stop_stack(p)
            if self.pool is not None:
                await asyncio.get_running_loop().run_in_executor(None, self.pool.close)
            for splice in list(self._splices):
                splice.close()
            await self.client.close()
            await runner.cleanup()
            if self._trace is not None:
                self._trace.close()
            self._say("stopped")

    async def _watch_invites(self, period_s: float = 1.0) -> None:
        """A link revoked with `touch4d study invite --revoke` stops its stack within `period_s`,
        whether or not anyone makes a request."""
        while True:
            await asyncio.sleep(period_s)
            self._load_invites()

    @staticmethod
    def _raise_priority(stack: list) -> None:
        """A stack whose haptic loop asks for `realtime`: this thread's loop, which every page message
        and pulse passes through (the splice), runs SCHED_FIFO where permitted, and it alone (the
        containers it starts raise their own loops when they load such a stack)."""
        if not any(spec.realtime for spec in stack):
            return
        if raise_loop_priority():
            log.info("the server's loop runs at real-time priority (SCHED_FIFO %d)", LOOP_PRIORITY)
        else:
            log.warning("%s: the server's loop and the participants' run at normal priority", NOT_PERMITTED)

    def _check_glove(self, stack: list) -> None:
        """Say on the terminal which tasks the participants' glove (their tactile node's) cannot tell
        (infotransfer.glove_task_warnings, as `study check --glove`): a few seconds of simulation, in
        a thread at the lowest priority while the server starts serving."""
        path = next((s.params["glove"] for s in stack if s.role == "tactile" and s.params.get("glove")), None)
        if path is None:
            return
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)   # this thread (Linux)
        except (OSError, AttributeError):
            pass
        try:
            from touch4d.study.infotransfer import glove_task_warnings
            from touch4d.tactile import load_glove
            warnings = glove_task_warnings(load_glove(path), self.study)
        except Exception as exc:  # noqa: BLE001 - a check that cannot run must not stop the serving
            log.warning("could not check the glove %s against the study's tasks: %s", path, exc)
            return
        for line in warnings:
            self._say(f"warning: {line}")

    def _claim_out(self) -> SessionLock:
        """OUT held for this server alone (a second server on it is refused, naming this one); made
        here if it is new (and removed again if the start is refused before anything is written)."""
        return SessionLock(self.out, SERVE, mode=0o700).acquire()   # personal data: its owner's alone

    def _listen(self) -> socket.socket:
        """The listening socket, bound before anything is written (a busy port: ConfigError naming it)."""
        try:
            family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
            sock = socket.create_server((self.host, self.port), family=family)
        except OSError as exc:
            expected = f"a port free to listen on at {self.host}"
            if exc.errno == errno.EADDRINUSE:
                raise ConfigError(COMMAND_LINE, "--port", expected, got=self.port, detail="in use by another "
                                  "program (another study server?): stop it, or serve on another --port") from None
            raise ConfigError(COMMAND_LINE, "--port", expected, got=self.port, detail=exc.strerror) from None
        self.port = sock.getsockname()[1]
        return sock

    def run(self) -> int:
        os.umask(0o077)         # what it writes, and the containers it starts: OUT holds personal data
        _refuse_shared(self.out)
        stack = self.stack_group("P00")   # a launch that cannot make a participant's stack fails now, not at a join
        with self._claim_out(), self._listen() as self._socket, \
                tempfile.TemporaryDirectory(prefix="touch4d-serve-") as tmp:
            self.tmp = Path(tmp)
            self._start_bus(self.tmp)
            self._raise_priority(stack)   # this thread alone: the bus's threads keep their own priorities
            threading.Thread(target=self._check_glove, args=(stack,), name="glove-check", daemon=True).start()
            try:
                with asyncio.Runner(loop_factory=new_event_loop) as runner:   # uvloop's where installed
                    runner.run(self._serve())
            finally:
                self.node.request_shutdown()
                self._bus_thread.join(5)
                self.broker.stop()
        return 0


def _refuse_shared(out: Path) -> None:
    """An --out that others may write to is refused: it holds personal data, and a file or symlink
    planted there would be read or written by the server."""
    try:
        mode = stat.S_IMODE(out.stat().st_mode)
    except FileNotFoundError:
        return   # made 0700
    if mode & 0o022:
        raise ConfigError(out, "--out", "a folder only its owner may write to (it holds participants' data: "
                          f"chmod go-w {out}, or a new --out)", got=f"mode {mode:04o}")


def served_url(out: Path) -> str | None:
    """The address the server last served OUT at (OUT/serve.json), for `touch4d study invite`."""
    try:
        return json.loads((Path(out) / SERVED).read_text())["url"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def participant_link(base_url: str, participant: str, token: str) -> str:
    """A participant's link (the experimenter's: /experimenter)."""
    if participant == EXPERIMENTER:
        return f"{base_url}/experimenter?token={token}"
    return f"{base_url}/?participant={quote(participant)}&token={token}"



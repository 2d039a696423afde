"""The study server (`touch4d study serve`): participants join a study from their own headset's
browser by a link, many at once, each a session held in this process (touch4d.web.served: the trial
machine, the scene, the page's frames, trials.csv, the manifest and the MCAP log, one folder each
as `touch4d study run` writes it), not a stack of processes: the page computes its touch itself, so
nothing of the haptic loop comes here.

A link is `URL/?participant=P07&token=...` (`invites.Invites`, kept in OUT/invites.json). Opening
it shows the study's consent and instructions (and takes the token out of the address bar: the
cookie carries on); Join starts that participant's session and serves the WebXR page, whose
WebSocket is theirs (one page at a time: a second is refused, 503). When their page closes, their
trial pauses; the page back within `leave_after_s` resumes it, else the session stops and the
link's next opening starts it again, resuming at the first trial without a row (a server killed and
started again on the same OUT resumes everyone the same way; a join whose page never connects stops
so too, after `page_grace_s` at least). More running participants than `max_participants`: a page
that says so, HTTP 503. A forged, expired or revoked token: 403 (access.CookieGate), logged once; a
link revoked or replaced in OUT/invites.json ends its cookies and its session. A participant id in
the link that is not its token's: 403. The experimenter's link opens /experimenter: every
participant's state, trial, frame rate, last message heard; pause or resume their trial, or revoke a
link; it is live by server-sent events (/experimenter/events) and offers every trial as one CSV.

Recruiting online (`--open-link`): one link for many, `URL/open?key=...` (its key in OUT/recruits.json);
each visitor gets a participant of their own, the next free Pnn of the least-filled counterbalancing
row (touch4d.study.recruitment), and is sent to its link. A platform's parameters (PROLIFIC_PID, ...)
go in the participant's manifest (`platform`), and the same platform id comes back to the same
participant. Done: `--complete-url` (with `--completion-code`); quit or a failed device check:
`--return-url`. The welcome page's device check (touch4d.web.devicecheck, the study's `device_check`)
comes before consent; a device that fails it is not a participant (an open-link place is freed).
"""
from __future__ import annotations

import asyncio
import errno
import html
import json
import logging
import os
import re
import socket
import signal
import stat
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote, urlsplit

import msgspec
from aiohttp import web

from touch4d.bus.heap import freeze_startup_heap
from touch4d.configfile import COMMAND_LINE
from touch4d.deadline import Deadline
from touch4d.errors import ConfigError, Touch4dError
from touch4d.eventloop import new_event_loop
from touch4d.study.design import Study
from touch4d.study.lock import SERVE, SessionLock
from touch4d.study.participation import Life, State
from touch4d.study.manifest import update_manifest
from touch4d.study.plan import plan_session, quick_plan
from touch4d.study.store import PARTICIPANT_ID, rows_written, session_dir

from .access import HOLDER, Access, CookieGate, cross_site
from .devicecheck import MAX_BODY as MAX_DEVICE_BODY, answered, failures, parse_report
from .experimenterpage import ExperimenterPage
from .hardening import ESCAPED, SECURITY_HEADERS, Hardening, host_name, raise_file_limit
from .inbox import TokenBucket
from .invites import EXPERIMENTER, Invites
from .openlink import OpenLink
from .served import ServedOptions, ServedSession, Shared
from .server import STATIC_DIR, PageBounds, PageServer, static_names

log = logging.getLogger("study-serve")
log.addFilter(ESCAPED)   # a request path in a line: its control and bidi characters escaped

SERVED = "serve.json"             # OUT/serve.json: the address served, for `touch4d study invite`
PAGE_GRACE_S = 60.0           # after a join, its page connects within this (or leave_after_s if longer)
# Participants at once by default, per core this process may run on: each costs the server a batch of
# its page's frames every 0.1 s and a frame every 0.25 s (bench/bench_serve.py: 512 took about 0.4 of
# one core and 1.3 MB each on a 2-core machine); the rest of the core is the room for joins and trials.
PARTICIPANTS_PER_CORE = 250
HOLDER_RATE = 20.0            # requests per second and link, on average (a page's load is ~15 files once)
HOLDER_BURST = 60             # and at most this many at once
# The page server's headers on every answer, but forms post here (join, the experimenter's); scripts
# are this server's files only (the welcome page's, the experimenter page's: no inline script).
STUDY_HEADERS = {**SECURITY_HEADERS, "Content-Security-Policy": (
    SECURITY_HEADERS["Content-Security-Policy"].replace("form-action 'none'", "form-action 'self'")
    + "; script-src 'self'")}
# A served page sends a batch every batch_s and its stats each second whatever the network does: a
# stall (until the heartbeat closes the page: WS_HEARTBEAT_S and its pong's wait) delivers them at
# once, and the answer sent behind them must not be dropped by the page server's bound on a page's
# messages (touch4d.web.inbox: 20 at once). This long of them may come at once; a flood is still cut.
PAGE_STALL_S = 10.0
DEVICE_FAILED = ("Thank you for your interest. This device did not pass the check this study needs (its "
                 "vibration, or its frame rate), so it cannot take part; you have not been counted as a "
                 "participant.")
# What a participant whose browser cannot vibrate reads before consent (and why).
NO_VIBRATION = ("This browser cannot vibrate: no VR headset (WebXR) and no gamepad with rumble were found. "
                "This study's touch is felt as vibration. With a gamepad, press one of its buttons, then reload.")
NO_VIBRATION_REFUSED = NO_VIBRATION + " Please join from a VR headset's browser (a Quest) or with a gamepad."
NO_VIBRATION_ALLOWED = NO_VIBRATION + " You may take part: in the trials with touch you will feel nothing."
STATIC_NAMES = static_names(STATIC_DIR)   # /static/ names served to a participant's page: its files only


def _cores() -> int:
    """The cores this process may run on (its CPU affinity)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def default_max_participants() -> int:
    """Participants at once when the experimenter does not say: PARTICIPANTS_PER_CORE per core this
    process may run on, at least 2."""
    return max(2, PARTICIPANTS_PER_CORE * _cores())


@dataclass
class Participant:
    """One participant: their life, their session while it runs, what the experimenter page shows."""

    id: str
    life: Life = field(default_factory=Life)   # invited, starting, running (paused by whom), left, done, revoked
    session: ServedSession | None = None       # while it runs (touch4d.web.served)
    conn: int | None = None            # its page's WebSocket, while one is open
    last_heard: float = 0.0            # wall clock of the last message its page sent
    leave: asyncio.TimerHandle | None = field(default=None, repr=False)
    tick: Deadline | None = field(default=None, repr=False)   # its session's next deadline
    vibration: str | None = None       # what its welcome page found: headset, gamepad, none (None: not told)
    starting: asyncio.Future | None = field(default=None, repr=False)   # a join making its session now
    device: dict | None = None         # what its device check measured (devicecheck.parse_report), for the manifest
    passed: bool | None = None         # whether that device passed the study's device_check (None: not judged)
    opened: bool = False               # made by the open link (freed again if its device fails or it quits first)
    since: float | None = None         # its last move (link made, join, a trial's row): recruitment.Place
    rows_seen: int = 0                 # its session's rows when last looked

    @property
    def pages(self) -> int:
        return int(self.conn is not None)


class ServeOptions(msgspec.Struct, kw_only=True, frozen=True):
    """How a study is served (`touch4d study serve`'s flags), declared once."""

    host: str = "127.0.0.1"
    port: int = 8095                         # 0: any free one
    max_participants: int | None = None      # None: default_max_participants()
    public_url: str | None = None            # a reverse proxy's address (https: Secure cookies)
    leave_after_s: float = 30.0              # a participant without a page this long has left
    secure: bool | None = None               # Secure cookies (None: from public_url's scheme)
    page_grace_s: float = PAGE_GRACE_S       # after a join, its page connects within this
    session: ServedOptions = msgspec.field(default_factory=ServedOptions)   # each participant's (glove, timings)
    open_link: bool = False                  # one link for many: each visitor becomes a participant of their own
    max_total: int | None = None             # the open link admits no one once this many are done or under way
    id_params: tuple[str, ...] = ()          # a platform's query parameters kept beside PLATFORM_PARAMS
    complete_url: str | None = None          # where a participant who finished every trial goes
    completion_code: str | None = None       # appended to complete_url as ?cc=CODE (Prolific's)
    return_url: str | None = None            # where one who quits, or whose device fails the check, goes
    glove_check: bool = True                 # at start, say which tasks the glove cannot tell (seconds of CPU)


class StudyServer:
    """The server; `run()` serves until SIGINT/SIGTERM."""

    def __init__(self, study: Study, study_path: Path, out: Path, options: ServeOptions | None = None):
        o = ServeOptions() if options is None else options
        self.options = o
        self.study, self.study_path, self.out = study, Path(study_path), Path(out)
        self.host, self.port = o.host, o.port
        self.max_participants = default_max_participants() if o.max_participants is None else o.max_participants
        self._cap_note = (f" ({PARTICIPANTS_PER_CORE} per core here; --max-participants N to change)"
                          if o.max_participants is None else "")
        self.public_url = o.public_url
        self.leave_after_s, self.quick = o.leave_after_s, o.session.quick
        self.page_grace_s = o.page_grace_s
        self.shared = Shared(o.session)          # the glove, the calibration: read once (a bad file fails now)
        # Cookies marked Secure when participants come over https (a reverse proxy's certificate):
        # this server speaks plain http, on loopback or behind that proxy.
        self.secure = (o.public_url or "").startswith("https://") if o.secure is None else o.secure
        self.invites = Invites(self.out)
        self.access = Access()
        self.gate = CookieGate(self.access, secure=self.secure, cookie="touch4d-study", open_prefixes=("/open",))
        # the internet's bounds, as the page server's (touch4d.web.hardening); the public name served too
        self.hardening = Hardening(o.host, [host_name(o.public_url)] if o.public_url else [], headers=STUDY_HEADERS,
                                   log=log)
        # the pages' WebSockets: the page server's bounds, queues and heartbeat, through this server's /ws
        bounds = PageBounds(max_pages=10**6, other_burst=round(PAGE_STALL_S * (1 / o.session.batch_s + 1)))
        self.pages = PageServer(o.host, 0, bounds=bounds, hardening=self.hardening, on_connect=self._page_opened,
                                on_message=self._page_message, on_close=self._page_closed)
        self.participants: dict[str, Participant] = {}
        self.counts = {"full": 0, "forged": 0, "mismatched": 0, "joined": 0, "resumed": 0, "left": 0,
                       "over budget": 0, "no vibration": 0, "second page": 0, "device failed": 0, "open link": 0,
                       "quit": 0, "total reached": 0}
        self._logged: set[str] = set()
        self._plan_lengths: dict[str, int] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self.stopping: asyncio.Event | None = None
        self._tokens: dict[str, str] | None = None    # OUT/invites.json as last adopted
        self._invites_signature: tuple | None = None   # and its file's (Invites.signature) then
        self._budgets: dict[str, TokenBucket] = {}   # each holder's requests (a flood of one slows no one else)
        self._by_conn: dict[int, Participant] = {}   # each open page's participant
        self.experimenter_token: str | None = None   # issued when it serves (run), not before
        self._socket: socket.socket | None = None   # bound by run() before OUT is written
        self.open_link = OpenLink(self)              # /open (with --open-link), /done, /quit
        self.experimenter = ExperimenterPage(self)   # its page: /experimenter and below
        self.load_invites()

    # ---- links ---------------------------------------------------------------------------------

    def base_url(self) -> str:
        if self.public_url:
            return self.public_url.rstrip("/")
        return f"http://{self.host}:{self.port}"

    def tokens(self) -> dict[str, str]:
        """Each participant's token now (OUT/invites.json as last adopted)."""
        return self._tokens or {}

    def load_invites(self) -> None:
        """Adopt OUT/invites.json (written by `touch4d study invite` too, while this runs): a link
        revoked or replaced there ends its holder's cookies and its session. A file that cannot be read as
        links keeps the links adopted before (logged once)."""
        signature = self.invites.signature()
        if self._tokens is not None and signature == self._invites_signature:
            return     # unchanged since read (every request asks: one stat, not a parse)
        self._invites_signature = signature
        try:
            tokens = self.invites.load()
        except ValueError as exc:
            self.log_once("invites", f"{exc}; keeping the links read before")
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
                if self.is_running(p):
                    self.say(f"{holder}: link {'replaced' if holder in tokens else 'revoked'}; its session stops")
                    self.stop_session(p)
                if holder not in tokens:
                    p.life.revoke()
            elif holder == EXPERIMENTER and holder in tokens:
                self.say("the experimenter's link was replaced: the old one and its browsers are refused")
        for holder, token in tokens.items():
            if self.access.check(token) != holder:
                self.access.issue(holder, token=token)
            if holder == EXPERIMENTER:
                self.experimenter_token = token
            elif holder not in self.participants:
                self._add_participant(holder)
            else:
                self.participants[holder].life.invited(self.rows(holder), self.planned(holder))

    def _add_participant(self, holder: str) -> "Participant":
        """A participant the server learns of (a link, or a folder of data): its life as its data say."""
        life = Life.from_data(self.rows(holder), self.planned(holder), invited=holder in (self._tokens or {}))
        p = self.participants[holder] = Participant(holder, life=life)
        return p


    # ---- participants' sessions ------------------------------------------------------------------

    async def _start_session(self, p: Participant) -> tuple[int, str] | None:
        """Start a participant's session (touch4d.web.served): None, or the status and page that say
        why not (the reason in the log, not on a page that faces the internet). Made in a thread: it
        writes and fsyncs its manifest and trials.csv, which on the loop held every other participant's
        frames while a wave of them joined."""
        try:
            p.session = await asyncio.to_thread(
                ServedSession, self.study, self.study_path, p.id, self.out, self.shared,
                send=lambda conn, frame: self.pages.send(conn, frame),
                broadcast=lambda frame, latest: self._to_page(p, frame, latest))
        except (Touch4dError, OSError) as exc:
            log.warning("%s: its session cannot start: %s", p.id, exc)
            p.life.stopped()
            return 500, f"touch4d: the session of {p.id} could not start; please tell the experimenter\n"
        self._schedule(p)
        return None

    def _to_page(self, p: Participant, frame: bytes, latest: bool) -> None:
        if p.conn is not None:
            self.pages.send(p.conn, frame, latest)

    def stop_session(self, p: Participant) -> None:
        """Its session ends: its page closed (it may come back), its log and manifest complete (the
        study keeps its rows)."""
        if p.leave is not None:
            p.leave.cancel()
            p.leave = None
        if p.tick is not None:
            p.tick.cancel()
        p.life.stopped()
        session, p.session = p.session, None
        if p.conn is not None:
            self.pages.close(p.conn)
        if session is not None:
            try:
                session.close()
            except (Touch4dError, OSError) as exc:
                log.warning("%s: its session did not close cleanly: %s", p.id, exc)

    def is_running(self, p: Participant) -> bool:
        return p.session is not None

    def running(self) -> int:
        """Participants whose session runs or is being made."""
        return sum(1 for p in self.participants.values() if p.session is not None or p.starting is not None)

    def _after(self, p: Participant) -> None:
        """After anything its session did: finished? its next deadline armed."""
        session = p.session
        if session is None:
            return
        if len(session.trials.rows) != p.rows_seen:     # a trial's row: it is under way (recruitment)
            p.rows_seen, p.since = len(session.trials.rows), time.time()
        if session.finished and p.life.state is State.RUNNING:
            p.life.finished()
            self.say(f"{p.id} is done: every trial has its row")
        self._schedule(p)

    def _schedule(self, p: Participant) -> None:
        """One timer per session, at its next deadline (touch4d.web.served: ServedSession.next_due;
        touch4d.deadline): a participant costs the loop its own deadlines only."""
        if p.tick is None:
            p.tick = Deadline(self._loop.call_later, time.time, lambda: self._tick(p))
        p.tick.arm(p.session.next_due())

    def _tick(self, p: Participant) -> None:
        if p.session is None:
            return
        try:
            p.session.tick()
        except (Touch4dError, OSError) as exc:   # its folder's disk full, its file gone: it stops, the rest go on
            self._failed(p, exc)
            return
        self._after(p)

    def _failed(self, p: Participant, exc: Exception) -> None:
        log.error("%s: its session stopped: %s", p.id, exc)
        self.say(f"{p.id}: its session stopped on an error (see the log); its link resumes it")
        self.stop_session(p)

    def command(self, participant: str, command: str, reason: str) -> None:
        """Pause or resume a participant's trials (on the server's loop)."""
        p = self.participants.get(participant)
        if p is not None and p.session is not None:
            p.session.command(command, reason)
            self._after(p)

    def tell(self, p: Participant, command: str | None, reason: str) -> None:
        """Carry out the command a life event returned (None: nothing to do)."""
        if command is not None:
            self.command(p.id, command, reason)

    # ---- the pages' WebSockets (touch4d.web.server.PageServer, mounted) ------------------------------

    def _page_opened(self, conn: int) -> None:
        holder = self.pages.holder(conn)
        p = self.participants.get(holder) if holder is not None else None
        if p is None or p.session is None:    # its session stopped between the upgrade and now
            self.pages.close(conn)
            return
        p.conn = conn
        self._by_conn[conn] = p
        p.last_heard = time.time()
        if p.leave is not None:
            p.leave.cancel()
            p.leave = None
        p.session.connected(conn, self.pages.peer(conn))
        if p.life.page_gone:   # the server's own pause (no page): the page back undoes it, not the experimenter's
            self.tell(p, p.life.page_opened(), "the participant's page is back")
            self.say(f"{p.id}: its page is back; " + ("its trial stays paused (by the experimenter)" if p.life.held
                                                         else "trial resumed"))
        self._after(p)

    def _page_message(self, conn: int, data, arrival: float) -> None:
        p = self._by_conn.get(conn)
        if p is None or p.session is None:
            return
        p.last_heard = arrival
        try:
            p.session.page_message(conn, data, arrival)
        except (Touch4dError, OSError) as exc:
            self._failed(p, exc)
            return
        self._after(p)

    def _page_closed(self, conn: int) -> None:
        p = self._by_conn.pop(conn, None)
        if p is None or p.conn != conn:
            return
        p.conn = None
        if p.session is None:
            return
        p.session.closed(conn)
        self.tell(p, p.life.page_closed(), "the participant's page closed")
        self.say(f"{p.id}: its page closed; paused (its session stops in {self.leave_after_s:g} s unless it comes "
                  "back)")
        p.leave = self._loop.call_later(self.leave_after_s, self._left, p)
        self._after(p)

    def _await_page(self, p: Participant) -> None:
        """A session just started: if no page of its participant connects within `leave_after_s` (at
        least `page_grace_s`, for a page loading on a slow headset), they have left (a place is not
        held forever by a join whose page never came)."""
        if p.conn is None and p.leave is None:
            p.leave = self._loop.call_later(max(self.leave_after_s, self.page_grace_s), self._left, p)

    def _left(self, p: Participant) -> None:
        p.leave = None
        if p.conn is None and self.is_running(p):
            self.counts["left"] += 1
            self.say(f"{p.id} left: its session stops (its link resumes it)")
            self.stop_session(p)

    # ---- HTTP ----------------------------------------------------------------------------------

    def say(self, text: str) -> None:
        """One line on the terminal (and the log) for what the experimenter follows: joins, leaves,
        pauses, refusals for a full study, shutdown."""
        print(f"{time.strftime('%H:%M:%S')} {text}", flush=True)
        log.info("%s", text)

    def log_once(self, cause: str, text: str) -> None:
        if cause not in self._logged:
            self._logged.add(cause)
            log.warning("%s (further ones are only counted)", text)

    @web.middleware
    async def _refusals(self, request: web.Request, handler):
        """The gate's 403 (a forged, expired or revoked token) counted and logged once."""
        self.load_invites()
        try:
            return await handler(request)
        except web.HTTPForbidden:
            if HOLDER in request:
                raise   # a holder refused something further (a mismatched id): counted there
            self.counts["forged"] += 1
            self.log_once("forged", f"refused a request with a forged, expired or revoked link ({request.path})")
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
                self.log_once(f"budget {holder}", f"{holder}: over {HOLDER_RATE:g} requests a second; "
                               "answering 429 for the rest")
                raise web.HTTPTooManyRequests(text="touch4d: too many requests; wait a second\n",
                                              headers={"Retry-After": "1"})
        return await handler(request)

    def participant(self, request: web.Request) -> Participant:
        holder = request[HOLDER]
        wanted = request.query.get("participant")
        if wanted is not None and wanted != holder:
            self.counts["mismatched"] += 1
            self.log_once("mismatched", f"refused a link whose participant id ({wanted[:32]!r}) is not its token's")
            raise web.HTTPForbidden(text="touch4d: this link's participant id does not match its token.\n")
        if holder == EXPERIMENTER:
            raise web.HTTPFound("/experimenter")
        p = self.participants.get(holder)
        if p is None:   # a holder the access layer knows is invited
            p = self._add_participant(holder)
        return p

    async def _index(self, request: web.Request) -> web.StreamResponse:
        p = self.participant(request)
        if p.life.state is State.DONE and self.options.complete_url:
            raise web.HTTPSeeOther(self.open_link.completion_url())   # back to the recruitment platform, with its code
        if self.is_running(p) and p.life.state in (State.RUNNING, State.DONE):
            return web.FileResponse(STATIC_DIR / "index.html")   # the WebXR page, its session's
        return web.Response(text=self._welcome(p), content_type="text/html")

    def _welcome(self, p: Participant) -> str:
        study = self.study
        rows = self.rows(p.id)
        paragraphs = lambda text: "".join(f"<p>{html.escape(t.strip())}</p>" for t in text.split("\n\n") if t.strip())  # noqa: E731
        go = "Continue" if rows else "Join"
        return (f"<!doctype html><html lang=en><head><meta charset=utf-8><meta name=viewport "
                f"content='width=device-width, initial-scale=1'><title>{html.escape(study.name)}</title></head><body>"
                f"<h1>{html.escape(study.description or study.name)}</h1>"
                + (f"<p>Welcome back: {rows} trials are done, the next one follows.</p>" if rows else "")
                + f"<h2>Consent</h2>{paragraphs(study.consent)}<h2>Instructions</h2>{paragraphs(study.instructions)}"
                "<p id=vibration role=alert hidden></p>"
                # the device check's vibration test (static/welcome.js), when the study file has device_check
                "<section id=check hidden><h2>Device check</h2><p id=check-text>Before you join, a short check: "
                "your device vibrates at random moments (on a headset: hold the right controller); after each, "
                "say whether you felt a vibration (on a headset: trigger for felt, grip for not felt).</p>"
                "<button id=check-start type=button>Start the check</button><p id=check-step aria-live=polite></p>"
                "<p id=check-answer hidden><button id=felt type=button>I felt it</button> "
                "<button id=not-felt type=button>I felt nothing</button></p></section>"
                f"<form method=post action=/join><button id=join type=submit>{go}</button></form>"
                "<form method=post action=/quit><button id=quit type=submit>Quit: I do not want to take part"
                "</button></form>"
                # the link's token out of the address bar; whether this browser can vibrate, before consent
                "<script src=/welcome.js></script></body></html>")

    async def _welcome_script(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC_DIR / "welcome.js")

    async def _device(self, request: web.Request) -> web.StreamResponse:
        """The welcome page's device check (before consent; touch4d.web.devicecheck): what this browser
        can vibrate, its frame rate and, when the study file has `device_check`, its answers to the
        vibration test, judged here; the answer says what to tell the participant, whether Join is open,
        and whether the test is still to run (`check`: its trials)."""
        p = self.participant(request)
        if cross_site(request):
            raise web.HTTPForbidden(text="touch4d: from another site refused\n")
        if (request.content_length or 0) > MAX_DEVICE_BODY:
            raise web.HTTPRequestEntityTooLarge(MAX_DEVICE_BODY, request.content_length)
        try:
            report = parse_report(await request.content.read(MAX_DEVICE_BODY + 1),
                                  request.headers.get("User-Agent", ""))
        except ValueError as exc:
            raise web.HTTPBadRequest(text=f"touch4d: {exc}\n") from None
        p.device = report
        vibration = "headset" if report["immersive"] else "gamepad" if report["rumble"] else "none"
        if vibration != p.vibration:
            p.vibration = vibration
            if vibration == "none":
                judged = "refused" if self.study.without_vibration == "refuse" else "allowed"
                self.say(f"{p.id}: its browser cannot vibrate ({judged} by the study's without_vibration)")
        check = self.study.device_check
        if check is None:
            refused = vibration == "none" and self.study.without_vibration == "refuse"
            text = "" if vibration != "none" else NO_VIBRATION_REFUSED if refused else NO_VIBRATION_ALLOWED
            return web.json_response({"vibration": vibration, "refused": refused, "text": text})
        why = failures(report, check)
        if why:
            return web.json_response({"vibration": vibration, "refused": True, "passed": False, "text": DEVICE_FAILED,
                                      "leave": self.options.return_url, **self._device_failed(p, why)})
        if not answered(report):
            return web.json_response({"vibration": vibration, "refused": True, "passed": None, "text": "",
                                      "check": {"trials": check.trials, "catch": check.catch}})
        p.passed = report["passed"] = True
        return web.json_response({"vibration": vibration, "refused": False, "passed": True, "text": ""})

    def _device_failed(self, p: Participant, why: list[str]) -> dict:
        """A device that fails the study's check: counted (once per participant), never a participant
        (an open-link visitor's id and link are freed, its platform id forgotten: it may try another device)."""
        if p.passed is not False:
            self.counts["device failed"] += 1
            self.say(f"{p.id}: its device failed the check ({'; '.join(why)})")
        p.passed = p.device["passed"] = False
        if self.free(p):
            return {"freed": True}
        return {}

    def free(self, p: Participant) -> bool:
        """An open-link participant with no folder (never joined) given up: its link and id free again."""
        if not p.opened or self.is_running(p) or session_dir(self.out, p.id).exists():
            return False
        self.invites.revoke(p.id)
        self.open_link.recruits.forget(p.id)
        self.load_invites()          # its cookies end
        self.participants.pop(p.id, None)
        self._budgets.pop(p.id, None)
        return True

    def _record(self, p: Participant) -> None:
        """What its device check measured and its recruitment platform's parameters, in its manifest."""
        fields = {}
        if p.device is not None:
            fields["device"] = p.device
        params = self.open_link.recruits.params_of(p.id)
        if params:
            fields["platform"] = params
        if fields and p.session is not None:
            try:
                update_manifest(p.session.directory, fields)
            except (Touch4dError, OSError) as exc:
                log.warning("%s: its manifest did not take its device and platform: %s", p.id, exc)

    async def _clock(self, request: web.Request) -> web.StreamResponse:
        """The server's clock (ms), for the welcome page's round trip and clock offset."""
        self.participant(request)
        return web.json_response({"time_ms": time.time() * 1000}, headers={"Cache-Control": "no-store"})

    def rows(self, participant: str) -> int:
        return rows_written(session_dir(self.out, participant))


    async def _join(self, request: web.Request) -> web.StreamResponse:
        p = self.participant(request)
        if p.vibration == "none" and self.study.without_vibration == "refuse":
            self.counts["no vibration"] += 1
            return web.Response(status=403, content_type="text/html", text=(
                "<!doctype html><html lang=en><meta charset=utf-8><title>Cannot vibrate</title><body><h1>This "
                f"browser cannot take part</h1><p>{html.escape(NO_VIBRATION_REFUSED)}</p></body></html>"))
        if self.study.device_check is not None and not p.passed and p.life.state is not State.DONE:
            return web.Response(status=403, content_type="text/html", text=(
                "<!doctype html><html lang=en><meta charset=utf-8><title>Device check</title><body><h1>The device "
                "check comes first</h1><p>Please open your link again and finish the device check.</p></body></html>"))
        if p.life.state is State.DONE and self.options.complete_url:
            raise web.HTTPSeeOther(self.open_link.completion_url())
        if p.starting is None:             # else a join already makes its session: wait with it
            p.starting = asyncio.ensure_future(self._start(p))   # on, even if this request's browser goes
            p.starting.add_done_callback(lambda _: setattr(p, "starting", None))
        refusal = await asyncio.shield(p.starting)
        if refusal is not None:
            status, text = refusal
            return web.Response(status=status, text=text, content_type="text/html" if status != 500 else "text/plain")
        raise web.HTTPSeeOther("/")

    async def _start(self, p: Participant) -> tuple[int, str] | None:
        """Start a participant's session unless it runs: None, or the status and page that say why not."""
        if self.is_running(p):
            return None
        if p.life.state is State.DONE:
            return 200, ("<!doctype html><html lang=en><meta charset=utf-8><title>Done</title><body><h1>Every "
                         "trial is done</h1><p>Thank you for taking part.</p></body></html>")
        if self.running() - 1 >= self.max_participants:    # itself (starting) not counted
            self.counts["full"] += 1
            self.say(f"{p.id}: refused, the study is full ({self.running() - 1} of {self.max_participants} "
                      "running; --max-participants to change)")
            return 503, ("<!doctype html><html lang=en><meta charset=utf-8><title>Full</title><body><h1>The "
                         "study is full right now</h1><p>Every place is taken. Please open your link again in a "
                         "few minutes.</p></body></html>")
        back = self.rows(p.id) > 0
        self.counts["resumed" if back else "joined"] += 1
        p.life.join()      # revoked links never get here (the gate refused them)
        refusal = await self._start_session(p)
        if refusal is not None:
            return refusal
        p.since = time.time()
        self._record(p)
        self.say(f"{p.id} {'is back' if back else 'joined'}; {self.running()} of {self.max_participants} running")
        self.tell(p, p.life.ready(), "the experimenter")   # held before: paused again at once
        self._after(p)
        self._await_page(p)
        return None

    # ---- the page's files and WebSocket (the open link, /done and /quit: touch4d.web.openlink) -------

    async def _static(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["path"]
        if name not in STATIC_NAMES:   # an over-long name, a folder, a `..`: never looked for
            raise web.HTTPNotFound(text="touch4d: no such file\n")
        p = self.participant(request)
        if not self.is_running(p):
            raise web.HTTPNotFound(text="touch4d: join first\n")
        return web.FileResponse(STATIC_DIR / name)

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        """The page's WebSocket: its participant's session's (touch4d.web.served), with the page
        server's bounds (message size, pacing, a heartbeat closing a page that vanished, slow
        readers closed); one page at a time per participant."""
        p = self.participant(request)
        if cross_site(request):
            raise web.HTTPForbidden(text="touch4d: WebSocket from another origin refused\n")
        if not self.is_running(p):
            raise web.HTTPNotFound(text="touch4d: join first\n")
        if p.conn is not None:
            self.counts["second page"] += 1
            self.log_once(f"second {p.id}", f"{p.id}: a second page refused while one is open")
            return web.Response(status=503, text="touch4d: this link is open in another page already; close it "
                                                 "and reload\n")
        return await self.pages.websocket(request)

    # ---- the experimenter's page: touch4d.web.experimenterpage ----------------------------------

    def planned(self, participant: str) -> int:
        """How many trials the participant's session has (its plan: a pure function of study and id)."""
        if participant not in self._plan_lengths:
            plan = (quick_plan if self.quick else plan_session)(self.study, participant)
            self._plan_lengths[participant] = len(plan)
        return self._plan_lengths[participant]


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


    def link(self, participant: str, token: str) -> str:
        return participant_link(self.base_url(), participant, token)

    # ---- running -------------------------------------------------------------------------------

    async def _serve(self) -> None:
        sock = self._socket or self._listen()     # bound before OUT is written
        self.experimenter_token = self.invites.issue(EXPERIMENTER, keep=True)
        if self.options.open_link:
            self.open_link.open()
        self.load_invites()
        self._adopt_folders()
        self._loop = asyncio.get_running_loop()
        self.pages.mount(self._loop)
        self.stopping = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._loop.add_signal_handler(sig, self.stopping.set)
        app = self.hardening.application([self._refusals, self.gate.middleware, self._budget])
        app.router.add_get("/", self._index)
        app.router.add_post("/join", self._join)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/static/{path:.*}", self._static)
        app.router.add_get("/welcome.js", self._welcome_script)
        app.router.add_post("/device", self._device)
        app.router.add_get("/clock", self._clock)
        self.open_link.add_routes(app)
        self.experimenter.add_routes(app)
        runner = self.hardening.runner(app)
        await runner.setup()
        site = web.SockSite(runner, sock)
        await site.start()
        freeze_startup_heap()   # the objects made so far: no full collection walks them again
        (self.out / SERVED).write_text(json.dumps({"url": self.base_url()}) + "\n")
        print(f"study {self.study.name}: serving {self.base_url()}/ for up to {self.max_participants} participants"
              f"{self._cap_note}; data in {self.out}", flush=True)
        if self.open_link.key is not None:
            print(f"open link: {self.base_url()}/open?key={self.open_link.key}", flush=True)
        print(f"experimenter page: {self.base_url()}/experimenter?token={self.experimenter_token}", flush=True)
        watch = asyncio.ensure_future(self._watch_invites())
        try:
            await self.stopping.wait()
        finally:
            watch.cancel()
            self.say(f"stopping: {self.running()} running participants' sessions stop (each resumes at its next "
                      "trial when its link is opened again)")
            for p in self.participants.values():
                if p.session is not None:
                    self.stop_session(p)
            await runner.cleanup()
            self.say("stopped")

    async def _watch_invites(self, period_s: float = 1.0) -> None:
        """A link revoked with `touch4d study invite --revoke` ends its session within `period_s`,
        whether or not anyone makes a request."""
        while True:
            await asyncio.sleep(period_s)
            self.load_invites()

    def _check_glove(self) -> subprocess.Popen | None:
        """Say on the terminal which tasks the participants' glove cannot tell (`study check --glove`,
        infotransfer.glove_task_warnings): seconds of simulation, in a process of its own at the lowest
        priority (in a thread of this one it would take the interpreter from the participants' loop)."""
        try:
            check = subprocess.Popen([sys.executable, "-m", "touch4d.cli", "study", "check", str(self.study_path),
                                      "--glove", self.options.session.glove], stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, text=True, preexec_fn=lambda: os.nice(19))
        except OSError as exc:
            log.warning("could not check the glove %s against the study's tasks: %s", self.options.session.glove, exc)
            return None

        def relay() -> None:
            for line in check.stdout:
                if line.startswith("warning:"):
                    self.say(line.rstrip("\n"))
            check.wait()
        threading.Thread(target=relay, name="glove-check", daemon=True).start()
        return check

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
        os.umask(0o077)         # what it writes: OUT holds personal data
        _refuse_shared(self.out)
        raise_file_limit()      # each participant holds a socket, its trials.csv, its log and its lock
        with self._claim_out(), self._listen() as self._socket:
            check = self._check_glove() if self.options.glove_check else None
            try:
                with asyncio.Runner(loop_factory=new_event_loop) as runner:   # uvloop's where installed
                    runner.run(self._serve())
            finally:
                if check is not None and check.poll() is None:
                    check.kill()
                    check.wait()
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


PARAM_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}\Z")
MAX_CODE_CHARS = 64


def _check_url(flag: str, url: str | None) -> str | None:
    """An http(s) address given on the command line, else ConfigError naming the flag."""
    if url is None:
        return None
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.netloc or not url.isprintable() or " " in url:
        raise ConfigError(COMMAND_LINE, flag, "an http:// or https:// address", got=url)
    return url


def recruit_options(args) -> dict:
    """ServeOptions' recruiting fields from `study serve`'s flags, checked (errors name the flag)."""
    for name in args.id_param:
        if not PARAM_NAME.match(name):
            raise ConfigError(COMMAND_LINE, "--id-param", "a query parameter's name: letters, digits, _ (at most 64)",
                              got=name)
    code = args.completion_code
    if code is not None and not (0 < len(code) <= MAX_CODE_CHARS and code.isprintable()):
        raise ConfigError(COMMAND_LINE, "--completion-code", f"1-{MAX_CODE_CHARS} printable characters", got=code)
    if code is not None and args.complete_url is None:
        raise ConfigError(COMMAND_LINE, "--completion-code", "--complete-url too (the code is appended to it)",
                          got=code)
    if args.max_total is not None and not args.open_link:
        raise ConfigError(COMMAND_LINE, "--max-total", "--open-link too (it caps what the open link admits)",
                          got=args.max_total)
    return {"open_link": args.open_link, "max_total": args.max_total, "id_params": tuple(args.id_param),
            "complete_url": _check_url("--complete-url", args.complete_url), "completion_code": code,
            "return_url": _check_url("--return-url", args.return_url)}


def participant_link(base_url: str, participant: str, token: str) -> str:
    """A participant's link (the experimenter's: /experimenter)."""
    if participant == EXPERIMENTER:
        return f"{base_url}/experimenter?token={token}"
    return f"{base_url}/?participant={quote(participant)}&token={token}"



"""Recruiting by one link for many (`touch4d study serve --open-link`), and leaving for the platform:
`/open?key=...` makes each visitor a participant of their own, the next free Pnn of the least-filled
counterbalancing row (touch4d.study.recruitment), and sends them to its link; a platform's id seen
before goes back to its participant; `/done` sends one who finished to `--complete-url` (with its
completion code), `/quit` one who leaves to `--return-url`. A part of the study server
(touch4d.web.studyserver.StudyServer), which holds the participants and their links."""
from __future__ import annotations

import hmac
import html
import time
from urllib.parse import quote, urlencode, urlsplit

from aiohttp import web

from touch4d.errors import ConfigError
from touch4d.study.participation import State
from touch4d.study.plan import order_table, participant_index
from touch4d.study.recruitment import (PENDING_S, PLATFORM_PARAMS, Place, Recruits, holds_row, identity,
                                       next_participant, platform_params, rows_filled)

from .access import HOLDER, cross_site
from .inbox import TokenBucket

OPEN_RATE, OPEN_BURST = 2.0, 20   # participants the open link makes per second (on average, at once)


class OpenLink:
    """The open link's key (OUT/recruits.json: the key, platform ids -> participants) and its routes."""

    def __init__(self, server):
        self.server = server   # the touch4d.web.studyserver.StudyServer whose participants it makes
        out = server.out
        try:
            self.recruits = Recruits(out)
        except ValueError as exc:
            raise ConfigError(out / "recruits.json", "(file)", "the open link's file as the server wrote it",
                              detail=str(exc)) from None
        self.key: str | None = None             # issued when it serves with --open-link
        self._budget = TokenBucket(OPEN_RATE, OPEN_BURST)
        self._param_names = tuple(dict.fromkeys((*PLATFORM_PARAMS, *server.options.id_params)))

    def open(self) -> None:
        self.key = self.recruits.open()

    def close(self) -> None:
        """No visitor is made a participant from now on (the experimenter's button)."""
        if self.key is not None:
            self.recruits.close()
            self.key = None

    def add_routes(self, app: web.Application) -> None:
        app.router.add_get("/open", self.visit)
        app.router.add_get("/done", self.done)
        app.router.add_post("/quit", self.quit)

    def places(self) -> list[Place]:
        return [Place(p.id, p.life.shown(), p.since) for p in self.server.participants.values()]

    def rows_filled(self) -> list[int]:
        """Each counterbalancing row's participants, done or under way (touch4d.study.recruitment)."""
        return rows_filled(len(order_table(self.server.study)), self.places(), lambda who: participant_index(self.server.study, who),
                           time.time(), self.server.leave_after_s)

    def _taken(self) -> set[str]:
        """Ids with a link or a folder (the open link never makes them again)."""
        try:
            folders = {d.name for d in self.server.out.iterdir()}
        except OSError:
            folders = set()
        return set(self.server.participants) | set(self.server.tokens()) | folders

    def page(self, status: int, title: str, text: str) -> web.Response:
        return web.Response(status=status, content_type="text/html", text=(
            f"<!doctype html><html lang=en><meta charset=utf-8><title>{html.escape(title)}</title><body>"
            f"<h1>{html.escape(title)}</h1><p>{html.escape(text)}</p></body></html>"))

    async def visit(self, request: web.Request) -> web.StreamResponse:
        """The open link (`--open-link`): a visitor becomes a participant of their own (the next id whose
        counterbalancing row is least filled) and goes to its link; a platform's id seen before goes
        to its participant's link again; the visitor's own cookie back to its page."""
        key = request.query.get("key", "")
        if self.key is None or not hmac.compare_digest(key.encode(), self.key.encode()):
            self.server.counts["forged"] += 1
            self.server.log_once("open", "refused a visit by an open link that is closed or not this server's")
            raise web.HTTPForbidden(text="touch4d: this study's open link is closed\n")
        holder = request.get(HOLDER)
        if holder in self.server.participants:          # this browser was here before: its own page
            raise web.HTTPSeeOther("/")
        if not self._budget.spend(time.monotonic()):
            self.server.counts["over budget"] += 1
            raise web.HTTPTooManyRequests(text="touch4d: too many visitors at once; wait a second\n",
                                          headers={"Retry-After": "1"})
        try:
            params = platform_params(request.query, self._param_names)
        except ValueError as exc:
            raise web.HTTPBadRequest(text=f"touch4d: {exc}\n") from None
        who = identity(params, self.server.options.id_params)
        known = self.recruits.participant_of(who)
        if known is not None:
            token = self.server.tokens().get(known)
            if token is None:
                return self.page(403, "Your place has ended", "Your place in this study was ended by the "
                                       "experimenter. Please contact them.")
            raise web.HTTPSeeOther(f"/?participant={quote(known)}&token={token}")
        self._free_stale()
        refusal = self._refusal()
        if refusal is not None:
            return refusal
        participant, row = next_participant(self.rows_filled(), self._taken())
        token = self.server.invites.issue(participant)
        if params:
            self.recruits.remember(who or f"{participant} (no platform id)", participant, params)
        self.server.load_invites()
        p = self.server.participants[participant]
        p.opened, p.since = True, time.time()
        self.server.counts["open link"] += 1
        self.server.say(f"{participant}: made by the open link (counterbalancing row {row + 1})")
        raise web.HTTPSeeOther(f"/?participant={quote(participant)}&token={token}")

    def _free_stale(self) -> None:
        """Open-link places given a link but never joined within PENDING_S freed (their ids reused, the
        links of OUT/invites.json bounded by the open link's rate times PENDING_S)."""
        stale = time.time() - PENDING_S
        for p in list(self.server.participants.values()):
            if p.opened and p.life.state is State.INVITED and p.since is not None and p.since < stale:
                self.server.free(p)

    def _refusal(self) -> web.Response | None:
        """Why the open link admits no one now (running at once, or the total reached), or None."""
        if self.server.running() >= self.server.max_participants:
            self.server.counts["full"] += 1
            return self.page(503, "The study is full right now", "Every place is taken. Please open the "
                                   "link again in a few minutes.")
        total = self.server.options.max_total
        now = time.time()
        if total is not None and sum(holds_row(place, now, self.server.leave_after_s) for place in self.places()) >= total:
            self.server.counts["total reached"] += 1
            self.server.log_once("total", f"the open link turned a visitor away: {total} participants done or under way "
                           "(--max-total)")
            return self.page(503, "The study has all its participants", "Thank you for your interest: "
                                   "this study needs no more participants.")
        return None

    def completion_url(self) -> str:
        """--complete-url with --completion-code appended as `cc` (Prolific's way)."""
        url, code = self.server.options.complete_url, self.server.options.completion_code
        if not code:
            return url
        return f"{url}{'&' if urlsplit(url).query else '?'}{urlencode({'cc': code})}"

    async def done(self, request: web.Request) -> web.StreamResponse:
        """Where the page goes when every trial is done: the platform's completion URL, or thanks."""
        p = self.server.participant(request)
        if p.life.state is not State.DONE:
            raise web.HTTPSeeOther("/")
        if self.server.options.complete_url:
            raise web.HTTPSeeOther(self.completion_url())
        return self.page(200, "Every trial is done", "Thank you for taking part.")

    async def quit(self, request: web.Request) -> web.StreamResponse:
        """The participant leaves the study (the welcome page's Quit): its session stops (its rows stay);
        an open-link place never joined is freed. Then the platform's return URL, or a page that says so."""
        p = self.server.participant(request)
        if cross_site(request):
            raise web.HTTPForbidden(text="touch4d: from another site refused\n")
        self.server.counts["quit"] += 1
        self.server.say(f"{p.id} quit")
        if self.server.is_running(p):
            self.server.stop_session(p)
        self.server.free(p)
        if self.server.options.return_url:
            raise web.HTTPSeeOther(self.server.options.return_url)
        return self.page(200, "You have left the study", "Thank you. You may close this page.")


"""The study server's page for the experimenter (`/experimenter`, its link's token only): every
participant's state, trial, frame rate and last message heard; pause, resume or revoke one, invite
one, close the open link; live by server-sent events (`/experimenter/events`) and every trial as
one CSV (`/experimenter/trials.csv`). A view of touch4d.web.studyserver.StudyServer, which owns the
participants: this module reads them and passes the experimenter's actions on."""
from __future__ import annotations

import asyncio
import csv
import html
import io
import json
import time

from aiohttp import web

from touch4d.study.plan import order_table
from touch4d.study.store import read_rows, session_dir

from .access import HOLDER, cross_site
from .invites import EXPERIMENTER, check_participant
from .server import STATIC_DIR

ACTIONS = ("pause", "resume", "revoke")   # the experimenter's buttons on each participant's row
# The experimenter's pages: participants' states, never cached; their address (once with the token) sent nowhere.
NO_STORE = {"Cache-Control": "no-store", "Referrer-Policy": "no-referrer"}
EVENTS_PERIOD_S = 1.0         # the experimenter page's events (server-sent), this often


class ExperimenterPage:
    """The experimenter's routes on the study server's application."""

    def __init__(self, server):
        self.server = server   # the touch4d.web.studyserver.StudyServer whose participants it shows

    def add_routes(self, app: web.Application) -> None:
        app.router.add_get("/experimenter", self.page)
        app.router.add_get("/experimenter.js", self.script)
        app.router.add_get("/experimenter/events", self.events)
        app.router.add_get("/experimenter/trials.csv", self.trials_csv)
        app.router.add_post("/experimenter/{action:%s}" % "|".join((*ACTIONS, "invite", "close-open")), self.action)

    def _only(self, request: web.Request) -> None:
        if request[HOLDER] != EXPERIMENTER:
            raise web.HTTPForbidden(text="touch4d: the experimenter's link only\n")

    def status(self) -> list[dict]:
        """Every participant: state (and who paused it), trials done of planned, the trial now, seconds
        since its page was last heard."""
        now = time.time()
        out = []
        for p in sorted(self.server.participants.values(), key=lambda p: p.id):
            t = p.session.trial if self.server.is_running(p) else None
            page = p.session.page if self.server.is_running(p) else {}
            rows = self.server.rows(p.id)
            out.append({"participant": p.id, "state": p.life.shown(), "paused_by": p.life.paused_by,
                        "vibration": p.vibration, "pages": p.pages,
                        "rows": rows, "planned": self.server.planned(p.id),
                        "trial": None if t is None or t.index < 0 else t.index + 1,
                        "of": None if t is None else t.total, "phase": None if t is None else t.phase,
                        "fps": page["fps"][-1] if page.get("fps") else None,
                        "counts": dict(p.session.counts) if self.server.is_running(p) else None,
                        "last_heard_s": None if not p.last_heard else round(now - p.last_heard, 1)})
        return out

    def table(self) -> str:
        """The participants' table (the experimenter's page, and what its script fetches each second)."""
        cell = lambda value, unit="": "-" if value is None else f"{html.escape(str(value))}{unit}"  # noqa: E731
        buttons = lambda who: "".join(  # noqa: E731
            f"<form method=post action=/experimenter/{action}><input type=hidden name=participant "
            f"value='{html.escape(who, quote=True)}'><button>{action}</button></form>" for action in ACTIONS)
        rows = "".join(
            f"<tr data-state={s['state']}><td>{html.escape(s['participant'])}</td>"
            f"<td>{s['state']}{'' if s['paused_by'] is None else ' by ' + html.escape(s['paused_by'])}</td>"
            f"<td>{s['rows']} of {s['planned']}</td><td>{cell(s['trial'])} of {cell(s['of'])}</td>"
            f"<td>{cell(s['phase'])}</td><td>{cell(s['vibration'])}</td><td>{cell(s['fps'])}</td>"
            f"<td>{cell(s['last_heard_s'], ' s')}</td>"
            f"<td>{'' if s['state'] == 'revoked' else buttons(s['participant'])}</td></tr>"
            for s in self.status())
        summary = self.summary()
        states = ", ".join(f"{n} {html.escape(state)}" for state, n in summary["states"].items()) or "none yet"
        orders = " ".join(f"{'/'.join(html.escape(c) for c in order)}: {n};"
                          for order, n in zip(order_table(self.server.study), summary["rows_filled"]))
        return (f"<p id=summary>{self.server.running()} of {self.server.max_participants} running; refused while full: "
                f"{self.server.counts['full']}; refused, cannot vibrate: {self.server.counts['no vibration']}</p>"
                f"<p id=recruitment>participants: {states}; trials done: {summary['trials_done']}; device check "
                f"failed: {self.server.counts['device failed']}; quit: {self.server.counts['quit']}; counterbalancing rows "
                f"filled (done or under way): {orders} <a href=/experimenter/trials.csv download>all trials "
                "(CSV)</a></p><table "
                "id=participants><tr><th>participant</th><th>state</th><th>trials done</th><th>trial now</th>"
                f"<th>phase</th><th>vibration</th><th>frame rate</th><th>last heard</th><th></th></tr>{rows}</table>")

    def summary(self) -> dict:
        """The study at a glance: participants by state, trials done, each counterbalancing row's
        participants (done or under way), the open link's state."""
        states: dict[str, int] = {}
        for p in sorted(self.server.participants.values(), key=lambda p: p.id):
            states[p.life.shown()] = states.get(p.life.shown(), 0) + 1
        return {"states": states, "trials_done": sum(self.server.rows(who) for who in self.server.participants),
                "rows_filled": self.server.open_link.rows_filled(), "open_link": self.server.open_link.key is not None}

    def view(self) -> dict:
        """The experimenter's page as data (?format=json, and each server-sent event)."""
        return {"participants": self.status(), "counts": self.server.counts, "running": self.server.running(),
                "max_participants": self.server.max_participants, "summary": self.summary()}

    async def page(self, request: web.Request) -> web.StreamResponse:
        self._only(request)
        form = request.query.get("format")
        if form == "json":
            return web.json_response(self.view(), headers=NO_STORE)
        if form == "table":
            return web.Response(content_type="text/html", text=self.table(), headers=NO_STORE)
        name = html.escape(self.server.study.name)
        return web.Response(content_type="text/html", headers=NO_STORE, text=(
            f"<!doctype html><html lang=en><meta charset=utf-8><meta name=referrer content=no-referrer>"
            f"<title>{name}: participants</title><body><h1>{name}: participants</h1><div id=live>{self.table()}</div>"
            f"<form method=post action=/experimenter/invite><input name=participant placeholder=P07>"
            f"<button>invite</button></form>"
            + ("<form method=post action=/experimenter/close-open><button>close the open link</button></form>"
               if self.server.open_link.key is not None else "")
            + "<script src=/experimenter.js></script></body></html>"))

    def _still_experimenter(self, request: web.Request) -> bool:
        """Whether the request's cookie (or token) is still the experimenter's (a replaced link ends it)."""
        cookie = request.cookies.get(self.server.gate.cookie)
        if cookie is not None and self.server.access.session_holder(cookie) == EXPERIMENTER:
            return True
        return self.server.access.check(request.query.get("token")) == EXPERIMENTER

    async def events(self, request: web.Request) -> web.StreamResponse:
        """The experimenter's page live (server-sent events, text/event-stream): the table and the data
        each EVENTS_PERIOD_S, until the page goes, its link is replaced, or the server stops."""
        self._only(request)
        response = web.StreamResponse(headers={**NO_STORE, "Content-Type": "text/event-stream",
                                               "X-Accel-Buffering": "no"})   # nginx: no buffering of the stream
        await response.prepare(request)
        try:
            while self._still_experimenter(request):
                event = json.dumps({**self.view(), "table": self.table()})
                await response.write(f"data: {event}\n\n".encode())
                try:
                    await asyncio.wait_for(self.server.stopping.wait(), EVENTS_PERIOD_S)
                    break
                except asyncio.TimeoutError:
                    pass
        except (ConnectionError, asyncio.CancelledError):
            pass
        return response

    async def trials_csv(self, request: web.Request) -> web.StreamResponse:
        """Every participant's trials.csv, one after another under one header (the columns of all)."""
        self._only(request)
        return web.Response(body=await asyncio.to_thread(self._all_trials), content_type="text/csv", charset="utf-8",
                            headers={**NO_STORE, "Content-Disposition": 'attachment; filename="trials.csv"'})

    def _all_trials(self) -> bytes:
        columns: dict[str, None] = {}
        rows: list[dict] = []
        for who in sorted(self.server.participants):
            header, theirs = read_rows(session_dir(self.server.out, who))
            columns.update(dict.fromkeys(header))
            rows += theirs
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(columns), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        return text.getvalue().encode()

    async def script(self, request: web.Request) -> web.StreamResponse:
        self._only(request)
        return web.FileResponse(STATIC_DIR / "experimenter.js", headers=NO_STORE)

    async def action(self, request: web.Request) -> web.StreamResponse:
        self._only(request)
        if cross_site(request):   # a form on another site posting with the experimenter's cookie
            self.server.log_once("cross-site", "refused an experimenter action posted from another site")
            raise web.HTTPForbidden(text="touch4d: actions from another site refused\n")
        form = await request.post()
        participant = str(form.get("participant", ""))
        action = request.match_info["action"]
        if action == "close-open":
            if self.server.open_link.key is not None:
                self.server.open_link.close()
                self.server.say("the open link was closed by the experimenter")
            raise web.HTTPSeeOther("/experimenter")
        if action == "invite":
            try:
                token = self.server.invites.issue(check_participant(participant))   # never the experimenter's
            except ValueError as exc:
                raise web.HTTPBadRequest(text=f"touch4d: {exc}\n") from None
            self.server.load_invites()
            link = self.server.link(participant, token)
            return web.Response(content_type="text/html", text=f"<!doctype html><p>{html.escape(link)}</p>"
                                                                 "<p><a href=/experimenter>back</a></p>")
        p = self.server.participants.get(participant)
        if p is None:
            raise web.HTTPNotFound(text="touch4d: no such participant\n")
        if action in ("pause", "resume"):
            self.server.tell(p, p.life.experimenter(action), "the experimenter")
        elif action == "revoke":
            self.server.invites.revoke(p.id)
            self.server.load_invites()       # ends its cookies and its session (it shows as revoked)
            self.server.say(f"{p.id}: link revoked by the experimenter")
        raise web.HTTPSeeOther("/experimenter")


"""The study server over HTTP on loopback (`touch4d study serve`, a real process): links, consent,
403 for a forged, revoked or mismatched link, 503 when full, a participant's session started on join
in the server's own process and driven over its page's WebSocket (a page without a browser: aiohttp)
to the last trial, a leave and a resume, a server killed and started again resuming everyone at the
first trial without a row, the experimenter's page."""
from __future__ import annotations

import asyncio
import csv
import http.cookiejar
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from contextlib import asynccontextmanager, contextmanager
from pathlib import Path

import aiohttp
import pytest

from touch4d.bus.testing import wait_until
from touch4d.cli import main as cli_main
from touch4d.study.design import load_study
from touch4d.study.plan import quick_plan
from touch4d.web.inbox import OTHER_RATE
from touch4d.web.protocol import unpack_frame
from touch4d.web.studyserver import PARTICIPANTS_PER_CORE

pytestmark = pytest.mark.timeout(240)

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"


class Served:
    """A `touch4d study serve` process and what it printed."""

    def __init__(self, proc, out: Path):
        self.proc, self.out = proc, out
        self.lines: list[str] = []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        wait_until(lambda: any(line.startswith("experimenter page:") for line in self.lines) or proc.poll() is not None,
                   timeout=60)
        text = "\n".join(self.lines)
        self.url = re.search(r"serving (http://\S+)/ for", text).group(1)
        self.experimenter = re.search(r"experimenter page: (\S+)", text).group(1)

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def text(self) -> str:
        return "\n".join(self.lines)


@contextmanager
def serve(tmp_path, *args, study=STUDY):
    """A served study (its glove's check at start left to test_study_serve_start: seconds of a core each)."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "study", "serve", study, "--out", str(out),
                             "--port", "0", "--quick", "--no-glove-check", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        yield Served(proc, out)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(30)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)   # whatever is left of its group
        except ProcessLookupError:
            pass
        proc.wait()


def invite(served, participant, *extra, capsys=None) -> str:
    assert cli_main(["study", "invite", str(served.out), participant, "--no-qr", *extra]) == 0
    return capsys.readouterr().out.strip().splitlines()[-1] if capsys else ""


def default_participants() -> int:
    """--max-participants' default: PARTICIPANTS_PER_CORE per core this process may use."""
    return PARTICIPANTS_PER_CORE * len(os.sched_getaffinity(0))


class Browser:
    """A cookie-keeping HTTP client: (status, text) for each request."""

    def __init__(self):
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))

    def get(self, url, data=None, timeout=120):
        try:
            with self.opener.open(url, data=data, timeout=timeout) as response:
                return response.status, response.read().decode()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read().decode()


def experimenter_view(served):
    status, text = Browser().get(served.experimenter.replace("/experimenter?", "/experimenter?format=json&"))
    assert status == 200
    return json.loads(text)


# ---- a participant's page without a browser: its link, Join, its WebSocket -----------------------------


@asynccontextmanager
async def joined(url: str, link: str, welcome: str = "id=join"):
    """A participant's browser: the link opened (its welcome holds `welcome`), Join pressed."""
    async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
        async with session.get(link) as response:
            assert response.status == 200 and welcome in await response.text()
        async with session.post(f"{url}/join", allow_redirects=False) as response:
            assert response.status == 303, (response.status, await response.text())
        yield session


@asynccontextmanager
async def page(url: str, link: str, welcome: str = "id=join"):
    """A participant's page: joined, the WebXR page's WebSocket open as a browser opens it (the
    cookie, this server's Origin)."""
    async with joined(url, link, welcome) as session, session.ws_connect(f"{url}/ws", origin=url) as ws:
        yield ws


async def study(ws, predicate, timeout: float = 30) -> dict:
    """Read the page's frames until the study's part of one satisfies `predicate`; that part."""
    async with asyncio.timeout(timeout):
        while True:
            msg = await ws.receive()
            if msg.type != aiohttp.WSMsgType.BINARY:
                raise AssertionError(f"the page's WebSocket ended: {msg.type!r} {msg.data!r}")
            header, _ = unpack_frame(msg.data)
            if header["kind"] == "frame" and header.get("study") and predicate(header["study"]):
                return header["study"]


async def respond(ws, index: int, option: str) -> None:
    """The page's answer button (its clock is this machine's: the server maps it all the same), within
    the page server's bound on a page's messages (more are dropped: touch4d.web.inbox)."""
    await ws.send_str(json.dumps({"type": "response", "index": index, "option": option, "time": time.time() * 1000}))
    await asyncio.sleep(1.5 / OTHER_RATE)


async def answer(ws, first: int, count: int) -> list[str]:
    """Answer trials first..first+count-1 in order, each with its first option (going on from a break
    before one); the options given."""
    given = []
    for index in range(first, first + count):
        shown = await study(ws, lambda s: s["index"] == index and s["phase"] in ("break", "stimulus"))
        if shown["phase"] == "break":
            await respond(ws, index, "go on")       # any answer ends a break
            shown = await study(ws, lambda s: s["index"] == index and s["phase"] == "stimulus")
        given.append(shown["options"][0])
        await respond(ws, index, given[-1])
    return given


def rows(out: Path, participant: str) -> list[dict]:
    """A participant's trials.csv, read here (not with the server's reader)."""
    with open(out / participant / "trials.csv", newline="") as f:
        return list(csv.DictReader(f))


def children(pid: int) -> list[str]:
    """The command lines of a process's children (every thread's)."""
    pids = [c for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()]
    return [Path(f"/proc/{c}/cmdline").read_bytes().replace(b"\0", b" ").decode() for c in pids]


# ---- tests ------------------------------------------------------------------------------------------------


def test_links_consent_and_refusals(tmp_path, capsys):
    with serve(tmp_path) as served:
        # no --max-participants: PARTICIPANTS_PER_CORE per core this process may use
        assert f"for up to {default_participants()} participants" in served.text
        link = invite(served, "P01", capsys=capsys)
        assert link.startswith(f"{served.url}/?participant=P01&token=")
        page = Browser()
        status, text = page.get(link)
        assert status == 200 and "By pressing Join you agree" in text and "enter VR" in text and 'id=join' in text
        # forged: 403, logged once however often
        for _ in range(3):
            assert Browser().get(f"{served.url}/?participant=P01&token=AAAAAAAAAAAAAAAAAAAAAA")[0] == 403
        # a participant id that is not its token's
        status, text = Browser().get(link.replace("participant=P01", "participant=P02"))
        assert status == 403 and "does not match" in text
        # revoked: the link and its cookie stop working
        assert cli_main(["study", "invite", str(served.out), "P01", "--revoke"]) == 0
        assert Browser().get(link)[0] == 403
        assert page.get(f"{served.url}/")[0] == 403
        view = experimenter_view(served)
        assert view["counts"]["forged"] >= 4 and view["counts"]["mismatched"] == 1
        # a new link works again
        assert Browser().get(invite(served, "P01", capsys=capsys))[0] == 200
    assert served.text.count("forged, expired or revoked") == 1
    assert oct((served.out / "invites.json").stat().st_mode & 0o777) == "0o600"


def test_join_starts_the_participants_session_in_the_server_and_a_second_is_refused_when_full(tmp_path, capsys):
    study = load_study(STUDY)
    with serve(tmp_path, "--max-participants", "1", "--leave-after", "600") as served:   # no page opens here
        p1, p2 = Browser(), Browser()
        assert p1.get(invite(served, "P01", capsys=capsys))[0] == 200
        assert p2.get(invite(served, "P02", capsys=capsys))[0] == 200
        status, text = p1.get(f"{served.url}/join", data=b"")
        assert status == 200 and '<canvas id="view">' in text          # the WebXR page
        assert p1.get(f"{served.url}/static/main.js")[0] == 200
        assert p2.get(f"{served.url}/static/main.js")[0] == 404         # not joined: no page yet
        status, text = p2.get(f"{served.url}/join", data=b"")
        assert status == 503 and "full" in text
        view = experimenter_view(served)
        states = {p["participant"]: p["state"] for p in view["participants"]}
        assert states == {"P01": "running", "P02": "invited"} and view["counts"]["full"] == 1
        # its session, in the server's own process: no process started for it (the glove's check, the server's
        # only other child, is off here), opened its folder and its first trial: the opening break
        assert children(served.proc.pid) == []
        manifest = json.loads((served.out / "P01" / "manifest.json").read_text())
        assert manifest["participant"] == "P01" and [s["pid"] for s in manifest["starts"]] == [served.proc.pid]
        (p01,) = [p for p in view["participants"] if p["participant"] == "P01"]
        assert p01["of"] == len(quick_plan(study, "P01")) and p01["trial"] == 1 and p01["phase"] == "break"
        # the experimenter pauses P01's session
        lab = Browser()
        assert lab.get(served.experimenter)[0] == 200
        assert lab.get(f"{served.url}/experimenter/pause", data=b"participant=P01")[0] == 200
        (p01,) = [p for p in experimenter_view(served)["participants"] if p["participant"] == "P01"]
        assert p01["phase"] == "paused" and p01["state"] == "paused" and p01["paused_by"] == "experimenter"
    # the terminal said each in a line: the join, the refusal while full, and the shutdown
    served.thread.join(10)          # its last lines read
    said = served.text.splitlines()
    assert any(re.match(r"\d\d:\d\d:\d\d P01 joined; 1 of 1 running", line) for line in said), served.text
    assert any(re.match(r"\d\d:\d\d:\d\d P02: refused, the study is full \(1 of 1 running", line) for line in said)
    assert any(line.endswith("stopping: 1 running participants' sessions stop (each resumes at its next trial when "
                             "its link is opened again)") for line in said), served.text
    assert said[-1].endswith(" stopped")


def test_a_full_study_over_the_pages_websocket_with_a_leave_and_a_resume(tmp_path, capsys):
    """A participant answers two trials, closes their page (paused, then left), comes back by their
    link (welcomed back, the next trial without a row again), and answers every trial: done, each
    trial one row with the answer given, a log per start; the link then says so."""
    planned = quick_plan(load_study(STUDY), "P01")
    with serve(tmp_path, "--leave-after", "2", "--iti", "0") as served:
        link = invite(served, "P01", capsys=capsys)

        def state():
            (p01,) = [p for p in experimenter_view(served)["participants"] if p["participant"] == "P01"]
            return p01

        async def run():
            async with page(served.url, link) as ws:
                given = await answer(ws, 0, 2)
                shown = await study(ws, lambda s: s["index"] == 2)        # the next trial is shown
            paused = await asyncio.to_thread(wait_until, lambda: (lambda p: p["state"] != "running" and p)(state()), 10)
            assert (paused["state"], paused["paused_by"]) == ("paused", "server (no page)")
            await asyncio.to_thread(wait_until, lambda: state()["state"] == "left", 10)
            assert len(rows(served.out, "P01")) == 2
            async with page(served.url, link, welcome="Welcome back: 2 trials are done") as ws:
                first = await study(ws, lambda s: s["phase"] in ("break", "stimulus"))
                given += await answer(ws, 2, len(planned) - 2)
                await study(ws, lambda s: s["phase"] == "done")
            return shown, first, given

        shown, first, given = asyncio.run(run())
        assert shown["phase"] in ("idle", "stimulus") and first["index"] == 2    # resumed where it left
        assert state()["state"] == "done"
        wait_until(lambda: served.text.count("P01 left: its session stops") == 2, timeout=10)   # its page gone
        written = rows(served.out, "P01")
        assert [int(r["index"]) for r in written] == [t.index for t in planned]
        assert [r["response"] for r in written] == given == [t.options[0] for t in planned]
        assert len(sorted((served.out / "P01").rglob("*.mcap"))) == 2       # one log per start
        resumed = [s["resumed_at"] for s in json.loads((served.out / "P01" / "manifest.json").read_text())["starts"]]
        assert resumed == [0, 2]
        done = Browser()
        assert done.get(link)[0] == 200
        status, text = done.get(f"{served.url}/join", data=b"")
        assert status == 200 and "Every trial is done" in text
    assert "P01 is done: every trial has its row" in served.text
    assert "P01 is back; 1 of" in served.text


def test_a_killed_server_loses_no_row_and_started_again_resumes_everyone_at_the_first_trial_without_one(tmp_path,
                                                                                                       capsys):
    links, answered = {}, {"P01": 3, "P02": 1}
    with serve(tmp_path, "--leave-after", "600", "--iti", "0") as served:
        for participant in answered:
            links[participant] = invite(served, participant, capsys=capsys)

        async def answering():
            async with page(served.url, links["P01"]) as one, page(served.url, links["P02"]) as two:
                await answer(one, 0, answered["P01"])
                await answer(two, 0, answered["P02"])
                await study(one, lambda s: s["index"] == answered["P01"])
                await study(two, lambda s: s["index"] == answered["P02"])
                served.proc.send_signal(signal.SIGKILL)                 # mid-session, pages open
                served.proc.wait()
        asyncio.run(answering())
    for participant, count in answered.items():                         # every row written survived
        assert [int(r["index"]) for r in rows(served.out, participant)] == list(range(count))
    with serve(tmp_path, "--leave-after", "600", "--iti", "0") as again:
        states = {p["participant"]: (p["state"], p["rows"]) for p in experimenter_view(again)["participants"]}
        assert states == {"P01": ("left", 3), "P02": ("left", 1)}

        async def resuming():
            firsts = {}
            for participant, count in answered.items():                   # the same links, the same tokens
                link = links[participant].replace(served.url, again.url)
                async with page(again.url, link, welcome=f"Welcome back: {count} trials are done") as ws:
                    firsts[participant] = await study(ws, lambda s: s["phase"] == "stimulus")
                    await answer(ws, count, 1)
                    await study(ws, lambda s: s["index"] == count + 1)
            return firsts
        firsts = asyncio.run(resuming())
        assert {p: s["index"] for p, s in firsts.items()} == answered
    for participant, count in answered.items():
        assert [int(r["index"]) for r in rows(again.out, participant)] == list(range(count + 1))


def test_the_experimenter_page_makes_and_revokes_links_and_only_for_the_experimenter(tmp_path, capsys):
    with serve(tmp_path) as served:
        lab = Browser()
        status, text = lab.get(served.experimenter)
        assert status == 200 and f"0 of {default_participants()} running" in text
        status, text = lab.get(f"{served.url}/experimenter/invite", data=b"participant=P09")
        link = re.search(r"(http://\S+participant=P09&amp;token=[\w-]+)", text).group(1).replace("&amp;", "&")
        participant = Browser()
        assert participant.get(link)[0] == 200
        assert participant.get(f"{served.url}/experimenter")[0] == 403          # a participant is not the lab
        assert lab.get(f"{served.url}/experimenter/invite", data=b"participant=experimenter")[0] == 400
        status, text = lab.get(f"{served.url}/experimenter/revoke", data=b"participant=P09")
        assert status == 200 and "P09" in text                                 # back on the list
        assert participant.get(f"{served.url}/")[0] == 403 and Browser().get(link)[0] == 403
        assert "P09" not in json.loads((served.out / "invites.json").read_text())

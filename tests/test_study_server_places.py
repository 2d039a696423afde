"""The study server's places, in process (the real server on loopback, each participant a session of
its own, pages without a browser: aiohttp): a link revoked with `touch4d study invite --revoke` or
replaced stops its session with no request made, a join whose page never connects gives its place
back, a page reloaded resumes only the server's pause, a session that cannot start says so without
the server's paths, an unreadable invites.json keeps the links read before instead of failing every
request, one link's flood is refused alone, and the experimenter's page."""
from __future__ import annotations

import asyncio
from pathlib import Path

import aiohttp
import pytest

from touch4d.cli import main as cli_main
from touch4d.study.design import load_study
from touch4d.study.lock import WRITER, SessionLock
from touch4d.web.invites import Invites
from touch4d.web.served import ServedOptions
from touch4d.web.studyserver import SERVED, ServeOptions, StudyServer

from test_study_serve import joined, page, study

pytestmark = pytest.mark.timeout(60)

STUDY = "config/studies/paper.yaml"
SESSION_OPTIONS = ("quick", "iti_s")     # _server's keywords for each participant's session (ServedOptions)


def _server(out, **kw) -> StudyServer:
    """The study server on any free port of loopback, as `study serve` makes it."""
    session = ServedOptions(**{k: kw.pop(k) for k in SESSION_OPTIONS if k in kw})
    return StudyServer(load_study(STUDY), STUDY, out, ServeOptions(port=0, session=session, **kw))


async def _until(predicate, timeout: float) -> bool:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            return False
        await asyncio.sleep(0.05)
    return True


def _serving(server: StudyServer, body) -> None:
    """Run `body(server)` (a coroutine function) while the server serves; stop it after (its
    participants' sessions stop as they do on SIGINT)."""
    async def main():
        serve = asyncio.ensure_future(server._serve())
        try:
            assert await _until(lambda: serve.done() or (server.out / SERVED).exists(), 30)
            if serve.done():
                serve.result()          # its failure, as it was raised
            await body(server)
        finally:
            if server.stopping is not None:
                server.stopping.set()
            await serve
    asyncio.run(main())


def _url(server: StudyServer) -> str:
    return f"http://127.0.0.1:{server.port}"


def _link(server: StudyServer, participant: str) -> str:
    """A participant's link, invited now (as `touch4d study invite` does) and adopted."""
    link = server.link(participant, Invites(server.out).issue(participant))
    server.load_invites()
    return link


async def _closed(ws, timeout: float = 10) -> bool:
    """Whether the server closes this page's WebSocket within `timeout` (its frames read meanwhile)."""
    try:
        async with asyncio.timeout(timeout):
            while (await ws.receive()).type == aiohttp.WSMsgType.BINARY:
                pass
    except TimeoutError:
        return False
    return True


def _state(server: StudyServer, participant: str) -> dict:
    return next(s for s in server.experimenter.status() if s["participant"] == participant)


def test_a_link_revoked_from_the_command_line_stops_its_session_without_a_request(tmp_path):
    server = _server(tmp_path)

    async def body(server):
        async with page(_url(server), _link(server, "P01")) as ws:
            await study(ws, lambda s: s["phase"] == "break")
            assert server.running() == 1
            assert cli_main(["study", "invite", str(tmp_path), "P01", "--revoke"]) == 0
            assert await _closed(ws), "the revoked participant's page is still served"
            assert await _until(lambda: server.running() == 0, 5), "the revoked participant's session still runs"
            assert _state(server, "P01")["state"] == "revoked"
    _serving(server, body)
    assert server.participants["P01"].session is None


def test_a_join_whose_page_never_connects_gives_its_place_back(tmp_path):
    server = _server(tmp_path, leave_after_s=0.1, page_grace_s=0.3)

    async def body(server):
        url = _url(server)
        async with joined(url, _link(server, "P01")), page(url, _link(server, "P02")) as stays:
            assert server.running() == 2
            assert await _until(lambda: server.running() == 1, 10), "a join without a page holds its place"
            assert _state(server, "P01")["state"] == "left" and server.counts["left"] == 1
            await asyncio.sleep(0.5)
            assert _state(server, "P02")["state"] == "running" and server.running() == 1
            await study(stays, lambda s: s["phase"] == "break")     # its page still served
    _serving(server, body)


def test_an_unreadable_invites_file_keeps_the_links_read_before(tmp_path):
    server = _server(tmp_path)
    token = Invites(tmp_path).issue("P01")

    async def body(server):
        url = _url(server)
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as page:
            async with page.get(f"{url}/?participant=P01&token={token}") as response:
                assert response.status == 200 and "id=join" in await response.text()
            (tmp_path / "invites.json").write_text("{not json")
            async with page.get(f"{url}/") as response:
                assert response.status == 200 and "id=join" in await response.text()
            async with page.get(f"{url}/?participant=P01&token={token}") as response:
                assert response.status == 200
            async with aiohttp.ClientSession() as stranger:
                async with stranger.get(f"{url}/?participant=P01&token=AAAAAAAAAAAAAAAAAAAAAA") as response:
                    assert response.status == 403
    _serving(server, body)


def test_the_experimenter_pauses_and_resumes_a_trial_and_the_page_shows_it(tmp_path):
    """A pause from the experimenter's page needs its way back: the participant's page has no resume."""
    server = _server(tmp_path)

    async def body(server):
        url = _url(server)
        async with page(url, _link(server, "P01")) as ws, \
                aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await study(ws, lambda s: s["phase"] == "break")
            async with lab.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
                assert response.status == 200 and "action=/experimenter/resume" in await response.text()
            for action, phase in (("pause", "paused"), ("resume", "break")):   # a break paused shows again
                async with lab.post(f"{url}/experimenter/{action}", data={"participant": "P01"}) as response:
                    assert response.status == 200
                await study(ws, lambda s: s["phase"] == phase)
            assert _state(server, "P01")["state"] == "running"
    _serving(server, body)


def test_a_page_reloaded_resumes_only_the_servers_pause_not_the_experimenters(tmp_path):
    """The page gone pauses the trial and the page back resumes it; a pause from the experimenter's
    page stays through the participant's reloads until the experimenter resumes it."""
    server = _server(tmp_path, leave_after_s=60)

    async def phases(ws, seconds: float) -> set[str]:
        """The study phases the page's frames show for `seconds` (the server repeats its last frame)."""
        seen = set()
        try:
            async with asyncio.timeout(seconds):
                while True:
                    seen.add((await study(ws, lambda s: True, timeout=seconds))["phase"])
        except TimeoutError:
            return seen

    async def body(server):
        url = _url(server)
        async with joined(url, _link(server, "P01")) as browser, \
                aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            async with browser.ws_connect(f"{url}/ws", origin=url) as ws:
                await study(ws, lambda s: s["phase"] == "break")
            assert await _until(lambda: _state(server, "P01")["paused_by"] == "server (no page)", 5)
            async with browser.ws_connect(f"{url}/ws", origin=url) as ws:     # back: the server resumes
                await study(ws, lambda s: s["phase"] == "break")
                assert _state(server, "P01")["state"] == "running"
                async with lab.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
                    assert response.status == 200
                async with lab.post(f"{url}/experimenter/pause", data={"participant": "P01"},
                                    headers={"Origin": url}) as response:
                    assert response.status == 200
                await study(ws, lambda s: s["phase"] == "paused")
            async with browser.ws_connect(f"{url}/ws", origin=url) as ws:     # the participant reloads
                assert await phases(ws, 1.0) == {"paused"}       # no resume: the experimenter's pause holds
                view = _state(server, "P01")
                assert view["state"] == "paused" and view["paused_by"] == "experimenter"
                async with lab.post(f"{url}/experimenter/resume", data={"participant": "P01"},
                                    headers={"Origin": url}) as response:
                    assert response.status == 200
                await study(ws, lambda s: s["phase"] == "break")
            assert server.participants["P01"].session.machine.counts["pauses"] == 2   # the server's, the experimenter's
    _serving(server, body)


def test_a_new_link_ends_what_the_old_one_opened(tmp_path):
    """Re-inviting a participant (a leaked or lost link) cuts off the old link's browsers and session."""
    server = _server(tmp_path)

    async def body(server):
        url = _url(server)
        old = _link(server, "P01")
        async with joined(url, old) as leaked, leaked.ws_connect(f"{url}/ws", origin=url) as ws:
            await study(ws, lambda s: s["phase"] == "break")
            assert cli_main(["study", "invite", str(tmp_path), "P01", "--no-qr", "--public-url", url]) == 0
            assert await _closed(ws), "the old link's page is still served"
            async with leaked.get(f"{url}/") as response:
                assert response.status == 403, "the old link's cookie still opens the page"
            assert await _until(lambda: server.running() == 0, 5), "the old link's session still runs"
        new = Invites(tmp_path).load()["P01"]
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as fresh:
            async with fresh.get(f"{url}/?participant=P01&token={new}") as response:
                assert response.status == 200 and "id=join" in await response.text()
        async with aiohttp.ClientSession() as stranger:
            async with stranger.get(old) as response:
                assert response.status == 403
    _serving(server, body)


def test_a_session_that_cannot_start_tells_the_participant_without_the_servers_paths(tmp_path, caplog):
    """The page faces the internet: where the server keeps its files is the experimenter's to read. P01's
    folder is a file; P02's is held by another writer (a `study run` on the same folder)."""
    server = _server(tmp_path)
    (tmp_path / "P01").write_text("not a folder\n")
    other = SessionLock(tmp_path / "P02", WRITER).acquire()

    async def body(server):
        url = _url(server)
        for participant in ("P01", "P02"):
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as browser:
                async with browser.get(_link(server, participant)) as response:
                    assert response.status == 200
                async with browser.post(f"{url}/join") as response:
                    text = await response.text()
                    assert response.status == 500 and f"the session of {participant} could not start" in text
                    assert str(tmp_path) not in text and "lock" not in text
        assert server.running() == 0
    try:
        _serving(server, body)
    finally:
        other.release()
    assert "P01: its session cannot start" in caplog.text and str(tmp_path / "P01") in caplog.text
    assert "P02: its session cannot start" in caplog.text and "another process" in caplog.text


def test_a_glove_or_calibration_that_cannot_be_read_fails_the_server_at_start(tmp_path, capsys):
    """Every participant's session shares them: a missing or broken file stops `study serve` before it
    serves anyone, naming the flag or the file and the key; OUT is not made."""
    broken = tmp_path / "glove.yaml"
    broken.write_text("no_such_key: 1\n")
    missing = str(tmp_path / "none.yaml")
    for flag, value, said in (("--glove", missing, "--glove"), ("--glove", str(broken), f"{broken}: key 'no_such_key'"),
                              ("--calibration", missing, "--calibration")):
        out = tmp_path / flag.strip("-")
        assert cli_main(["study", "serve", STUDY, "--out", str(out), "--port", "0", flag, value]) == 2
        err = capsys.readouterr().err
        assert said in err and "Traceback" not in err, err
        assert not out.exists()


def test_the_welcome_back_counts_whole_rows_as_the_study_node_does(tmp_path):
    """A row cut short by a crash is run again, so it is not done; a cell may hold a line break."""
    from touch4d.study.store import TrialsFile
    from touch4d.study.table import COLUMNS

    trials = TrialsFile(tmp_path / "P01" / "trials.csv")
    for index in range(3):
        trials.write({c: "" for c in COLUMNS} | {"index": index, "response": "left\nthen right"})
    trials.close()
    with open(tmp_path / "P01" / "trials.csv", "a") as f:
        f.write("P01,1,0,4,3")                                  # the fourth row, cut short
    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server.load_invites()
    assert "3 trials are done" in server._welcome(server.participants["P01"])
    assert len(TrialsFile(tmp_path / "P01" / "trials.csv").done) == 3     # the study node agrees


def _trials(out: Path, participant: str, rows: int) -> None:
    """A session folder whose trials.csv has `rows` whole rows (what a study node wrote before a restart)."""
    from touch4d.study.table import COLUMNS
    folder = out / participant
    folder.mkdir()
    lines = [",".join(COLUMNS)] + [",".join([participant, "1", "1", str(k), str(k)] + [""] * (len(COLUMNS) - 5))
                                   for k in range(rows)]
    (folder / "trials.csv").write_text("\n".join(lines) + "\n")


async def _experimenter(server, session: aiohttp.ClientSession, url: str) -> None:
    async with session.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
        assert response.status == 200


def test_the_experimenter_page_shows_each_participants_state_from_its_data_after_a_restart(tmp_path):
    """Restarted on an OUT with data: 7 trials done is 'left' (not 'invited'), every trial done is
    'done', a revoked link's data is 'revoked' (not gone); empty cells read '-'; the page refreshes
    itself from its script and keeps no token in the address."""
    from touch4d.study.plan import quick_plan
    study = load_study(STUDY)
    for participant in ("P01", "P02", "P04"):
        Invites(tmp_path).issue(participant)
    _trials(tmp_path, "P02", 7)
    _trials(tmp_path, "P03", 2)                       # its link revoked before the restart
    _trials(tmp_path, "P04", len(quick_plan(study, "P04")))
    server = _server(tmp_path, quick=True)

    async def body(server):
        url = _url(server)
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            async with lab.get(f"{url}/experimenter?format=json") as response:
                view = await response.json()
            states = {p["participant"]: (p["state"], p["rows"]) for p in view["participants"]}
            assert states == {"P01": ("invited", 0), "P02": ("left", 7), "P03": ("revoked", 2),
                              "P04": ("done", len(quick_plan(study, "P04")))}
            async with lab.get(f"{url}/experimenter") as response:
                page = await response.text()
                assert response.headers["Referrer-Policy"] == "no-referrer"
            assert "<script src=/experimenter.js></script>" in page and "<script>" not in page
            assert "<td>- of -</td>" in page and " of </td>" not in page and "None" not in page
            async with lab.get(f"{url}/experimenter.js") as response:
                script = await response.text()
                assert response.status == 200 and response.headers["Cache-Control"] == "no-store"
            assert 'history.replaceState(null, "", "/experimenter")' in script
            assert 'new EventSource("/experimenter/events")' in script      # live by server-sent events
            async with lab.get(f"{url}/experimenter?format=table") as response:
                table = await response.text()
            assert table.count("<tr data-state=") == 4 and "<tr data-state=revoked><td>P03</td>" in table
        async with aiohttp.ClientSession() as stranger:       # the table is the experimenter's alone
            async with stranger.get(f"{url}/experimenter?format=table") as response:
                assert response.status == 403
    _serving(server, body)


def test_experimenter_actions_posted_from_another_site_are_refused(tmp_path):
    server = _server(tmp_path)

    async def body(server):
        url = _url(server)
        async with joined(url, _link(server, "P01")), \
                aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            for headers in ({"Origin": "https://evil.example"}, {"Sec-Fetch-Site": "cross-site"},
                            {"Origin": "null"}):
                for action in ("pause", "revoke"):
                    async with lab.post(f"{url}/experimenter/{action}", data={"participant": "P01"},
                                        headers=headers, allow_redirects=False) as response:
                        assert response.status == 403, headers
            assert _state(server, "P01")["phase"] == "break" and "P01" in Invites(tmp_path).load()
            async with lab.post(f"{url}/experimenter/pause", data={"participant": "P01"},
                                headers={"Origin": url, "Sec-Fetch-Site": "same-origin"}) as response:
                assert response.status == 200
            assert _state(server, "P01")["phase"] == "paused"
    _serving(server, body)


def test_a_new_experimenter_link_ends_the_old_one_and_its_browsers(tmp_path, capsys):
    server = _server(tmp_path)

    async def body(server):
        url = _url(server)
        old = server.experimenter_token
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            assert cli_main(["study", "invite", str(tmp_path), "--experimenter", "--public-url", url, "--no-qr"]) == 0
            link = capsys.readouterr().out.strip().splitlines()[-1]
            assert link.startswith(f"{url}/experimenter?token=") and old not in link
            await asyncio.sleep(1.5)                         # the server reads invites.json again each second
            async with lab.get(f"{url}/experimenter?format=json") as response:
                assert response.status == 403                # the old link's cookie
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as fresh:
            async with fresh.get(f"{url}/experimenter?format=json&token={old}") as response:
                assert response.status == 403
            async with fresh.get(link.replace("/experimenter?", "/experimenter?format=json&")) as response:
                assert response.status == 200
    _serving(server, body)


def test_one_links_flood_gets_429_and_spares_the_others_and_a_running_session_starts_once(tmp_path):
    server = _server(tmp_path)
    loads = []
    load = server.invites.load
    server.invites.load = lambda: loads.append(1) or load()

    async def body(server):
        url = _url(server)
        links = {p: _link(server, p) for p in ("P01", "P02")}
        async with joined(url, links["P01"]) as one, \
                aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as other:
            async with other.get(links["P02"]) as response:
                assert response.status == 200
            loads.clear()

            async def join():
                async with one.post(f"{url}/join", allow_redirects=False) as response:
                    return response.status
            statuses = await asyncio.gather(*(join() for _ in range(300)))
            assert set(statuses) == {303, 429}, set(statuses)
            assert 20 <= statuses.count(303) <= 120      # the burst and what a second refills, no more
            assert server.running() == 1 and server.counts["joined"] == 1     # running: never started again
            async with other.get(f"{url}/") as response:
                assert response.status == 200            # the other link is not slowed by the flood
            assert loads == []                           # invites.json unchanged: not parsed again
            Invites(tmp_path).issue("P03")
            async with other.get(f"{url}/") as response:
                assert response.status == 200
            assert len(loads) == 1 and "P03" in server.participants
    _serving(server, body)
    manifest = (tmp_path / "P01" / "manifest.json").read_text()
    assert manifest.count('"resumed_at"') == 1                       # one start of its session

"""Recruiting online with the study server (a real `touch4d study serve` process, pages without a
browser: aiohttp): one open link makes a participant per visitor in counterbalancing order, keeps a
platform's ids in the manifest and sends the same platform id back to its participant; a finished
participant lands on the completion URL with its code, one who quits on the return URL; a device that
fails the study's check is not counted; the experimenter's page live by server-sent events, and every
trial as one CSV."""
from __future__ import annotations

import asyncio
import csv
import io
import json
import re
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import aiohttp
import pytest

from touch4d.bus.testing import wait_until
from touch4d.cli import main as cli_main
from touch4d.study.design import load_study
from touch4d.study.plan import order_table, quick_plan

from touch4d.study.recruitment import PENDING_S, Recruits
from touch4d.web.invites import EXPERIMENTER

from test_study_serve import answer, experimenter_view, invite, rows, serve, study
from test_study_server_places import _server, _serving

pytestmark = pytest.mark.timeout(240)

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"
COMPLETE = "https://app.prolific.com/submissions/complete"
BACK = "https://example.org/back"
CHROME_UA = "Mozilla/5.0 (X11; Linux x86_64) AppleWebKit/537.36 (KHTML, like Gecko) Chrome/120.0 Safari/537.36"


def open_link(served) -> str:
    wait_until(lambda: "open link: " in served.text, timeout=10)
    return re.search(r"open link: (\S+)", served.text).group(1)


def client() -> aiohttp.ClientSession:
    return aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True))


async def visit(session, url: str, **params) -> tuple[int, str]:
    """Open `url` (the open link, with a platform's parameters) without following: status, Location."""
    async with session.get(url, params=params, allow_redirects=False) as response:
        return response.status, response.headers.get("Location", "")


def participant_of(location: str) -> str:
    return parse_qs(urlsplit(location).query)["participant"][0]


async def welcome(served, session, location: str) -> str:
    async with session.get(served.url + location) as response:
        assert response.status == 200
        return await response.text()


async def report(served, session, **said) -> dict:
    body = {"immersive": True, "rumble": False, "fps": 72, **said}
    async with session.post(f"{served.url}/device", json=body, headers={"User-Agent": CHROME_UA}) as response:
        assert response.status == 200, await response.text()
        return await response.json()


async def join(served, session) -> int:
    async with session.post(f"{served.url}/join", allow_redirects=False) as response:
        return response.status


def test_the_open_link_makes_one_participant_per_visitor_in_counterbalancing_order_and_keeps_platform_ids(tmp_path):
    study_rows = len(order_table(load_study(STUDY)))
    with serve(tmp_path, "--open-link", "--leave-after", "2", "--max-total", "3", "--id-param", "workerId") as served:
        link = open_link(served)
        assert link.startswith(f"{served.url}/open?key=")

        async def run():
            async with client() as a, client() as b, client() as a_again, client() as c, client() as d, \
                    client() as e, client() as stranger:
                status, first = await visit(a, link, PROLIFIC_PID="5f00aa", STUDY_ID="s1", SESSION_ID="t1",
                                            other="dropped")
                assert status == 303 and first.startswith("/?participant=P01&token=")
                assert "Join" in await welcome(served, a, first)
                assert await visit(a, link, PROLIFIC_PID="5f00aa") == (303, "/")       # its own cookie: its page
                status, second = await visit(b, link, PROLIFIC_PID="5f00bb")
                assert participant_of(second) == "P02"                               # the next row
                # the same platform id from another browser: the same participant, the same link
                assert await visit(a_again, link, PROLIFIC_PID="5f00aa", SESSION_ID="t2") == (303, first)
                # P01 joins (its device told first: kept in its manifest), then answers no trial
                await report(served, a)
                assert await join(served, a) == 303
                await asyncio.sleep(2.5)          # no trial for --leave-after: its place holds no row now
                status, third = await visit(c, link, workerId="W3")
                assert participant_of(third) == f"P{study_rows + 1:02d}"     # row 1 again, P01 taken
                status, fourth = await visit(d, link)                        # no platform id at all
                assert participant_of(fourth) == "P03"
                # P02, P07 and P03 under way: --max-total 3 turns the next visitor away
                status, _ = await visit(e, link, PROLIFIC_PID="5f00ee")
                assert status == 503
                # a wrong key, a platform id that is not printable
                assert (await visit(stranger, link.replace("key=", "key=x")))[0] == 403
                assert (await visit(stranger, link, PROLIFIC_PID="a\x07b"))[0] == 400
        asyncio.run(run())
        view = experimenter_view(served)
        assert sorted(p["participant"] for p in view["participants"]) == ["P01", "P02", "P03", f"P{study_rows + 1:02d}"]
        assert view["counts"]["open link"] == 4 and view["counts"]["total reached"] == 1
        assert view["summary"]["rows_filled"][:3] == [1, 1, 1]
        manifest = json.loads((served.out / "P01" / "manifest.json").read_text())
        assert manifest["platform"] == {"PROLIFIC_PID": "5f00aa", "STUDY_ID": "s1", "SESSION_ID": "t1"}
        assert manifest["device"]["browser"] == "Chrome" and manifest["device"]["fps"] == 72
        recruits = json.loads((served.out / "recruits.json").read_text())
        assert {who: entry["participant"] for who, entry in recruits["platform"].items()} == {
            "PROLIFIC_PID=5f00aa": "P01", "PROLIFIC_PID=5f00bb": "P02", "workerId=W3": f"P{study_rows + 1:02d}"}
        assert not any("5f00" in path.name for path in served.out.rglob("*"))   # never in a file's name


def test_a_finished_participant_goes_to_the_completion_url_and_one_who_quits_to_the_return_url(tmp_path):
    planned = quick_plan(load_study(STUDY), "P01")
    with serve(tmp_path, "--open-link", "--iti", "0", "--complete-url", COMPLETE, "--completion-code", "C0DE42",
               "--return-url", BACK) as served:
        link = open_link(served)

        async def run():
            async with client() as session, client() as quitter:
                _, location = await visit(session, link, PROLIFIC_PID="5f01")
                await welcome(served, session, location)
                assert await join(served, session) == 303
                async with session.ws_connect(f"{served.url}/ws", origin=served.url) as ws:
                    await answer(ws, 0, len(planned))
                    await study(ws, lambda s: s["phase"] == "done")
                for path in ("/done", "/"):
                    async with session.get(served.url + path, allow_redirects=False) as response:
                        assert (response.status, response.headers["Location"]) == (303, f"{COMPLETE}?cc=C0DE42")
                assert await join(served, session) == 303
                # a second visitor reads the welcome page and quits: back to the platform, its id freed
                _, location = await visit(quitter, link, PROLIFIC_PID="5f02")
                assert participant_of(location) == "P02" and "id=quit" in await welcome(served, quitter, location)
                async with quitter.post(f"{served.url}/quit", allow_redirects=False) as response:
                    assert (response.status, response.headers["Location"]) == (303, BACK)
                async with quitter.get(f"{served.url}/", allow_redirects=False) as response:
                    assert response.status == 403                     # its link ended with its place
        asyncio.run(run())
        assert len(rows(served.out, "P01")) == len(planned)
        assert "P02" not in json.loads((served.out / "invites.json").read_text())
        assert not (served.out / "P02").exists()
        assert experimenter_view(served)["counts"]["quit"] == 1


def test_a_device_that_fails_the_check_is_not_a_participant_and_is_counted(tmp_path):
    checked = tmp_path / "checked.yaml"
    checked.write_text((REPO / STUDY).read_text() + "\ndevice_check: {trials: 4, catch: 2, min_hits: 3, "
                       "max_false_alarms: 0, min_fps: 30}\n")
    with serve(tmp_path, "--open-link", "--return-url", BACK, study=str(checked)) as served:
        link = open_link(served)

        async def run():
            async with client() as no_actuator, client() as slow, client() as good, client() as numb:
                _, location = await visit(no_actuator, link, PROLIFIC_PID="aa")
                assert participant_of(location) == "P01"
                await welcome(served, no_actuator, location)
                said = await report(served, no_actuator, immersive=False, rumble=False, haptics="none")
                assert said["passed"] is False and said["refused"] and said["leave"] == BACK
                assert "not been counted" in said["text"] and said["freed"]
                assert await join(served, no_actuator) == 403                 # its link ended
                # its id is free again: the next visitor is P01
                _, location = await visit(slow, link, PROLIFIC_PID="bb")
                assert participant_of(location) == "P01"
                await welcome(served, slow, location)
                assert (await report(served, slow, fps=20))["passed"] is False   # below min_fps
                # a capable device is asked for the test, and joins only once it passes
                _, location = await visit(good, link, PROLIFIC_PID="cc")
                await welcome(served, good, location)
                said = await report(served, good)
                assert said["check"] == {"trials": 4, "catch": 2} and said["refused"] and said["passed"] is None
                assert await join(served, good) == 403                        # the check comes first
                said = await report(served, good, trials=4, catch=2, hits=3, false_alarms=0, round_trip_ms=12.5,
                                    clock_offset_ms=-3.25)
                assert said["passed"] is True and not said["refused"]
                assert await join(served, good) == 303
                # one that felt too little fails
                _, location = await visit(numb, link, PROLIFIC_PID="dd")
                await welcome(served, numb, location)
                said = await report(served, numb, trials=4, catch=2, hits=2, false_alarms=0)
                assert said["passed"] is False
                # a report that is not the page's: 400
                async with good.post(f"{served.url}/device", json={"immersive": True, "rumble": False, "hits": 9,
                                                                    "trials": 4}) as response:
                    assert response.status == 400
            return participant_of(location)
        asyncio.run(run())
        view = experimenter_view(served)
        assert view["counts"]["device failed"] == 3
        assert [p["participant"] for p in view["participants"]] == ["P01"]
        assert sorted(d.name for d in served.out.iterdir() if d.is_dir()) == ["P01"]
        device = json.loads((served.out / "P01" / "manifest.json").read_text())["device"]
        assert (device["hits"], device["false_alarms"], device["passed"]) == (3, 0, True)
        assert (device["round_trip_ms"], device["clock_offset_ms"]) == (12.5, -3.25)
        assert set(json.loads((served.out / "invites.json").read_text())) == {"experimenter", "P01"}
    assert "P01: its device failed the check (no haptic actuator)" in served.text
    assert "frame rate 20 below 30" in served.text


def test_the_experimenter_page_is_live_by_server_sent_events_and_gives_every_trial_as_one_csv(tmp_path, capsys):
    with serve(tmp_path, "--iti", "0", "--leave-after", "600") as served:
        links = {who: invite(served, who, capsys=capsys) for who in ("P01", "P02")}

        async def events(lab, count: int) -> list[dict]:
            seen = []
            async with lab.get(f"{served.url}/experimenter/events") as response:    # its cookie, as EventSource
                assert response.status == 200 and response.content_type == "text/event-stream"
                assert response.headers["Cache-Control"] == "no-store"
                async with asyncio.timeout(30):
                    async for line in response.content:
                        if line.startswith(b"data: "):
                            seen.append(json.loads(line[len(b"data: "):]))
                            if len(seen) == count:
                                return seen
            return seen

        async def run():
            async with client() as lab, client() as one, client() as two:
                async with lab.get(served.experimenter) as response:               # the page: its cookie
                    assert response.status == 200 and "/experimenter.js" in await response.text()
                first, = await events(lab, 1)
                assert {p["participant"]: p["state"] for p in first["participants"]} == {"P01": "invited",
                                                                                        "P02": "invited"}
                assert "<table id=participants>" in first["table"] and "trials.csv" in first["table"]
                for session, who, count in ((one, "P01", 2), (two, "P02", 1)):
                    async with session.get(links[who]) as response:
                        assert response.status == 200
                    assert await join(served, session) == 303
                    async with session.ws_connect(f"{served.url}/ws", origin=served.url) as ws:
                        await answer(ws, 0, count)
                        await study(ws, lambda s, count=count: s["index"] == count)
                later = (await events(lab, 2))[-1]
                assert later["summary"]["trials_done"] == 3 and later["summary"]["states"]
                assert {p["participant"]: p["rows"] for p in later["participants"]} == {"P01": 2, "P02": 1}
                # a participant's cookie is not the experimenter's
                async with one.get(f"{served.url}/experimenter/events") as response:
                    assert response.status == 403
                async with one.get(f"{served.url}/experimenter/trials.csv") as response:
                    assert response.status == 403
                async with lab.get(f"{served.url}/experimenter/trials.csv") as response:
                    assert response.status == 200 and response.headers["Cache-Control"] == "no-store"
                    text = await response.text()
                # a replaced experimenter's link ends its stream
                async with lab.get(f"{served.url}/experimenter/events") as response:
                    assert response.status == 200
                    assert cli_main(["study", "invite", str(served.out), "--experimenter", "--no-qr"]) == 0
                    async with asyncio.timeout(10):
                        await response.content.read()                # the server ends it
            return text
        text = asyncio.run(run())
    table = list(csv.DictReader(io.StringIO(text)))
    header = (served.out / "P01" / "trials.csv").read_text().splitlines()[0]
    assert text.splitlines()[0] == header and text.count(header) == 1          # one header
    assert [(r["participant"], r["index"]) for r in table] == [("P01", "0"), ("P01", "1"), ("P02", "0")]
    assert [r["response"] for r in table] == [r["response"] for who in ("P01", "P02") for r in rows(served.out, who)]


@pytest.mark.parametrize("flags, named", [
    (["--completion-code", "C0DE"], "--completion-code"),                       # without --complete-url
    (["--complete-url", "javascript:alert(1)"], "--complete-url"),
    (["--return-url", "ftp://example.org/"], "--return-url"),
    (["--max-total", "5"], "--max-total"),                                      # without --open-link
    (["--open-link", "--id-param", "a b"], "--id-param"),
    (["--complete-url", COMPLETE, "--completion-code", "tab\there"], "--completion-code"),
])
def test_recruiting_flags_are_checked_before_anything_is_served(tmp_path, capsys, flags, named):
    out = tmp_path / "out"
    assert cli_main(["study", "serve", STUDY, "--out", str(out), "--port", "0", *flags]) == 2
    assert named in capsys.readouterr().err and not out.exists()


def test_a_place_never_joined_is_freed_after_a_while_and_the_experimenter_closes_the_open_link(tmp_path):
    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        link = f"{url}/open?key={server.open_link.key}"
        async with client() as a, client() as b, client() as lab, client() as late:
            _, first = await visit(a, link, PROLIFIC_PID="x1")
            assert participant_of(first) == "P01"
            server.participants["P01"].since -= PENDING_S + 1           # its link not joined for ten minutes
            _, second = await visit(b, link, PROLIFIC_PID="x2")
            assert participant_of(second) == "P01" and second != first    # its id again, a new link
            assert Recruits(server.out).participant_of("PROLIFIC_PID=x1") is None
            async with a.get(url + first, allow_redirects=False) as response:
                assert response.status == 403                             # the stale link ended
            async with lab.get(server.link(EXPERIMENTER, server.experimenter_token)) as response:
                assert "close the open link" in await response.text()
            async with lab.post(f"{url}/experimenter/close-open", allow_redirects=False) as response:
                assert response.status == 303
            assert (await visit(late, link, PROLIFIC_PID="x3"))[0] == 403
            assert Recruits(server.out).key is None
    _serving(_server(tmp_path / "out", open_link=True, quick=True), body)

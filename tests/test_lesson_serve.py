"""`touch4d lesson serve` over HTTP and WebSockets (no browser): the links, the class link making each
browser a student of its own, the terminal's command reaching every page at once, the bounds it shares
with the page server (Host, headers, origin, the class's size, each link's budget) and revocation."""
from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

import aiohttp
import pytest

from touch4d.web.lessonserver import send_command
from touch4d.web.protocol import unpack_frame

REPO = Path(__file__).resolve().parents[1]
SCENE = "config/scenes/hypercube.yaml"
pytestmark = pytest.mark.timeout(120)


class Served:
    def __init__(self, proc, out: Path, lines: list[str]):
        self.proc, self.out, self.lines = proc, out, lines
        self.teacher = next(re.sub("^teacher link: ", "", l) for l in lines if l.startswith("teacher link: "))
        self.klass = next(re.sub("^class link: ", "", l) for l in lines if l.startswith("class link: "))
        self.base = f"{urlsplit(self.teacher).scheme}://{urlsplit(self.teacher).netloc}"


@contextmanager
def served_lesson(tmp_path, *args, scene=SCENE):
    """`touch4d lesson serve` until its links are printed; stopped (its process group) afterwards."""
    out = tmp_path / "lesson"
    proc = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "lesson", "serve", scene, "--out", str(out),
                             "--port", "0", *args], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while not any(l.startswith("class link: ") for l in lines):
            line = proc.stdout.readline()
            if not line or time.monotonic() > deadline:
                raise AssertionError("the lesson printed no links:\n" + "".join(lines))
            lines.append(line.rstrip("\n"))
        yield Served(proc, out, lines)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(20)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
        proc.stdout.close()


async def open_page(session: aiohttp.ClientSession, link: str):
    """A browser opening `link` and its WebSocket: the page's answer and the socket."""
    async with session.get(link) as page:
        body = await page.text()
    base = f"ws://{urlsplit(link).netloc}"
    ws = await session.ws_connect(f"{base}/ws", headers={"Origin": f"http://{urlsplit(link).netloc}"})
    return page, body, ws


async def frames_until(ws, predicate, timeout=10.0):
    """Frames from `ws` until one satisfies predicate(fields); returns (fields, arrays, kinds seen)."""
    kinds = []
    async with asyncio.timeout(timeout):
        async for msg in ws:
            if msg.type != aiohttp.WSMsgType.BINARY:
                raise AssertionError(f"the socket ended: {msg.type} {msg.data!r}")
            fields, arrays = unpack_frame(msg.data)
            kinds.append(fields["kind"])
            if predicate(fields):
                return fields, arrays, kinds
    raise AssertionError(f"the socket closed; frames seen: {kinds}")


async def drain(ws) -> None:
    """Read `ws` until it closes (a browser reads all the time, and so answers pings)."""
    async for _ in ws:
        pass


def browser() -> aiohttp.ClientSession:
    """A client keeping cookies as a browser does (for 127.0.0.1 too)."""
    return aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True))


def run(coro):
    return asyncio.run(coro)


def test_links_pages_and_a_terminal_command_that_every_page_shows(tmp_path):
    with served_lesson(tmp_path) as lesson:
        assert (lesson.out / "invites.json").stat().st_mode & 0o077 == 0
        assert (lesson.out.stat().st_mode & 0o077) == 0

        async def scenario():
            async with browser() as teacher, browser() as one, \
                    browser() as two:
                page, body, t_ws = await open_page(teacher, lesson.teacher)
                assert page.status == 200 and 'src="/static/lesson.js"' in body
                assert "frame-ancestors 'none'" in page.headers["Content-Security-Policy"]
                assert "Server" not in page.headers
                # the class link: a student of its own (its own token, then its own cookie)
                async with one.get(lesson.klass, allow_redirects=False) as moved:
                    assert moved.status == 302 and "token=" in moved.headers["Location"]
                    assert urlsplit(moved.headers["Location"]).query != urlsplit(lesson.klass).query
                _, _, s1 = await open_page(one, lesson.klass)
                _, _, s2 = await open_page(two, lesson.klass)
                for ws in (t_ws, s1, s2):
                    setup, _, kinds = await frames_until(ws, lambda f: f["kind"] == "frame")
                    assert kinds[:3] == ["setup", "geometry", "frame"]
                lessons = [await frames_until(ws, lambda f: f["kind"] == "lesson") for ws in (s1, s2)]
                assert [f["role"] for f, _, _ in lessons] == ["student", "student"]
                assert lessons[0][0]["name"] != lessons[1][0]["name"]
                sent = time.time()
                ok, text = await send_command(lesson.out, "slice", "1.25")
                assert ok, text
                for ws in (s1, s2, t_ws):
                    frame, _, _ = await frames_until(ws, lambda f: f["kind"] == "frame" and f["slice_w"] == 1.25)
                took = time.time() - sent
                assert took < 1.0, f"the command reached the pages {took:.3f} s after it was sent"
                ok, text = await send_command(lesson.out, "rotate", "qq 5")
                assert not ok and "expected PLANE DEG" in text
                # a late joiner: the current state at once
                async with browser() as three:
                    _, _, s3 = await open_page(three, lesson.klass)
                    frame, _, kinds = await frames_until(s3, lambda f: f["kind"] == "frame")
                    assert kinds[:3] == ["setup", "geometry", "frame"] and frame["slice_w"] == 1.25
                    await s3.close()
                for ws in (t_ws, s1, s2):
                    await ws.close()

        run(scenario())


def test_the_command_line_says_what_is_wrong(tmp_path, capsys, monkeypatch):
    from types import SimpleNamespace

    from touch4d.cli import main

    monkeypatch.chdir(REPO)

    def cli(*args):   # in this process: the command line's own parsing and errors, without an interpreter's start
        code = main(["lesson", *args])
        said = capsys.readouterr()
        return SimpleNamespace(returncode=code, stdout=said.out, stderr=said.err)

    missing = cli("serve", "no/such/scene.yaml", "--out", str(tmp_path / "x"))
    assert missing.returncode == 2 and "no/such/scene.yaml" in missing.stderr
    bad_students = cli("serve", SCENE, "--out", str(tmp_path / "x"), "--max-students", "0")
    assert bad_students.returncode == 2 and "--max-students" in bad_students.stderr
    nowhere = cli("command", str(tmp_path / "none"), "next")
    assert nowhere.returncode == 2 and "lesson.json" in nowhere.stderr
    verb = cli("command", str(tmp_path / "none"), "fly")
    assert verb.returncode == 2 and "VERB" in verb.stderr and "rotate" in verb.stderr
    shared = tmp_path / "shared"
    shared.mkdir(mode=0o777)
    shared.chmod(0o777)
    refused = cli("serve", SCENE, "--out", str(shared))
    assert refused.returncode == 2 and "chmod go-w" in refused.stderr
    with served_lesson(tmp_path) as lesson:
        ok = cli("command", str(lesson.out), "view", "both")
        assert ok.returncode == 0 and "lesson: view both" in ok.stdout
        wrong = cli("command", str(lesson.out), "slice", "deep")
        assert wrong.returncode == 2 and "slice: expected where to cut" in wrong.stdout


def test_the_bounds_it_shares_with_the_page_server(tmp_path):
    with served_lesson(tmp_path, "--max-students", "1") as lesson:
        async def scenario():
            port = urlsplit(lesson.base).port
            async with browser() as anyone:
                async with anyone.get(f"{lesson.base}/?token=forged-forged-forged-forged") as forged:
                    assert forged.status == 403
                async with anyone.get(lesson.teacher, headers={"Host": f"rebound.example:{port}"}) as rebound:
                    assert rebound.status == 421            # DNS rebinding
            async with browser() as one, browser() as two:
                _, _, s1 = await open_page(one, lesson.klass)
                await frames_until(s1, lambda f: f["kind"] == "frame")
                await two.get(lesson.klass)
                with pytest.raises(aiohttp.WSServerHandshakeError) as full:
                    await two.ws_connect(f"ws://{urlsplit(lesson.base).netloc}/ws")
                assert full.value.status == 503             # the class is full
                with pytest.raises(aiohttp.WSServerHandshakeError) as hijack:
                    await one.ws_connect(f"ws://{urlsplit(lesson.base).netloc}/ws",
                                         headers={"Origin": "https://evil.example"})
                assert hijack.value.status == 403           # another site's page
                await s1.close()
            async with browser() as flood:
                statuses = [(await flood.get(lesson.teacher)).status for _ in range(40)]
            assert statuses[0] == 200 and 429 in statuses    # the teacher link's budget
            async with browser() as student:
                assert (await student.get(lesson.klass)).status == 200   # another link's budget is its own
        run(scenario())


def test_a_removed_student_and_a_replaced_class_link_are_refused(tmp_path):
    with served_lesson(tmp_path) as lesson:
        async def scenario():
            async with browser() as one, browser() as teacher:
                _, _, s1 = await open_page(one, lesson.klass)
                _, _, t_ws = await open_page(teacher, lesson.teacher)
                await frames_until(s1, lambda f: f["kind"] == "frame")
                # both pages read on (and answer the server's pings) from now on
                readers = [asyncio.ensure_future(drain(ws)) for ws in (s1, t_ws)]
                # one student removed by name: their page closes, their link and cookie refused; the others stay
                async with browser() as bo:
                    _, _, s2 = await open_page(bo, lesson.klass)
                    await s2.send_str(json.dumps({"type": "hello", "name": "Bo"}))
                    await frames_until(s2, lambda f: f["kind"] == "lesson" and f["name"] == "Bo")
                    removing = asyncio.ensure_future(drain(s2))
                    ok, text = await send_command(lesson.out, "remove", "Bo")
                    assert ok, text
                    await asyncio.wait_for(removing, 5)
                    assert s2.close_code == 1008
                    assert (await bo.get(f"{lesson.base}/")).status == 403
                assert not s1.closed
                # (not blocking the loop: the pages keep answering the server's pings meanwhile)
                revoke = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "touch4d.cli", "lesson", "revoke", str(lesson.out), "class", cwd=REPO,
                    stdout=asyncio.subprocess.PIPE)
                stdout = (await asyncio.wait_for(revoke.communicate(), 60))[0].decode()
                assert revoke.returncode == 0 and "class link: " in stdout
                new_link = stdout.split("class link: ")[1].strip()
                await asyncio.wait_for(readers[0], 5)
                assert s1.close_code == 1008                # closed for its access (not for silence)
                async with browser() as late:
                    assert (await late.get(lesson.klass)).status == 403
                    assert (await late.get(new_link)).status == 200
                assert not t_ws.closed                      # the teacher stays
                await t_ws.close()
                await readers[1]
        run(scenario())


def test_a_launch_file_gives_its_scene_and_its_webxr_nodes_glove():
    from touch4d.commands.lesson import lesson_inputs
    from touch4d.geometry.scene import load_scene

    scene, glove = lesson_inputs("launch/quest.yaml", None)
    assert glove == "config/gloves/quest-controller.yaml"          # tracker.params.glove of launch/quest.yaml
    assert [o.name for o in scene.objects] == [o.name for o in load_scene(SCENE).objects]
    assert lesson_inputs("launch/quest.yaml", "config/glove.yaml")[1] == "config/glove.yaml"

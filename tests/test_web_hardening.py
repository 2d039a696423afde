"""The bounds both web servers share (touch4d.web.hardening), probed on the study server on loopback as
an attacker would (raw sockets, bounded in count and time): slow connections from one address capped
and closed, Host names it does not serve, the security headers and no banner on every answer,
request paths escaped in the log and no aiohttp traceback; the file limit raised. Then what a
participant's page is served (its files only, one page at a time, from this site only), the logs
(capped, never written through a symlink), OUT (refused when others may write to it, its files the
owner's), and a page server's secret (nothing but its holder gets its page or WebSocket)."""
from __future__ import annotations

import asyncio
import json
import logging
import os
import resource
import stat
import subprocess
import sys

import aiohttp
import pytest

from touch4d.bus import Executor
from touch4d.bus import logfiles
from touch4d.bus.container import Container
from touch4d.bus.logfiles import CappedLog, GroupLog
from touch4d.bus.pool import ContainerPool
from touch4d.web.invites import Invites
from touch4d.web.server import SECRET_HEADER

from test_study_serve import REPO, STUDY, joined, respond, serve as serve_cli, study
from test_study_server_places import _link, _server, _serving, _url
from test_web_limits import headers_of, raw, serve, status_of  # noqa: F401 - serve: the page server fixture

pytestmark = pytest.mark.timeout(120)

UPGRADE = ("Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
           "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n")


def request(path: str, host: str, extra: str = "") -> bytes:
    return f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n{extra}\r\n".encode()


# ---- the study server's bounds ------------------------------------------------------------------------


def test_slow_connections_from_one_address_are_capped_and_closed_and_a_real_request_is_served(tmp_path):
    server = _server(tmp_path)
    server.hardening.limit_loopback = True     # as an internet client's (a loopback one is a reverse proxy's)
    server.hardening.max_per_address, server.hardening.header_timeout_s = 8, 0.5

    async def body(server):
        loop = asyncio.get_running_loop()
        conns = []
        for _ in range(40):                     # each a header begun and never finished
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            conns.append((reader, writer))
        started = loop.time()

        async def closed(reader) -> float | None:
            try:
                await asyncio.wait_for(reader.read(), 10)
            except asyncio.TimeoutError:
                return None
            except ConnectionError:
                pass
            return loop.time() - started
        held = await asyncio.gather(*(closed(r) for r, _ in conns))
        for _, writer in conns:
            writer.close()
        answer = await raw(server.port, request("/", f"127.0.0.1:{server.port}"))
        return held, answer

    result = {}
    _serving(server, lambda s: _keep(result, body(s)))
    held, answer = result["value"]
    assert None not in held and max(held) < 3                  # every one closed, none held
    assert server.hardening.over_address == 32 and server.hardening.header_timeouts == 8
    assert status_of(answer) == 403                            # then served (no link: refused by the gate)


async def _keep(result: dict, coroutine) -> None:
    result["value"] = await coroutine


def test_only_its_host_names_are_served_and_every_answer_has_the_security_headers_and_no_banner(tmp_path):
    server = _server(tmp_path, public_url="https://study.example.org/")
    token = Invites(tmp_path).issue("P01")
    server.load_invites()

    async def body(server):
        port, local = server.port, f"127.0.0.1:{server.port}"
        cases = ((local, f"/?participant=P01&token={token}", 200),                      # the welcome
                 ("study.example.org", f"/?participant=P01&token={token}", 200),       # the public name
                 ("evil.example", f"/?participant=P01&token={token}", 421),
                 (f"evil.example:{port}", "/ws", 421),
                 (local, f"/experimenter?token={server.experimenter_token}", 200),
                 (local, "/", 403), (local, f"/nothing?token={token}", 404))
        return [(host, path, expected, await raw(port, request(path, host))) for host, path, expected in cases]

    result = {}
    _serving(server, lambda s: _keep(result, body(s)))
    for host, path, expected, answer in result["value"]:
        headers = headers_of(answer)
        assert status_of(answer) == expected, (host, path)
        assert "server" not in headers, (path, headers.get("server"))
        csp = headers["content-security-policy"]
        assert "frame-ancestors 'none'" in csp and "connect-src 'self'" in csp, path
        assert headers["x-content-type-options"] == "nosniff" and headers["referrer-policy"] == "no-referrer", path
    assert server.hardening.refused_host == 2


def test_a_request_path_is_logged_escaped_and_a_malformed_request_without_a_traceback(tmp_path, caplog):
    server = _server(tmp_path)
    forged = "/%1b%5b31mP01%0d%0aWARNING%20study-serve:%20all%20fine%E2%80%AE?token=" + "A" * 22

    async def body(server):
        local = f"127.0.0.1:{server.port}"
        return (await raw(server.port, request(forged, local)),
                await raw(server.port, f"GET / HTTP/1.1\r\nHost: {local}\r\nX: {'a' * 9000}\r\n\r\n".encode()))

    result = {}
    with caplog.at_level(logging.DEBUG):
        _serving(server, lambda s: _keep(result, body(s)))
    refused, malformed = result["value"]
    assert status_of(refused) == 403 and status_of(malformed) == 400
    lines = [r.getMessage() for r in caplog.records]
    said = [line for line in lines if "forged" in line]
    assert said and "\\x1b[31mP01\\r\\nWARNING" in said[0] and "\\u202e" in said[0]
    assert not [line for line in lines if any(c in line for c in "\x1b\r\n\u202e")]
    assert not [r for r in caplog.records if r.exc_info] and server.hardening.errors.count == 1


def test_the_file_limit_is_raised_to_its_hard_limit_when_a_server_starts(tmp_path):
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    lowered = min(hard, 512)
    if lowered == hard:
        pytest.skip(f"the hard file limit here is {hard}: nothing to raise")
    resource.setrlimit(resource.RLIMIT_NOFILE, (lowered, hard))
    try:
        seen = {}

        async def body(server):
            seen["soft"] = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
        _serving(_server(tmp_path), body)
        assert seen["soft"] == hard
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


# ---- what reaches a participant's page ------------------------------------------------------------------


def test_only_the_pages_files_are_served_and_an_overlong_name_is_404_not_500(tmp_path, caplog):
    server = _server(tmp_path)

    async def body(server):
        port = server.port
        async with joined(_url(server), _link(server, "P01")) as session:
            cookie = "; ".join(f"{c.key}={c.value}" for c in session.cookie_jar)
            got = {}
            for path in ("/static/main.js", "/static/" + "a" * 4000, "/static/%2e%2e%2fws", "/static/..%2fws",
                         "/static/nothing.js", "/static/", "/static/%2e%2e%2f%2e%2e%2finvites.json"):
                got[path[:40]] = status_of(await raw(port, request(path, f"127.0.0.1:{port}", f"Cookie: {cookie}\r\n")))
            return got

    with caplog.at_level(logging.DEBUG):
        result = {}
        _serving(server, lambda s: _keep(result, body(s)))
    assert result["value"] == {"/static/main.js": 200, "/static/" + "a" * 32: 404, "/static/%2e%2e%2fws": 404,
                               "/static/..%2fws": 404, "/static/nothing.js": 404, "/static/": 404,
                               "/static/%2e%2e%2f%2e%2e%2finvites.json": 404}
    assert not [r for r in caplog.records if r.exc_info]


def test_a_participants_second_page_is_refused_503_and_a_page_from_another_site_403(tmp_path, caplog):
    """One page per participant (its session's frames go to one page); a reload, the first closed,
    is served again. A WebSocket opened by another site's page with the participant's cookie: 403."""
    server = _server(tmp_path)

    async def body(server):
        url = _url(server)
        async with joined(url, _link(server, "P01")) as browser:
            async with browser.ws_connect(f"{url}/ws", origin=url) as first:
                await study(first, lambda s: s["phase"] == "break")
                refused = []
                for origin in (url, url, "https://evil.example"):
                    try:
                        async with browser.ws_connect(f"{url}/ws", origin=origin):
                            refused.append(101)
                    except aiohttp.WSServerHandshakeError as exc:
                        refused.append(exc.status)
                await study(first, lambda s: s["phase"] == "break")     # the first page is still served
            async with browser.ws_connect(f"{url}/ws", origin=url) as reloaded:
                await study(reloaded, lambda s: s["phase"] == "break")
        return refused

    result = {}
    with caplog.at_level(logging.DEBUG):
        _serving(server, lambda s: _keep(result, body(s)))
    assert result["value"] == [503, 503, 403] and server.counts["second page"] == 2
    assert caplog.text.count("P01: a second page refused while one is open") == 1


def test_a_pages_answer_behind_a_network_stalls_batches_is_taken_and_a_flood_is_still_bounded(tmp_path):
    """A served page sends a batch of its frames every batch_s whatever the network does: after a
    stall of seconds they arrive at once, and the answer sent behind them counts (dropped, the trial
    would time out unanswered). A page's flood is dropped past the bound all the same."""
    server = _server(tmp_path)
    stall_s, flood = 5.0, 2000                                 # a stall the heartbeat lets pass
    batch = json.dumps({"type": "batch", "poses": {"time": [1.0], "valid": [False], "hand": [0, 0, 0, 0, 0, 0, 1]},
                        "touches": {"time": [], "intensity": []}})

    async def body(server):
        url = _url(server)
        async with joined(url, _link(server, "P01")) as browser, browser.ws_connect(f"{url}/ws", origin=url) as ws:
            await study(ws, lambda s: s["phase"] == "break")
            batches = round(stall_s / server.options.session.batch_s) + round(stall_s)   # and a stats a second
            for _ in range(batches):
                await ws.send_str(batch)
            await respond(ws, 0, "go on")                          # any answer ends the opening break
            await study(ws, lambda s: s["phase"] != "break", timeout=10)
            counts = server.participants["P01"].session.counts
            taken = counts["batches"]
            for _ in range(flood):                                 # a page that floods
                await ws.send_str(batch)
            await asyncio.sleep(0.5)
            return batches, taken, counts["batches"] - taken

    result = {}
    _serving(server, lambda s: _keep(result, body(s)))
    batches, taken, flooded = result["value"]
    assert taken == batches and flooded < flood / 4, (batches, taken, flooded)


def test_the_page_server_answers_an_overlong_static_name_404_without_a_traceback(serve, caplog):  # noqa: F811
    server, port = serve()
    with caplog.at_level(logging.DEBUG):
        answers = [asyncio.run(raw(port, request(path, f"127.0.0.1:{port}")))
                   for path in ("/static/" + "a" * 4000, "/static/main.js", "/static/%2e%2e%2f%2e%2e%2fetc%2fpasswd")]
    assert [status_of(a) for a in answers] == [404, 200, 404]
    assert not [r for r in caplog.records if r.exc_info] and server.counts()["page_handler_error"] == 0


def test_a_containers_output_and_a_groups_log_are_capped(tmp_path, monkeypatch):
    monkeypatch.setattr(logfiles, "LOG_CAP", 4096)
    out = CappedLog(tmp_path / "c.log")
    writer = subprocess.Popen([sys.executable, "-c", "for i in range(3000): print('x' * 40, i, flush=True)"],
                              stdout=subprocess.PIPE)
    out.follow(writer.stdout)
    writer.wait(30)
    out.close()
    sizes = [(tmp_path / name).stat().st_size for name in ("c.log", "c.log.1")]
    assert max(sizes) <= 4096 and (tmp_path / "c.log").read_text().endswith(f"{'x' * 40} 2999\n")  # ~130 kB written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.log", "c.log.1"]
    handler = GroupLog(tmp_path / "g.log")
    lines = logging.getLogger("test-group-log")
    lines.addHandler(handler)
    try:
        for k in range(1000):
            lines.warning("line %d of a client's flood", k)
    finally:
        lines.removeHandler(handler)
        handler.close()
    assert max((tmp_path / name).stat().st_size for name in ("g.log", "g.log.1")) <= 4096
    assert "line 999 of" in (tmp_path / "g.log").read_text()


# ---- local trust ----------------------------------------------------------------------------------------


def test_a_log_planted_as_a_symlink_is_not_written_through(tmp_path, caplog):
    target = tmp_path / "elsewhere"
    target.write_text("untouched\n")
    link = tmp_path / "serve.log"
    link.symlink_to(target)
    executor = Executor()
    box = Container(executor, bus=None)
    try:
        box.load({"load": "A", "namespace": "A", "nodes": [], "log": str(link)})
        box.unload("A")
    finally:
        executor.close()
    ContainerPool._give_up("A", {"log": str(link)}, "its process died 3 times")
    assert target.read_text() == "untouched\n" and link.is_symlink()
    assert "serve.log" in caplog.text and "Too many levels of symbolic links" in caplog.text


def test_an_out_others_may_write_to_is_refused_and_the_servers_files_are_its_owners(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    done = subprocess.run([sys.executable, "-m", "touch4d.cli", "study", "serve", STUDY, "--out", str(shared),
                           "--port", "0", "--quick"], cwd=REPO, capture_output=True, text=True, timeout=60)
    said = done.stdout + done.stderr
    assert done.returncode != 0 and str(shared) in said and "0777" in said and "--out" in said
    assert not (shared / "serve.json").exists()
    with serve_cli(tmp_path) as served_:
        assert "experimenter page" in served_.text
        modes = {name: stat.S_IMODE(os.stat(served_.out / name).st_mode) for name in ("", "serve.json")}
    assert modes == {"": 0o700, "serve.json": 0o600}


def test_the_page_server_with_a_secret_answers_nothing_but_its_files_without_it(serve):  # noqa: F811
    secret = "S" * 22
    server, port = serve(secret=secret)
    local = f"127.0.0.1:{port}"
    with_secret = f"{SECRET_HEADER}: {secret}\r\n"
    answers = {(path, who): status_of(asyncio.run(raw(port, request(path, local, extra + (UPGRADE if path == "/ws" else "")))))
               for path in ("/", "/ws", "/static/main.js")
               for who, extra in (("none", ""), ("wrong", f"{SECRET_HEADER}: {'T' * 22}\r\n"), ("secret", with_secret))}
    assert answers == {("/", "none"): 403, ("/", "wrong"): 403, ("/", "secret"): 200,
                       ("/ws", "none"): 403, ("/ws", "wrong"): 403, ("/ws", "secret"): 101,
                       ("/static/main.js", "none"): 200, ("/static/main.js", "wrong"): 200,
                       ("/static/main.js", "secret"): 200}


def test_a_handlers_failure_is_logged_with_its_traceback_once_then_in_one_escaped_line(caplog):
    from touch4d.web.hardening import Hardening
    hardening = Hardening("127.0.0.1", log=logging.getLogger("test-hardening"))
    with caplog.at_level(logging.DEBUG):
        for name in ("a" * 300, "b\x1b[2J"):
            try:
                raise OSError(36, "File name too long", name)
            except OSError:
                hardening.http_log.exception("Error handling request from %s", "127.0.0.1")
    first, second = [r for r in caplog.records if r.name == "test-hardening.http"]
    assert first.exc_info is not None and second.exc_info is None
    assert second.getMessage() == ("Error handling request from 127.0.0.1: OSError: [Errno 36] File name too long: "
                                   "'b\\x1b[2J'") and hardening.counts()["handler_error"] == 2

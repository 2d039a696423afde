"""The page's WebSocket through the study server, in process, to a real page server (PageServer, as a
participant's node serves it; a `sleep` process stands as the rest of the stack): spliced byte for
byte, messages and frames pass unchanged, the participant's page counted open and, when either side
closes or the headset vanishes (no pong: the page server's heartbeat), paused; a page over its
max_pages gets the page server's 503; its message limit holds; the wire trace rows; after the
splice nothing more reaches the browser and aiohttp logs nothing."""
from __future__ import annotations

import asyncio
import csv
import json
import logging
import threading
import time

import aiohttp
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, wait_until
from touch4d.messages import StudyCommand
from touch4d.web.invites import Invites
from touch4d.web.protocol import MAX_PAGE_MESSAGE, pack_frame
from touch4d.web.server import WS_HEARTBEAT_S, PageServer

from test_study_server_places import _reap, _server, _serving, _stack, _until

pytestmark = pytest.mark.timeout(120)


class Stack:
    """P01's page server (a real PageServer) and what reached it."""

    def __init__(self):
        self.opened, self.messages, self.closed = [], [], []
        self.page = PageServer("127.0.0.1", 0, max_pages=1, on_connect=self.opened.append,
                               on_message=lambda conn, data, arrival: self.messages.append(data),
                               on_close=self.closed.append)
        self.port = self.page.start()


def served(tmp_path, body, expect: int, **kw):
    """Run `body(server, stack, url, session)` against a study server whose P01 runs `Stack`; returns
    the pause/resume commands P01's study node was sent: once `expect` of them have arrived (the
    server sends them from its node's thread, so the last may still be on its way when `body` ends),
    and any that follow within a moment, or what came in 10 s."""
    server = _server(tmp_path, **kw)
    token = Invites(tmp_path).issue("P01")
    server._load_invites()
    server._start_bus(tmp_path)
    probe = Node("probe", bus=server.node.bus)
    heard = collect(probe, "P01/study/command", StudyCommand)
    spinning = threading.Thread(target=probe.spin, daemon=True)
    spinning.start()
    stack = Stack()
    p, proc = _stack(server, "P01")
    p.port = stack.port
    try:
        async def main(server):
            url = f"http://127.0.0.1:{server.port}"
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
                async with session.get(f"{url}/?participant=P01&token={token}") as response:
                    assert response.status == 200 and '<canvas id="view">' in await response.text()
                await body(server, stack, url, session)
        _serving(server, main)
        try:
            wait_until(lambda: len(heard) >= expect, timeout=10)
            time.sleep(0.3)    # an unexpected extra command would come as soon
        except TimeoutError:
            pass               # the test's assertion shows what came
    finally:
        stack.page.stop()
        _reap(proc)
        probe.request_shutdown()
        server.node.request_shutdown()
        server._bus_thread.join(5)
        server.broker.stop()
    return [m.command for m in heard]


def test_messages_and_frames_pass_unchanged_a_second_page_gets_503_and_a_close_pauses(tmp_path):
    trace_path = tmp_path / "wire.csv"

    async def body(server, stack, url, session):
        p = server.participants["P01"]
        ws = await session.ws_connect(f"{url}/ws", origin=url)
        assert await _until(lambda: stack.opened and p.pages == 1 and p.life.shown() == "running", 10)
        before = p.last_heard
        text = json.dumps({"type": "input", "time": 1234.5, "tracking": True, "head": None, "sources": []})
        await ws.send_str(text)
        assert await _until(lambda: stack.messages, 10)
        assert stack.messages == [text] and p.last_heard > before     # unchanged; heard
        frame = pack_frame("frame", {"n": 1, "haptic": 0.75})
        stack.page.send(stack.opened[0], frame)
        msg = await ws.receive(10)
        assert msg.type == aiohttp.WSMsgType.BINARY and msg.data == frame
        # a page over the page server's max_pages: its refusal (503) passed on, not parsed here
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await session.ws_connect(f"{url}/ws", origin=url)
        assert refused.value.status == 503 and p.pages == 1
        # over the page server's message limit: it closes the page (message too big)
        await ws.send_str("x" * (MAX_PAGE_MESSAGE + 1))
        msg = await ws.receive(10)
        assert msg.type == aiohttp.WSMsgType.CLOSE and msg.data == aiohttp.WSCloseCode.MESSAGE_TOO_BIG
        assert await _until(lambda: p.pages == 0 and p.life.shown() == "paused", 10)
        # the page again: resumed, and its own close pauses it
        ws = await session.ws_connect(f"{url}/ws", origin=url)
        assert await _until(lambda: p.pages == 1 and p.life.shown() == "running", 10)
        await ws.close()
        assert await _until(lambda: p.pages == 0 and p.life.shown() == "paused" and len(stack.closed) == 2, 10)
        # another origin, or not an upgrade: refused here, before the page server
        with pytest.raises(aiohttp.WSServerHandshakeError) as other:
            await session.ws_connect(f"{url}/ws", origin="http://elsewhere.example")
        assert other.value.status == 403
        async with session.get(f"{url}/ws") as response:
            assert response.status == 400
        assert len(stack.opened) == 2

    commands = served(tmp_path, body, expect=3, wire_trace=trace_path)
    assert commands == ["pause", "resume", "pause"]
    rows = list(csv.reader(open(trace_path, newline="")))
    assert [r[:3] for r in rows] == [["P01", "in", "1234.5"], ["P01", "out", "0.75"]]
    assert int(rows[0][3]) < int(rows[1][3])


async def _upgrade(url: str, session: aiohttp.ClientSession, key: bytes = b"dGhlIHNhbXBsZSBub25jZQ=="):
    """A raw connection through the study server's /ws (the cookie's): (reader, writer, the response head)."""
    port = int(url.rsplit(":", 1)[1])
    cookie = "; ".join(f"{c.key}={c.value}" for c in session.cookie_jar)
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: {url}\r\nCookie: {cookie}\r\n"
                  "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n").encode()
                 + b"Sec-WebSocket-Key: " + key + b"\r\n\r\n")
    head = await reader.readuntil(b"\r\n\r\n")
    return reader, writer, head


def _messages(data: bytes) -> list:
    """The WebSocket messages in `data` (a server's, unmasked), read by aiohttp's frame reader."""
    from touch4d.web.wiretrace import _frames
    got = []
    feed = _frames(got.append, 0)
    assert feed(data) == (False, b"")
    return got


def test_a_headset_that_vanished_is_noticed_by_the_page_servers_heartbeat_and_nothing_follows(tmp_path, caplog):
    caplog.set_level(logging.DEBUG)

    async def body(server, stack, url, session):
        p = server.participants["P01"]
        _, refused, head = await _upgrade(url, session, key="€".encode())   # no header to pass on
        assert head.startswith(b"HTTP/1.1 400 ")
        refused.close()
        reader, writer, head = await _upgrade(url, session)
        assert head.startswith(b"HTTP/1.1 101 ") and b"s3pPLMBiTxaQ9kYGzzhZRbK+xOo=" in head   # RFC 6455's example
        assert await _until(lambda: p.pages == 1, 10)
        # it reads nothing more and answers no ping (a headset gone without a word): the page server's
        # heartbeat closes it, and the splice with it
        assert await _until(lambda: p.pages == 0 and p.life.shown() == "paused", 4 * WS_HEARTBEAT_S + 5)
        rest = await asyncio.wait_for(reader.read(), 10)     # what it was sent after the 101, up to EOF
        writer.close()
        # the page server's pings and nothing else: no HTTP response of aiohttp's after the splice
        kinds = {m.type for m in _messages(rest)}
        assert kinds <= {aiohttp.WSMsgType.PING, aiohttp.WSMsgType.CLOSE} and aiohttp.WSMsgType.PING in kinds
        assert b"HTTP/1.1" not in rest

    assert served(tmp_path, body, expect=1) == ["pause"]
    noise = [r for r in caplog.records if r.name.startswith(("aiohttp", "asyncio")) and
             (r.levelno >= logging.INFO or "disconnection" in r.getMessage())]
    assert not noise, [r.getMessage() for r in noise]

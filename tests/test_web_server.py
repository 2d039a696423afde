"""The page server without a browser: token and origin checks, files from the package, TLS with
the node's own certificate, and the node surviving garbage on its WebSocket."""
import asyncio
import json
import os
import queue
import ssl
import time

import aiohttp
import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, node_process, running_broker, wait_until
from touch4d.messages import ControllerState, HandPose, Heartbeat
from touch4d.web.access import Access, is_loopback, page_url, qr_text
from touch4d.web.tls import ensure_certificate, server_ssl_context
from touch4d.web.protocol import unpack_frame
from touch4d.web.server import PageBounds, PageServer

pytestmark = pytest.mark.timeout(60)


def fetch(url, ssl_context=None, headers=None):
    async def go():
        async with aiohttp.ClientSession() as session:
            async with session.get(url, ssl=ssl_context, headers=headers or {}) as r:
                return r.status, dict(r.headers), await r.text()
    return asyncio.run(go())


@pytest.fixture
def lan_server():
    """A server bound beyond loopback (all interfaces) with a token; the test reaches it on 127.0.0.1."""
    access = Access()
    server = PageServer("0.0.0.0", 0, access, bounds=PageBounds(secure_cookie=False))
    server.token = access.issue("headset")
    port = server.start()
    try:
        yield server, port
    finally:
        server.stop()


def test_without_the_token_the_page_and_the_socket_are_refused(lan_server):
    server, port = lan_server
    status, _, text = fetch(f"http://127.0.0.1:{port}/")
    assert status == 403 and "token" in text
    assert fetch(f"http://127.0.0.1:{port}/?token=wrong")[0] == 403
    assert fetch(f"http://127.0.0.1:{port}/ws")[0] == 403
    status, headers, text = fetch(f"http://127.0.0.1:{port}/?token={server.token}")
    assert status == 200 and '<script type="module" src="/static/main.js">' in text
    assert "default-src 'self'" in headers["Content-Security-Policy"]
    assert headers["Referrer-Policy"] == "no-referrer"
    assert server.refused == 3


def test_the_page_files_come_from_the_package(lan_server):
    _, port = lan_server
    status, headers, text = fetch(f"http://127.0.0.1:{port}/static/main.js")
    assert status == 200 and "javascript" in headers["Content-Type"] and "WebXR" in text
    assert fetch(f"http://127.0.0.1:{port}/static/../bridge.py")[0] in (403, 404)   # outside static/: needs the token
    assert fetch(f"http://127.0.0.1:{port}/static/nothing.js")[0] == 404


def test_a_websocket_from_another_site_is_refused():
    server = PageServer("127.0.0.1", 0)
    port = server.start()

    async def go(origin):
        async with aiohttp.ClientSession() as session:
            try:
                async with session.ws_connect(f"http://127.0.0.1:{port}/ws", headers={"Origin": origin}):
                    return "open"
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status
    try:
        assert asyncio.run(go("https://evil.example")) == 403
        assert asyncio.run(go(f"http://127.0.0.1:{port}")) == "open"
    finally:
        server.stop()


def test_tls_with_the_nodes_own_certificate(tmp_path):
    cert, key, fingerprint = ensure_certificate(tmp_path, ["127.0.0.1"])
    assert os.stat(key).st_mode & 0o777 == 0o600
    assert ensure_certificate(tmp_path, ["127.0.0.1"])[2] == fingerprint      # made once, then reused
    access = Access()
    token = access.issue("headset")
    server = PageServer("127.0.0.1", 0, access, ssl_context=server_ssl_context(cert, key))
    port = server.start()
    try:
        client = ssl.create_default_context(cafile=str(cert))                  # trust exactly this certificate
        status, headers, _ = fetch(f"https://127.0.0.1:{port}/?token={token}", ssl_context=client)
        assert status == 200 and "Secure" in headers["Set-Cookie"]
        with pytest.raises(aiohttp.ClientConnectorCertificateError):
            fetch(f"https://127.0.0.1:{port}/?token={token}", ssl_context=ssl.create_default_context())
    finally:
        server.stop()
    # a new address needs a new certificate
    assert ensure_certificate(tmp_path, ["192.0.2.7"])[2] != fingerprint


def test_a_new_page_hears_broadcasts_only_after_its_first_frame():
    """The node answers a connection on its own thread: broadcasts queued before its setup frame
    must not reach the page ahead of it."""
    connected = queue.Queue()
    server = PageServer("127.0.0.1", 0, on_connect=connected.put)
    port = server.start()
    try:
        async def page():
            async with aiohttp.ClientSession() as session, session.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
                conn = await asyncio.get_running_loop().run_in_executor(None, connected.get, True, 5)
                server.broadcast(b"frame before setup", latest=True)
                server.broadcast(b"geometry before setup")
                await asyncio.sleep(0.2)
                server.send(conn, b"setup")
                server.broadcast(b"frame after setup", latest=True)
                return [await ws.receive_bytes(timeout=5), await ws.receive_bytes(timeout=5)]

        assert asyncio.run(page()) == [b"setup", b"frame after setup"]
    finally:
        server.stop()


def test_access_helpers():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")
    assert page_url("https", "192.168.1.5", 8090, "abc") == "https://192.168.1.5:8090/?token=abc"
    assert page_url("http", "::1", 8090, None) == "http://[::1]:8090/"
    qr = qr_text("https://192.168.1.5:8090/?token=abc")
    assert len(qr.splitlines()) > 10 and "█" in qr or "▀" in qr


def test_the_node_counts_garbage_and_keeps_serving():
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={"port": port, "tracker": True,
                                                                     "save_calibration": False}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)
        probe = Node("probe", bus=bus, heartbeat=False)
        beats = collect(probe, "node/heartbeat", Heartbeat)
        poses = collect(probe, "hand/pose", HandPose)
        try:
            url = f"http://127.0.0.1:{port}/ws"
            grip = [0.0, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]

            def good(t):
                return json.dumps({"type": "input", "time": t * 1000, "tracking": True, "head": None, "sources": [
                    {"handedness": "right", "grip": grip, "trigger": 0, "buttons": [], "joints": None}]})

            async def attack():
                async with aiohttp.ClientSession() as session:
                    async with session.ws_connect(url) as ws:
                        setup, _ = unpack_frame(await ws.receive_bytes())
                        assert setup["kind"] == "setup" and setup["tracker"] is True
                        await ws.send_str("{garbage")
                        await ws.send_str('{"type": "input", "time": 1, "tracking": true, "head": [NaN, 0, 0, 0, 0, 0, 1], "sources": []}')
                        await ws.send_bytes(b"\x00\xff" * 10)
                        await ws.send_str(good(time.time()))
                        await ws.send_str(json.dumps({"type": "input", "pad": "x" * 50000}))   # ends it
                    async with session.ws_connect(url) as ws:   # a message over 1 MiB ends its connection
                        await ws.receive_bytes()
                        try:
                            await ws.send_str("y" * (2 << 20))
                        except ConnectionError:
                            pass    # closed by the server, having read the frame's header, before all was sent
                        else:
                            while (msg := await ws.receive()).type == aiohttp.WSMsgType.BINARY:
                                pass                                # frames sent before the close
                            assert msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
                    async with session.ws_connect(url) as ws:   # and the node still serves
                        assert unpack_frame(await ws.receive_bytes())[0]["kind"] == "setup"
                        await ws.send_str(good(time.time()))
                        await asyncio.sleep(0.2)

            asyncio.run(attack())

            def counted():
                stats = [b.stats for b in beats if b.node == "webxr"]
                return stats and stats[-1].get("page_non_finite") == 1 and stats[-1].get("page_oversized") == 2 \
                    and stats[-1].get("page_malformed") == 2 and stats[-1]
            stats = wait_until(counted, timeout=10, spin=probe)
            assert stats["page_connections"] == 3
            assert any(p.valid and np.allclose(p.position, 0.0) for p in poses)
            assert proc.returncode is None
        finally:
            probe.shutdown()

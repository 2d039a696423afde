"""The page server's bounds, probed on loopback as an attacker would (raw sockets and WebSocket
clients, bounded in count and time): Host names it does not serve, the security headers on every
answer, connections that send nothing or trickle, too many from one address, messages over the
page limit, pages that never read, and a revoked holder's open page."""
import asyncio
import logging
import time

import aiohttp
import pytest

from touch4d.web.access import Access
from touch4d.web.protocol import MAX_PAGE_MESSAGE
from touch4d.web.server import PageBounds, PageServer

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def serve():
    started = []

    def start(**kwargs):
        server = PageServer("127.0.0.1", 0, **kwargs)
        started.append(server)
        return server, server.start()
    yield start
    for server in started:
        server.stop()


async def raw(port: int, request: bytes, wait: float = 5.0) -> bytes:
    """What the server answers to `request` sent as is, until it closes or `wait` s pass."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        await writer.drain()
        return await asyncio.wait_for(reader.read(1 << 16), wait)
    except ConnectionResetError:
        return b""
    finally:
        writer.close()


def get(port: int, path: str = "/", host: str | None = None, headers: dict | None = None) -> bytes:
    lines = [f"GET {path} HTTP/1.1", f"Host: {f'127.0.0.1:{port}' if host is None else host}", "Connection: close",
             *(f"{k}: {v}" for k, v in (headers or {}).items())]
    return asyncio.run(raw(port, ("\r\n".join(lines) + "\r\n\r\n").encode()))


def status_of(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1])


def headers_of(answer: bytes) -> dict:
    head = answer.split(b"\r\n\r\n", 1)[0].decode().split("\r\n")[1:]
    return {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in head)}


def test_a_host_name_it_does_not_serve_gets_nothing_page_or_socket(serve):
    """DNS rebinding: another site's name pointed at this address, with a matching Origin."""
    server, port = serve(names=["touch4d.example.org"])
    assert status_of(get(port)) == 200
    assert status_of(get(port, host=f"localhost:{port}")) == 200
    assert status_of(get(port, host=f"touch4d.example.org:{port}")) == 200          # the configured name
    assert status_of(get(port, host=f"attacker.example:{port}")) == 421
    assert status_of(get(port, host="")) in (400, 421)
    upgrade = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
               "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==", "Origin": f"http://attacker.example:{port}"}
    lines = [f"GET /ws HTTP/1.1", f"Host: attacker.example:{port}", *(f"{k}: {v}" for k, v in upgrade.items())]
    answer = asyncio.run(raw(port, ("\r\n".join(lines) + "\r\n\r\n").encode(), wait=5))
    assert status_of(answer) == 421 and not server.clients
    assert server.refused_host == 3


def test_every_answer_carries_the_security_headers_and_no_banner(serve):
    _, port = serve()
    _, gated = serve(access=Access())
    for port, path, method, host, expected in (
            (port, "/", "GET", "127.0.0.1", 200), (port, "/nothing", "GET", "127.0.0.1", 404),
            (port, "/", "POST", "127.0.0.1", 405), (port, "/static/main.js", "GET", "127.0.0.1", 200),
            (port, "/static/none.js", "GET", "127.0.0.1", 404), (port, "/", "GET", "attacker.example", 421),
            (gated, "/", "GET", "127.0.0.1", 403), (gated, "/ws", "GET", "127.0.0.1", 403)):
        answer = asyncio.run(raw(port, f"{method} {path} HTTP/1.1\r\nHost: {host}:{port}\r\n"
                                       "Connection: close\r\nContent-Length: 0\r\n\r\n".encode()))
        headers = headers_of(answer)
        assert status_of(answer) == expected, (path, method)
        assert "server" not in headers, (path, method, headers.get("server"))
        csp = headers["content-security-policy"]
        assert "connect-src 'self';" in csp and "ws:" not in csp and "frame-ancestors 'none'" in csp
        assert headers["x-content-type-options"] == "nosniff" and headers["referrer-policy"] == "no-referrer"
        assert headers["cache-control"] == "no-store"


def test_a_malformed_request_is_answered_and_counted_not_logged_with_a_traceback(serve, caplog):
    server, port = serve()
    with caplog.at_level(logging.DEBUG):
        answer = asyncio.run(raw(port, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX: " + b"a" * 9000 + b"\r\n\r\n"))
    assert status_of(answer) == 400
    assert not [r for r in caplog.records if r.exc_info] and server.counts()["page_bad_request"] == 1


def test_a_connection_that_sends_nothing_or_trickles_is_closed(serve):
    server, port = serve(bounds=PageBounds(header_timeout_s=0.5))

    async def probe():
        t0 = time.monotonic()
        silent = await raw(port, b"", wait=5)                         # sends nothing at all
        silent_s = time.monotonic() - t0
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        t0 = time.monotonic()
        closed_after = None
        for k in range(40):                                           # a header line every 0.1 s
            try:
                writer.write(f"X-Slow-{k}: y\r\n".encode() if k else b"GET / HTTP/1.1\r\n")
                await writer.drain()
                if await asyncio.wait_for(reader.read(100), 0.1) == b"":
                    closed_after = time.monotonic() - t0
                    break
            except asyncio.TimeoutError:
                continue
            except ConnectionError:
                closed_after = time.monotonic() - t0
                break
        writer.close()
        return silent, silent_s, closed_after

    silent, silent_s, trickle_s = asyncio.run(probe())
    assert silent == b"" and 0.4 < silent_s < 3
    assert trickle_s is not None and trickle_s < 3
    assert server.header_timeouts == 2
    assert status_of(get(port)) == 200                                # a real request is served as before


def test_connections_from_one_address_are_capped(serve):
    server, port = serve(bounds=PageBounds(max_per_address=4, limit_loopback=True))

    async def probe():
        held = [await asyncio.open_connection("127.0.0.1", port) for _ in range(4)]
        over = await raw(port, f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode(), wait=5)
        for _, writer in held:
            writer.close()
        await asyncio.sleep(0.3)
        return over

    assert asyncio.run(probe()) == b""                                # closed at once, nothing answered
    assert server.over_address == 1
    assert status_of(get(port)) == 200                                # freed again


def test_connections_from_one_address_are_capped_before_their_tls_handshake(serve, tmp_path):
    """Over https the cap counts TCP connections, not finished handshakes: connections that never
    start one (each held until the handshake timeout) cannot take the server's sockets."""
    import ssl

    from touch4d.web.tls import ensure_certificate, server_ssl_context

    cert, key, _ = ensure_certificate(tmp_path / "tls", ["127.0.0.1"])
    server, port = serve(bounds=PageBounds(max_per_address=4, limit_loopback=True, header_timeout_s=20),
                         ssl_context=server_ssl_context(cert, key))

    async def probe():
        held = [await asyncio.open_connection("127.0.0.1", port) for _ in range(4)]   # no handshake
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        started = time.monotonic()
        try:
            over = await asyncio.wait_for(reader.read(1), 5)
        except ConnectionResetError:
            over = b""
        closed_after = time.monotonic() - started
        writer.close()
        for _, w in held:
            w.close()
        await asyncio.sleep(0.3)
        client = ssl.create_default_context(cafile=str(cert))
        async with aiohttp.ClientSession() as session, session.get(f"https://127.0.0.1:{port}/", ssl=client) as r:
            return over, closed_after, r.status

    over, closed_after, status = asyncio.run(probe())
    assert over == b"" and closed_after < 5                           # the fifth closed at once
    assert server.over_address == 1
    assert status == 200                                              # freed again, and TLS still served
    assert server.counts()["page_tls_failed"] == 4                    # the four that never began one


def test_a_message_over_the_page_limit_ends_the_connection_at_once(serve):
    received = []
    server, port = serve(on_message=lambda conn, data, arrival: received.append(data))

    async def page():
        async with aiohttp.ClientSession() as session, session.ws_connect(f"http://127.0.0.1:{port}/ws") as ws:
            await ws.send_str('{"type": "stats", "fps": 60}')
            await ws.send_str("x" * (MAX_PAGE_MESSAGE + 1))
            msg = await ws.receive(timeout=5)
            return msg.type, ws.close_code

    kind, code = asyncio.run(page())
    deadline = time.monotonic() + 5
    while len(received) < 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert kind in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED) and code == 1009
    assert received[0] == '{"type": "stats", "fps": 60}' and isinstance(received[-1], Exception)
    assert len(received) == 2


def test_a_page_that_does_not_read_is_closed_and_counted(serve):
    server, port = serve(bounds=PageBounds(send_timeout_s=1.0, max_queued=8))
    connected = []
    server.on_connect = connected.append

    async def page():
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(f"http://127.0.0.1:{port}/ws", autoping=False)
            try:
                for _ in range(100):
                    if connected:
                        break
                    await asyncio.sleep(0.02)
                big = b"g" * (1 << 20)
                for _ in range(64):                                   # geometry frames it never reads
                    server.send(connected[0], big)
                    await asyncio.sleep(0.02)
                for _ in range(300):
                    if not server.clients:
                        return True
                    await asyncio.sleep(0.02)
                return False
            finally:
                await ws.close()

    assert asyncio.run(page())
    assert server.send_overflow == 1


@pytest.mark.parametrize("frame", [2000, 20000])
def test_a_page_that_floods_pings_and_reads_nothing_is_closed_and_its_place_freed(serve, frame):
    """Pings are not answered (a browser never sends them): answering them, the server's reading
    waited for the unread pongs to leave, and the page held its place (or its socket, left closing
    behind its unread pongs) for ever."""
    import base64
    import os
    import socket
    import threading

    ended = []
    server, port = serve(on_connect=lambda conn: server.send(conn, b"setup"),
                         on_message=lambda conn, data, arrival: isinstance(data, Exception) and ended.append(data))
    ticking = threading.Event()

    def node_frames():                      # what a node sends every tick
        while not ticking.wait(0.05):
            server.broadcast(b"f" * frame, latest=True)

    threading.Thread(target=node_frames, daemon=True).start()
    page = socket.create_connection(("127.0.0.1", port))
    try:
        page.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        key = base64.b64encode(os.urandom(16)).decode()
        page.sendall(f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
        assert page.recv(12) == b"HTTP/1.1 101"
        ping = bytes([0x89, 0x80 | 125]) + b"\0\0\0\0" + b"x" * 125     # masked, as from a client
        page.setblocking(False)
        started, sent, closed = time.monotonic(), 0, False
        while time.monotonic() - started < 15 and sent < 300000 and not closed:
            try:
                page.send(ping)
                sent += 1
            except BlockingIOError:
                time.sleep(0.01)
                closed = not server.clients and not server._guards
            except OSError:                 # reset: the server closed it
                closed = True
        from touch4d.web.server import WS_HEARTBEAT_S

        # incoming data delays the heartbeat: once the flood stops, a ping goes out and, unanswered, closes it
        deadline = time.monotonic() + 3 * WS_HEARTBEAT_S
        while (server.clients or server._guards) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not server.clients and not server._guards and not server._per_address   # closed, its place freed
        # closed as a page that answers no ping (the node counts it, page_unresponsive) or takes no frame
        assert len(ended) + server.send_overflow == 1
    finally:
        ticking.set()
        page.close()


def test_a_revoked_holder_loses_its_open_page_and_the_others_keep_theirs(serve):
    access = Access()
    tokens = {name: access.issue(name) for name in ("P01", "P02")}
    server, port = serve(access=access, bounds=PageBounds(secure_cookie=False))

    async def pages():
        async with aiohttp.ClientSession() as session:
            socks = {name: await session.ws_connect(f"http://127.0.0.1:{port}/ws?token={token}")
                     for name, token in tokens.items()}
            await asyncio.sleep(0.2)
            holders = sorted(server.holder(conn) for conn in server.clients)
            access.revoke("P01")
            msg = await socks["P01"].receive(timeout=5)
            await asyncio.sleep(0.2)
            alive = {name: not ws.closed for name, ws in socks.items()}
            for ws in socks.values():
                await ws.close()
            return holders, msg.type, alive

    holders, kind, alive = asyncio.run(pages())
    assert holders == ["P01", "P02"]
    assert kind in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
    assert alive == {"P01": False, "P02": True}


@pytest.mark.parametrize("tls", [False, True])
def test_a_page_outlives_the_header_timeout(serve, tmp_path, tls):
    """The header timeout bounds a request's header, not the WebSocket that follows it."""
    import ssl

    from touch4d.web.tls import ensure_certificate, server_ssl_context

    context, client = None, True                                      # (True: aiohttp's default checks)
    if tls:
        cert, key, _ = ensure_certificate(tmp_path, ["127.0.0.1"])
        context, client = server_ssl_context(cert, key), ssl.create_default_context(cafile=str(cert))
    received = []
    server, port = serve(bounds=PageBounds(header_timeout_s=0.3), ssl_context=context,
                         on_message=lambda conn, data, arrival: received.append(data))

    async def page():
        scheme = "https" if tls else "http"
        async with aiohttp.ClientSession() as session, \
                session.ws_connect(f"{scheme}://127.0.0.1:{port}/ws", ssl=client) as ws:
            await asyncio.sleep(1.0)                                  # over three header timeouts
            await ws.send_str('{"type": "stats", "fps": 60}')
            await asyncio.sleep(0.2)
            return ws.closed

    assert asyncio.run(page()) is False
    assert received == ['{"type": "stats", "fps": 60}'] and server.header_timeouts == 0


def test_two_servers_on_one_host_keep_their_own_cookies(serve):
    """Browsers keep cookies per host, not per port: two page servers of one machine (a participant's
    each) opened in one browser must not overwrite each other's cookie."""
    first, second = Access(), Access()
    tokens = first.issue("P01"), second.issue("P02")
    ports = [serve(access=access, bounds=PageBounds(secure_cookie=False))[1] for access in (first, second)]

    async def browse():
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as browser:
            for port, token in zip(ports, tokens):                    # each link opened once
                async with browser.get(f"http://127.0.0.1:{port}/?token={token}") as r:
                    assert r.status == 200
            answers = []
            for port in ports:                                        # then reloaded without it
                async with browser.get(f"http://127.0.0.1:{port}/") as r:
                    answers.append(r.status)
            return answers

    assert asyncio.run(browse()) == [200, 200]


def test_behind_a_proxy_the_websocket_needs_the_browsers_host_passed_on(serve):
    """A reverse proxy that rewrites Host to the node's own address (nginx's default) makes the page's
    WebSocket look cross-origin: refused; with the public name passed on (and in `names`) it opens."""
    server, port = serve(names=["touch4d.example"])
    upgrade = ("Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
               "Sec-WebSocket-Version: 13\r\nOrigin: https://touch4d.example\r\n")

    def open_socket(host: str) -> int:
        return status_of(asyncio.run(raw(port, f"GET /ws HTTP/1.1\r\nHost: {host}\r\n{upgrade}\r\n".encode(), 2)))

    assert open_socket(f"127.0.0.1:{port}") == 403 and server.refused_origin == 1
    assert open_socket("touch4d.example") == 101


@pytest.mark.parametrize("name, host", [("touch4d.example", "touch4d.example"),
                                        ("Touch4D.example:443", "touch4d.example"),
                                        ("https://touch4d.example/", "touch4d.example:443"),
                                        ("fe80::1", "[fe80::1]:8090"), ("[FE80::1]:443", "[fe80::1]")])
def test_a_public_name_is_served_however_it_is_written(serve, name, host):
    server, port = serve(names=[name])
    assert status_of(get(port, "/static/index.html", host=host)) == 200
    assert status_of(get(port, "/static/index.html", host="other.example")) == 421

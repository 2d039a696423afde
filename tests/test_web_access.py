"""The access layer alone: tokens per holder that expire and are revoked, and the cookie a link's
token is exchanged for (flags checked on a real aiohttp server on loopback)."""
import asyncio
import math

import aiohttp
import pytest
from aiohttp import web

from touch4d.web.access import HOLDER, Access, CookieGate, check_token, new_token

pytestmark = pytest.mark.timeout(60)


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def test_tokens_per_holder_expire_and_are_revoked():
    clock = Clock()
    access = Access(now=clock)
    p1, p2 = access.issue("P01", ttl=60), access.issue("P02")
    experimenter = access.issue("experimenter", ttl=3600)
    assert len({p1, p2, experimenter}) == 3
    assert access.check(p1) == "P01" and access.check(p2) == "P02" and access.check(experimenter) == "experimenter"
    forged = ("y" if p1[0] == "x" else "x") + p1[1:]    # one character changed (a token may begin with x)
    assert access.check(forged) is None and access.check("") is None and access.check(None) is None
    clock.t += 61
    assert access.check(p1) is None and access.check(p2) == "P02"     # P01's hour is over, the others stay
    assert access.holders() == ["P02", "experimenter"]
    revoked = []
    access.on_revoke(revoked.append)
    assert access.revoke("P02") and not access.revoke("P02")
    assert access.check(p2) is None and revoked == ["P02", "P02"]
    renewed = access.issue("experimenter")                            # a new link replaces the old one
    assert access.check(experimenter) is None and access.check(renewed) == "experimenter"


def test_a_token_carries_128_bits_at_least():
    token = new_token()
    assert len(token) >= 22 and check_token(token) is None
    assert "22 characters" in check_token("s3cret")
    assert "characters" in check_token("a b" * 20)
    with pytest.raises(ValueError, match="P03"):
        Access().issue("P03", token="short")
    assert Access().check(Access().issue("P04", token="A" * 22)) is None   # another Access: unknown there


def test_the_cookie_expires_with_the_token_and_dies_with_its_holder():
    clock = Clock()
    access = Access(now=clock)
    token = access.issue("P01", ttl=100)
    holder, cookie, expires = access.exchange(token)
    assert holder == "P01" and expires == 1100.0 and cookie != token
    assert access.session_holder(cookie) == "P01"
    assert access.check(cookie) is None and access.session_holder(token) is None   # kinds do not mix
    assert access.exchange("nope") is None
    clock.t += 101
    assert access.session_holder(cookie) is None
    token = access.issue("P01")
    _, cookie, expires = access.exchange(token)
    assert math.isinf(expires)
    access.revoke("P01")
    assert access.session_holder(cookie) is None


def serve(gate):
    async def index(request):
        return web.Response(text=f"hello {request[HOLDER]}")

    app = web.Application(middlewares=[gate.middleware])
    app.router.add_get("/", index)
    async def static(request):
        return web.Response(text="// open")

    app.router.add_get("/static/x.js", static)
    return app


def test_the_gate_exchanges_a_link_for_a_strict_cookie():
    access = Access()
    token = access.issue("P01", ttl=600)
    gate = CookieGate(access, open_prefixes=("/static/",))

    async def go():
        runner = web.AppRunner(serve(gate))
        await runner.setup()
        site = web.TCPSite(runner, "127.0.0.1", 0)
        await site.start()
        base = f"http://127.0.0.1:{runner.addresses[0][1]}"
        try:
            async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
                async with s.get(f"{base}/") as r:
                    refused = r.status, await r.text()
                async with s.get(f"{base}/static/x.js") as r:
                    open_file = r.status
                async with s.get(f"{base}/?token={token}") as r:
                    first = r.status, await r.text(), r.headers.getall("Set-Cookie")
                cookie = first[2][0].split(";")[0].split("=", 1)[1]
                async with s.get(f"{base}/", headers={"Cookie": f"touch4d={cookie}"}) as r:
                    again = r.status, await r.text(), r.headers.getall("Set-Cookie", [])
                other = access.issue("experimenter")
                async with s.get(f"{base}/?token={other}", headers={"Cookie": f"touch4d={cookie}"}) as r:
                    switched = await r.text()                # a link opened in that browser: its holder
                access.revoke("P01")
                async with s.get(f"{base}/", headers={"Cookie": f"touch4d={cookie}"}) as r:
                    after = r.status
                async with s.get(f"{base}/?token={token}") as r:
                    after_link = r.status
            return refused, open_file, first, again, after, after_link, switched
        finally:
            await runner.cleanup()

    refused, open_file, first, again, after, after_link, switched = asyncio.run(go())
    assert switched == "hello experimenter"
    assert refused[0] == 403 and "link" in refused[1] and open_file == 200
    status, text, set_cookie = first
    assert status == 200 and text == "hello P01" and len(set_cookie) == 1
    flags = [f.strip().lower() for f in set_cookie[0].split(";")]
    assert {"httponly", "secure", "samesite=strict", "path=/"} <= set(flags)
    assert any(f.startswith("max-age=") and 590 <= int(f.split("=")[1]) <= 600 for f in flags)
    assert token not in set_cookie[0]
    assert again == (200, "hello P01", [])          # the cookie alone lets in, and no new one is set
    assert after == 403 and after_link == 403
    assert gate.refused == 3


def test_a_holder_keeps_a_bounded_number_of_cookies_and_a_link_names_its_own_holder():
    access = Access()
    token = access.issue("P01")
    cookies = [access.exchange(token)[1] for _ in range(100)]      # a page reloaded 100 times with its link
    alive = [c for c in cookies if access.session_holder(c) == "P01"]
    assert alive == cookies[-16:]
    access.issue("P02", ttl=1e-9)                                  # expired before anyone used it
    access.issue("P03")
    assert "P02" not in access.holders()

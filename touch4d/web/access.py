"""Who may open the page: tokens per holder (a headset, each participant of a study, an
experimenter), each of them able to expire and be revoked, exchanged on first load for a cookie.

    access = Access()
    token = access.issue("P07", ttl=3600)      # >= 128 bits; a second issue replaces the holder's token
    access.check(token)                         # -> "P07" (None: unknown, expired or revoked)
    access.revoke("P07")                        # its token and its cookies stop working at once
    gate = CookieGate(access)                   # aiohttp middleware: web.Application(middlewares=[gate.middleware])

The holder opens `https://host/?token=...` once: `CookieGate` finds the token, sets a session cookie
(HttpOnly, Secure, SameSite=Strict: no script, no plain http, no other site sees it) that expires
with the token, and puts the holder in `request[HOLDER]`; the page then removes the token from
the address bar (history.replaceState), so it stays out of the browser's history and of what a
proxy logs later; the page's files and its WebSocket go with the cookie. A request with neither a
valid token nor a valid cookie gets 403 (paths under `open_prefixes` excepted). Tokens and cookies
are kept as SHA-256 digests (a dict lookup, no timing hint about the secret). Thread-safe: a study
may issue and revoke from any thread; `on_revoke(callback)` lets a server close a holder's pages
(an expiry refuses new loads and connections; a page already open stays until it closes or is revoked).

Beyond the layer: the node's link (`page_url`), the QR code for a headset's camera, the addresses
a headset on the LAN can reach, and the token a user provides (`check_token`: 128 bits at least).
"""
from __future__ import annotations

import hashlib
import socket
import threading
import time
from dataclasses import dataclass
from typing import Callable
from urllib.parse import urlsplit

from aiohttp import web

from touch4d.bus.config import is_loopback  # noqa: F401  (the bus's rule: 127.0.0.0/8, ::1, localhost)
from touch4d.tokens import check_token, new_token  # noqa: F401  (the links' tokens: touch4d.tokens)

MAX_COOKIES = 16                                  # per holder (browsers, reloads): the oldest goes first
COOKIE = "touch4d"
HOLDER = web.RequestKey("holder", str)             # request[HOLDER]: who the gate let in (None: an open path)
REFUSED = ("touch4d: this page needs its link (the URL with a token, or its QR code, that you were given); "
           "the link may have expired or been revoked.\n")


def _digest(secret: str) -> bytes:
    return hashlib.sha256(secret.encode("utf-8", "surrogatepass")).digest()


@dataclass
class _Grant:
    holder: str
    expires: float          # on the Access clock; inf: never
    session: bool           # a cookie's value (from exchange), not a link's token


class Access:
    """Tokens per holder; see the module doc. `now` is the clock the `ttl`s count on."""

    def __init__(self, now: Callable[[], float] = time.time):
        self.now = now
        self._grants: dict[bytes, _Grant] = {}
        self._lock = threading.Lock()
        self._revoked: list[Callable[[str], None]] = []

    def issue(self, holder: str, ttl: float | None = None, token: str | None = None) -> str:
        """A new token for `holder`, valid `ttl` seconds (None: until revoked), replacing its previous
        token (its cookies stay valid). `token`: one of the user's own (see check_token)."""
        if not holder:
            raise ValueError("a holder needs a name")
        if token is None:
            token = new_token()
        elif (why := check_token(token)) is not None:
            raise ValueError(f"token for {holder!r}: {why}")
        if ttl is not None and not ttl > 0:
            raise ValueError(f"ttl for {holder!r}: a number of seconds > 0, got {ttl!r}")
        now = self.now()
        expires = float("inf") if ttl is None else now + ttl
        with self._lock:
            # the holder's previous token goes, and every grant past its time
            self._grants = {d: g for d, g in self._grants.items()
                            if (g.session or g.holder != holder) and g.expires > now}
            self._grants[_digest(token)] = _Grant(holder, expires, False)
        return token

    def revoke(self, holder: str) -> bool:
        """End `holder`'s token and cookies at once (and tell `on_revoke` callbacks); False: none held."""
        with self._lock:
            kept = {d: g for d, g in self._grants.items() if g.holder != holder}
            had = len(kept) != len(self._grants)
            self._grants = kept
        for callback in list(self._revoked):
            callback(holder)
        return had

    def check(self, token: str | None) -> str | None:
        """The holder of a link's token, or None (unknown, expired or revoked)."""
        return self._find(token, session=False)

    def session_holder(self, cookie: str | None) -> str | None:
        """The holder of a cookie's value from `exchange`, or None."""
        return self._find(cookie, session=True)

    def exchange(self, token: str | None) -> tuple[str, str, float] | None:
        """A link's token -> (holder, cookie value, expiry) for a browser to keep; None if the token
        is not valid. The cookie expires with the token and is revoked with its holder; a holder
        keeps its last MAX_COOKIES cookies."""
        with self._lock:
            grant = self._valid(token, session=False)
            if grant is None:
                return None
            cookies = [d for d, g in self._grants.items() if g.session and g.holder == grant.holder]
            for digest in cookies[:max(0, len(cookies) - MAX_COOKIES + 1)]:
                del self._grants[digest]    # the oldest (a dict keeps the order of insertion)
            cookie = new_token()
            self._grants[_digest(cookie)] = _Grant(grant.holder, grant.expires, True)
            return grant.holder, cookie, grant.expires

    def holders(self) -> list[str]:
        """The holders with a valid token or cookie."""
        now = self.now()
        with self._lock:
            return sorted({g.holder for g in self._grants.values() if g.expires > now})

    def on_revoke(self, callback: Callable[[str], None]) -> None:
        """Call `callback(holder)` after each revoke (on the revoking thread)."""
        self._revoked.append(callback)

    def _find(self, secret: str | None, session: bool) -> str | None:
        with self._lock:
            grant = self._valid(secret, session)
            return grant.holder if grant is not None else None

    def _valid(self, secret: str | None, session: bool) -> _Grant | None:
        if not secret:
            return None
        digest = _digest(secret)
        grant = self._grants.get(digest)
        if grant is None or grant.session != session:
            return None
        if grant.expires <= self.now():
            del self._grants[digest]
            return None
        return grant


class CookieGate:
    """aiohttp middleware: a request passes with a valid `?token=` (then a cookie is set) or cookie;
    else 403 (counted in `refused`). Paths under `open_prefixes` pass without (the page's own files).
    `secure=False` only for plain-http tests: a browser keeps Secure cookies from https (and localhost)."""

    def __init__(self, access: Access, cookie: str = COOKIE, secure: bool = True,
                 open_prefixes: tuple[str, ...] = (), refused_text: str = REFUSED):
        self.access, self.cookie, self.secure = access, cookie, secure
        self.open_prefixes = open_prefixes
        self.refused_text = refused_text
        self.refused = 0

    def holder(self, request: web.Request) -> str | None:
        """The holder a request's cookie names (None: no valid cookie)."""
        return self.access.session_holder(request.cookies.get(self.cookie))

    @web.middleware
    async def middleware(self, request: web.Request, handler):
        holder, cookie = self.holder(request), None
        token = request.query.get("token")
        if token is not None:              # a link opened: its holder, whoever the browser was before
            exchanged = self.access.exchange(token)
            if exchanged is not None:
                holder, cookie, expires = exchanged
        if holder is None and not request.path.startswith(self.open_prefixes or ("\0",)):
            self.refused += 1
            raise web.HTTPForbidden(text=self.refused_text)
        request[HOLDER] = holder
        response = await handler(request)
        if cookie is not None and not response.prepared:
            max_age = None if expires == float("inf") else max(1, int(expires - self.access.now()))
            response.set_cookie(self.cookie, cookie, max_age=max_age, path="/", secure=self.secure,
                                httponly=True, samesite="Strict")
        return response


def cross_site(request: web.Request) -> bool:
    """Whether a browser sent `request` from another site's page (cross-site WebSocket hijacking, a
    forged form POST): its `Origin` is not this server's, or its `Sec-Fetch-Site` says another site. A
    request with neither (a script, curl) is not a browser's and is judged by its token alone."""
    origin = request.headers.get("Origin")
    if origin is not None and urlsplit(origin).netloc != request.host:
        return True
    return request.headers.get("Sec-Fetch-Site", "same-origin") not in ("same-origin", "none")


# ---- the link ---------------------------------------------------------------------------------------


def lan_addresses(host: str) -> list[str]:
    """The addresses a headset on the LAN can use to reach a server bound to `host`."""
    if host not in ("0.0.0.0", "::", ""):
        return [host]
    found = []
    # A UDP "connection" sends nothing: it only asks the kernel which local address routes outward.
    # 192.0.2.1 is a documentation address (RFC 5737) that is never contacted.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("192.0.2.1", 9))
            found.append(probe.getsockname()[0])
        except OSError:
            pass
    try:
        for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET):
            found.append(info[4][0])
    except OSError:
        pass
    lan = [a for a in dict.fromkeys(found) if not is_loopback(a)]
    return lan or ["127.0.0.1"]


def page_url(scheme: str, address: str, port: int, token: str | None) -> str:
    host = f"[{address}]" if ":" in address else address
    return f"{scheme}://{host}:{port}/" + (f"?token={token}" if token else "")


def qr_text(url: str) -> str:
    """The URL as a QR code drawn with block characters, for a headset's camera or a phone."""
    import io

    import segno

    out = io.StringIO()
    segno.make(url, error="l").terminal(out=out, compact=True)
    return out.getvalue()

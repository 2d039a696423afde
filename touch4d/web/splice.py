"""Two TCP connections joined byte for byte (the study server's page WebSocket, once the upgrade was
answered 101): what one side reads is written to the other as it comes, no frame parsed.

Flow control: a side whose unsent bytes pass `high_water` stops the other side reading until they
drain below `low_water` (a slow browser cannot grow the server's memory without bound). A side that
stays over the mark for `stall_s` is taken for gone and both are cut: the side stopped reading
would not even notice its peer's end. When a side closes, the other's unsent bytes get `grace_s`
to leave before it is cut (a vanished peer never drains them).
"""
from __future__ import annotations

import asyncio
import http.client
import io
from typing import Callable

HIGH_WATER = 256 * 1024     # bytes a side may hold unsent before the other side stops reading
LOW_WATER = 64 * 1024       # ... and reads again once they drained below this
GRACE_S = 5.0               # a side closed: the other's unsent bytes leave within this, or it is cut
STALL_S = 10.0              # a side that takes nothing of its unsent bytes for this long is cut (twice
                            # the page server's own limit for a page that takes no frame)
MAX_HEAD = 16 * 1024        # an upstream response head longer than this is not an HTTP server's
MAX_BODY = 64 * 1024        # a refusal's body passed on, at most

Tap = Callable[[bytes], None]


class SpliceError(ConnectionError):
    """The upstream server did not answer the upgrade with an HTTP response."""


class _End(asyncio.Protocol):
    """One connection of a splice: what it reads goes to the other's transport (and its tap)."""

    def __init__(self, splice: "Splice", tap: Tap | None):
        self.splice, self.tap = splice, tap
        self.transport: asyncio.Transport | None = None
        self.other: _End | None = None
        self.lost = False
        self._stall: asyncio.TimerHandle | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        if self.tap is not None:   # the client's bytes: tapped as they arrive
            self.tap(data)
        self.other.transport.write(data)

    def eof_received(self) -> bool:
        return False   # a half-close ends the splice: the transport closes, connection_lost follows

    def pause_writing(self) -> None:
        # this side's unsent bytes passed the high-water mark: the other side stops reading
        if not self.other.transport.is_closing():
            self.other.transport.pause_reading()
        self._stall = asyncio.get_running_loop().call_later(self.splice.stall_s, self.splice.abort)

    def resume_writing(self) -> None:
        if self._stall is not None:
            self._stall.cancel()
            self._stall = None
        if not self.other.transport.is_closing():
            self.other.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = True
        if self._stall is not None:
            self._stall.cancel()
        self.splice._lost()


class _Upstream(_End):
    """The server's side: what it sends is held until the splice is joined (its response head first)."""

    def __init__(self, splice: "Splice", tap: Tap | None):
        super().__init__(splice, tap)
        self.received = bytearray()
        self.arrived = asyncio.Event()     # more of `received`, or the connection's end
        self.joined = False

    def data_received(self, data: bytes) -> None:
        if self.joined:
            self.other.transport.write(data)
            if self.tap is not None:   # the server's bytes: tapped once passed on
                self.tap(data)
            return
        self.received += data
        self.arrived.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.arrived.set()
        super().connection_lost(exc)

    async def until(self, enough: Callable[[], bool]) -> None:
        """Wait for `received` to be `enough` or the connection to end."""
        while not enough() and not self.lost:
            self.arrived.clear()
            await self.arrived.wait()


class Splice:
    """Opens the upstream connection (`upgrade`), then joins a client's transport to it (`join`).
    `to_server` is called with each chunk of the client's as it arrives, `to_client` with each of
    the server's once it was passed on (the wire trace's two instants; both on the hot path).
    `closed` is done when every connection of it is."""

    def __init__(self, to_server: Tap | None = None, to_client: Tap | None = None, *,
                 high_water: int = HIGH_WATER, low_water: int = LOW_WATER, grace_s: float = GRACE_S,
                 stall_s: float = STALL_S):
        self._loop = asyncio.get_running_loop()
        self.client = _End(self, to_server)
        self.server = _Upstream(self, to_client)
        self.client.other, self.server.other = self.server, self.client
        self.high_water, self.low_water, self.grace_s, self.stall_s = high_water, low_water, grace_s, stall_s
        self.closed: asyncio.Future = self._loop.create_future()
        self._head_end = 0
        self._cut: asyncio.TimerHandle | None = None

    async def upgrade(self, host: str, port: int, request: bytes,
                      timeout: float) -> tuple[int, http.client.HTTPMessage, bytes]:
        """Connect to host:port, send `request` (an HTTP upgrade) and read the response: its status, its
        headers and, unless 101, its body (at most MAX_BODY; the connection is closed then). Raises
        OSError (SpliceError included) or TimeoutError when there is no HTTP answer within `timeout`."""
        server = self.server
        try:
            async with asyncio.timeout(timeout):
                await self._loop.create_connection(lambda: server, host, port)
                server.transport.write(request)
                await server.until(lambda: b"\r\n\r\n" in server.received or len(server.received) > MAX_HEAD)
                end = server.received.find(b"\r\n\r\n") + 4
                if end < 4:
                    raise SpliceError("no HTTP response head" + ("" if server.lost else f" within {MAX_HEAD} bytes"))
                status_line, _, fields = bytes(server.received[:end]).partition(b"\r\n")
                try:
                    status = int(status_line.split(b" ", 2)[1])
                    headers = http.client.parse_headers(io.BytesIO(fields))
                except (ValueError, IndexError, http.client.HTTPException):
                    raise SpliceError(f"not an HTTP response: {status_line[:80]!r}") from None
                self._head_end = end
                if status == 101:
                    return status, headers, b""
                try:   # a refusal's body: as much as it says (or until it closes)
                    length = min(int(headers.get("Content-Length", MAX_BODY)), MAX_BODY)
                except ValueError:
                    length = 0
                await server.until(lambda: len(server.received) - end >= length)
                body = bytes(server.received[end:end + length])
        except BaseException:
            self.close()
            raise
        self.close()
        return status, headers, body

    def join(self, transport: asyncio.Transport | None,
             take: Callable[[asyncio.Transport, asyncio.BaseProtocol], None] | None = None) -> bool:
        """Take `transport` (the client's, from whoever served it until now: `take(transport, protocol)`
        hands it over, by default its set_protocol; a server's guard keeps counting it), write it the
        upstream's 101 head and what followed it, then pass bytes both ways. False, the upstream
        closed: the client had gone (its transport None or closing: it may have left while the
        upstream answered)."""
        if transport is None or transport.is_closing():
            self.close()
            return False
        server = self.server
        self.client.transport = transport
        if take is None:
            transport.set_protocol(self.client)
        else:
            take(transport, self.client)
        for end in (self.client, server):
            end.transport.set_write_buffer_limits(self.high_water, self.low_water)
        received, server.received, server.joined = server.received, bytearray(), True
        transport.write(bytes(received[:self._head_end]))
        if len(received) > self._head_end:
            server.data_received(bytes(received[self._head_end:]))
        if not transport.is_reading():
            transport.resume_reading()
        return True

    async def finish(self, protocol: asyncio.BaseProtocol) -> None:
        """Once joined: wait until either side closes, close both, and tell `protocol` (aiohttp's
        handler of the client's connection, which the splice took) that its connection is gone, so
        the response its handler then returns writes nothing."""
        try:
            await self.closed
        finally:
            self.close()
            protocol.connection_lost(None)

    def close(self) -> None:
        """Close both connections (their unsent bytes get `grace_s` to leave, then they are cut)."""
        for end in (self.client, self.server):
            if end.transport is not None and not end.transport.is_closing():
                end.transport.close()
        if not self._ended() and self._cut is None:
            self._cut = self._loop.call_later(self.grace_s, self.abort)

    def abort(self) -> None:
        """Cut both connections, their unsent bytes dropped."""
        for end in (self.client, self.server):
            if end.transport is not None and not end.lost:
                end.transport.abort()

    def _lost(self) -> None:
        """A connection ended: the other closes too."""
        if not self._ended():
            self.close()

    def _ended(self) -> bool:
        """Every connection opened (the client's only once joined) has ended: `closed` is done."""
        if all(end.lost for end in (self.client, self.server) if end.transport is not None):
            if self._cut is not None:
                self._cut.cancel()
            if not self.closed.done():
                self.closed.set_result(None)
            return True
        return False

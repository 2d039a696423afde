"""Two loopback connections spliced (touch4d.web.splice), no WebSocket: the upstream's 101 head and
what follows it reach the client, bytes pass both ways unchanged (megabytes, at once), a client that
does not read stops the upstream being read (bounded memory) and gets everything once it reads,
either side's close closes the other, a refusal comes back with its status and body."""
from __future__ import annotations

import asyncio
import os

import pytest

from touch4d.web.splice import Splice, SpliceError

pytestmark = pytest.mark.timeout(60)

HEAD = b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\r\n"
REQUEST = b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\r\n"


class Upstream:
    """A loopback server: reads a request head, answers `answer`, then keeps its streams."""

    def __init__(self, answer: bytes):
        self.answer = answer
        self.request = b""
        self.streams: asyncio.Future | None = None

    async def start(self) -> int:
        self.streams = asyncio.get_running_loop().create_future()
        self.server = await asyncio.start_server(self._connected, "127.0.0.1", 0)
        return self.server.sockets[0].getsockname()[1]

    async def _connected(self, reader, writer):
        self.request = await reader.readuntil(b"\r\n\r\n")
        writer.write(self.answer)
        self.streams.set_result((reader, writer))

    async def close(self):
        self.server.close()
        await self.server.wait_closed()


class Front(asyncio.Protocol):
    """The client's connection as a server took it (aiohttp's, in the study server)."""

    def __init__(self, made: asyncio.Future):
        self.made = made

    def connection_made(self, transport):
        self.made.set_result(transport)


async def spliced(answer: bytes = HEAD, **kw):
    """(splice, client reader, client writer, upstream reader, upstream writer, upstream)."""
    loop = asyncio.get_running_loop()
    upstream = Upstream(answer)
    port = await upstream.start()
    made = loop.create_future()
    front = await loop.create_server(lambda: Front(made), "127.0.0.1", 0)
    reader, writer = await asyncio.open_connection("127.0.0.1", front.sockets[0].getsockname()[1])
    transport = await made
    front.close()
    taps = ([], [])
    splice = Splice(taps[0].append, taps[1].append, **kw)
    splice.taps = taps
    status, _, _ = await splice.upgrade("127.0.0.1", port, REQUEST, timeout=10)
    assert status == 101 and upstream.request == REQUEST
    up_reader, up_writer = await upstream.streams
    assert splice.join(transport)
    return splice, reader, writer, up_reader, up_writer, upstream


def test_bytes_pass_both_ways_unchanged_the_head_first():
    async def main():
        splice, reader, writer, up_reader, up_writer, upstream = await spliced(HEAD + b"early")
        assert await reader.readexactly(len(HEAD) + 5) == HEAD + b"early"   # what followed the head too
        down, up = os.urandom(8 << 20), os.urandom(8 << 20)

        async def send(w, data):
            for i in range(0, len(data), 100_000):
                w.write(data[i:i + 100_000])
                await w.drain()

        got = await asyncio.gather(send(writer, up), send(up_writer, down),
                                   up_reader.readexactly(len(up)), reader.readexactly(len(down)))
        assert got[2] == up and got[3] == down
        assert b"".join(splice.taps[0]) == up                       # the client's bytes, as they came
        assert b"".join(splice.taps[1]) == b"early" + down           # the server's, once passed on
        writer.close()
        await asyncio.wait_for(splice.closed, 10)
        await upstream.close()
    asyncio.run(main())


def test_a_client_that_does_not_read_stops_the_upstream_being_read_and_gets_everything_later():
    async def main():
        high = 64 * 1024
        splice, reader, writer, up_reader, up_writer, upstream = await spliced(high_water=high, low_water=high // 4)
        await reader.readexactly(len(HEAD))
        data = os.urandom(48 << 20)     # far more than the kernel's buffers of both connections hold
        sending = asyncio.ensure_future(_send_all(up_writer, data))
        await asyncio.sleep(1.0)
        # the splice holds no more than its high-water mark (and a read) unsent: the upstream waits
        assert not splice.server.transport.is_reading()
        assert splice.client.transport.get_write_buffer_size() <= high + 256 * 1024
        assert not sending.done()
        assert await reader.readexactly(len(data)) == data           # read now: all of it, in order
        await asyncio.wait_for(sending, 10)
        assert splice.server.transport.is_reading()
        up_writer.close()
        await asyncio.wait_for(splice.closed, 10)
        await upstream.close()
    asyncio.run(main())


async def _send_all(writer, data):
    for i in range(0, len(data), 1 << 20):
        writer.write(data[i:i + (1 << 20)])
        await writer.drain()


@pytest.mark.parametrize("closing", ["client", "upstream"])
def test_either_sides_close_closes_the_other_after_its_last_bytes(closing):
    async def main():
        splice, reader, writer, up_reader, up_writer, upstream = await spliced()
        await reader.readexactly(len(HEAD))
        if closing == "client":
            writer.write(b"last words")
            writer.close()
            assert await up_reader.read() == b"last words"           # then EOF: the splice closed it
        else:
            up_writer.write(b"last words")
            up_writer.close()
            assert await reader.read() == b"last words"
        await asyncio.wait_for(splice.closed, 10)
        assert splice.client.transport.is_closing() and splice.server.transport.is_closing()
        await upstream.close()
    asyncio.run(main())


def test_a_client_that_never_reads_is_cut_once_it_stalled_and_after_the_grace_once_upstream_went():
    async def main():
        # stalled: the upstream (not read meanwhile) went, as the page server cuts a page taking no frame
        splice, reader, writer, up_reader, up_writer, upstream = await spliced(high_water=1 << 16, stall_s=2.0)
        up_writer.write(os.urandom(32 << 20))    # more than the client's kernel buffers: it stays unsent
        await asyncio.sleep(0.3)
        assert not splice.server.transport.is_reading()
        up_writer.transport.abort()
        await asyncio.sleep(0.3)
        assert not splice.closed.done()          # a stall is not cut at once ...
        await asyncio.wait_for(splice.closed, 5)  # ... but after stall_s
        writer.close()
        await upstream.close()
        # under the high-water mark, the upstream closing: the client's unsent bytes get the grace
        splice, reader, writer, up_reader, up_writer, upstream = await spliced(high_water=256 << 20, grace_s=1.0)
        up_writer.write(os.urandom(32 << 20))
        up_writer.close()
        await asyncio.wait_for(_until(lambda: splice.server.lost), 5)
        assert splice.client.transport.get_write_buffer_size() > 0 and not splice.closed.done()
        await asyncio.wait_for(splice.closed, 5)
        writer.close()
        await upstream.close()


async def _until(predicate):
    while not predicate():
        await asyncio.sleep(0.01)
        writer.close()
        await upstream.close()
    asyncio.run(main())


def test_a_refusal_comes_back_with_its_status_and_body_and_no_answer_is_an_error():
    async def main():
        body = b"touch4d: 1 pages are connected already\n"
        upstream = Upstream(b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n"
                            b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
        port = await upstream.start()
        splice = Splice()
        status, headers, got = await splice.upgrade("127.0.0.1", port, REQUEST, timeout=10)
        assert (status, headers["Content-Type"], got) == (503, "text/plain; charset=utf-8", body)
        await asyncio.wait_for(splice.closed, 5)             # its connection closed
        await upstream.close()
        mute = Upstream(b"not http at all")                  # closes after this: no head
        port = await mute.start()
        splice = Splice()
        task = asyncio.ensure_future(splice.upgrade("127.0.0.1", port, REQUEST, timeout=10))
        (_, w) = await mute.streams
        w.close()
        with pytest.raises(SpliceError):
            await task
        await mute.close()
        with pytest.raises(OSError):                         # nobody listening
            await Splice().upgrade("127.0.0.1", port, REQUEST, timeout=10)
    asyncio.run(main())


def test_a_client_gone_while_the_upstream_answered_closes_the_upstream():
    """The browser left during the upgrade (aiohttp's request then has no transport): join says so,
    and the participant's page server sees its connection closed, its page slot free again."""
    async def main():
        upstream = Upstream(HEAD)
        port = await upstream.start()
        splice = Splice(lambda data: None, lambda data: None)
        status, _, _ = await splice.upgrade("127.0.0.1", port, REQUEST, timeout=10)
        up_reader, up_writer = await upstream.streams
        assert status == 101
        assert splice.join(None) is False
        assert await asyncio.wait_for(up_reader.read(), 10) == b""   # end of stream: closed
        up_writer.close()
        await upstream.close()
    asyncio.run(main())

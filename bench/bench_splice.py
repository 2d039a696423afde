"""The study server's share of a page's WebSocket: CPU per page input in the front (its own thread and
event loop, `time.thread_time`) between a page and its page server, each input answered by one frame
as the webxr node does. Splice (touch4d.web.splice, what the study server does) against the baseline
measured in the same run: the aiohttp relay it replaced (a WebSocket each side, every message parsed,
re-framed and re-masked both ways); and the splice with the wire trace on (`--wire-trace`, both
directions read by aiohttp's frame reader). Rounds interleaved; medians.

    .venv/bin/python bench/bench_splice.py [--inputs 3000] [--rounds 3] [--frame-bytes 2048]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import aiohttp
from aiohttp import WSMsgType, web

from touch4d.eventloop import new_event_loop
from touch4d.web.splice import Splice
from touch4d.web.studyserver import _upgrade_request
from touch4d.web.wiretrace import WireTrace


class Loop:
    """An event loop in a thread of its own (the study server's kind: touch4d.eventloop); `call(coro)`
    runs a coroutine there and returns its result."""

    def __init__(self):
        self.loop = new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def call(self, coro, timeout: float = 60.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def stop(self):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)


async def _cpu() -> float:
    return time.thread_time()


async def serve(app: web.Application) -> tuple[web.AppRunner, int]:
    runner = web.AppRunner(app, access_log=None, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    return runner, runner.addresses[0][1]


def page_server(frame: bytes) -> web.Application:
    """The participant's page server, reduced to its wire: each text message answered by one frame."""
    async def ws_handler(request):
        ws = web.WebSocketResponse(max_msg_size=16384, compress=False, autoping=False)
        await ws.prepare(request)
        async for msg in ws:
            if msg.type == WSMsgType.TEXT:
                await ws.send_bytes(frame)
        return ws
    app = web.Application()
    app.router.add_get("/ws", ws_handler)
    return app


def relay_front(port: int) -> web.Application:
    """The baseline: the study server's relay before the splice (two WebSockets, messages copied)."""
    async def ws_handler(request):
        client = request.app["client"]
        upstream = await client.ws_connect(f"ws://127.0.0.1:{port}/ws", max_msg_size=0,
                                           origin=f"http://127.0.0.1:{port}")
        ws = web.WebSocketResponse(max_msg_size=1 << 20, compress=False, heartbeat=5.0)
        await ws.prepare(request)

        async def up():
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    await upstream.send_str(msg.data)

        async def down():
            async for msg in upstream:
                if msg.type == WSMsgType.BINARY:
                    await ws.send_bytes(msg.data)

        tasks = [asyncio.ensure_future(up()), asyncio.ensure_future(down())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await upstream.close()
            await ws.close()
        return ws

    async def session(app):
        app["client"] = aiohttp.ClientSession()
        yield
        await app["client"].close()
    app = web.Application()
    app.cleanup_ctx.append(session)
    app.router.add_get("/ws", ws_handler)
    return app


def splice_front(port: int, trace: WireTrace | None) -> web.Application:
    """The study server's way: the upgrade passed on, then the two connections spliced."""
    async def ws_handler(request):
        splice = Splice(None if trace is None else trace.page_bytes("P01"),
                        None if trace is None else trace.frame_bytes("P01"))
        status, _, body = await splice.upgrade("127.0.0.1", port, _upgrade_request(request, port), 10)
        if status != 101:
            return web.Response(status=status, body=body)
        if splice.join(request.transport):
            await splice.finish(request.protocol)
        return web.Response()
    app = web.Application()
    app.router.add_get("/ws", ws_handler)
    return app


async def page(port: int, inputs: int, front: Loop) -> tuple[float, float]:
    """A page sending `inputs` inputs, each after the frame of the one before: (front CPU s, median
    round trip s)."""
    text = json.dumps({"type": "input", "time": 0.0, "tracking": True, "head": [0.0] * 7,
                       "sources": [{"hand": "right", "grip": [0.1] * 7, "buttons": [0] * 6}]})
    trips = []
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(f"http://127.0.0.1:{port}/ws", origin=f"http://127.0.0.1:{port}") as ws:
            for _ in range(50):   # warm
                await ws.send_str(text)
                await ws.receive()
            cpu = front.call(_cpu())
            for i in range(inputs):
                t0 = time.perf_counter()
                await ws.send_str(text.replace('"time": 0.0', f'"time": {i}.5', 1))
                msg = await ws.receive()
                assert msg.type == WSMsgType.BINARY
                trips.append(time.perf_counter() - t0)
            cpu = front.call(_cpu()) - cpu
    return cpu, statistics.median(trips)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=int, default=3000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--frame-bytes", type=int, default=2048)
    args = parser.parse_args()
    upstream, front = Loop(), Loop()
    up_runner, up_port = upstream.call(serve(page_server(os.urandom(args.frame_bytes))))
    results: dict[str, list[tuple[float, float]]] = {"relay": [], "splice": [], "splice+trace": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for name in results:
                trace = WireTrace(Path(tmp) / "wire.csv") if name == "splice+trace" else None
                app = relay_front(up_port) if name == "relay" else splice_front(up_port, trace)
                runner, port = front.call(serve(app))
                results[name].append(asyncio.run(page(port, args.inputs, front)))
                front.call(runner.cleanup())
                if trace is not None:
                    trace.close()
    front.stop()
    upstream.call(up_runner.cleanup())
    upstream.stop()
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; {args.inputs} inputs a round, "
          f"{args.rounds} rounds, frames of {args.frame_bytes} bytes")
    base = statistics.median(cpu for cpu, _ in results["relay"]) / args.inputs
    for name, rounds in results.items():
        cpu = statistics.median(c for c, _ in rounds) / args.inputs
        trip = statistics.median(t for _, t in rounds)
        print(f"{name:13s} front CPU {cpu * 1e6:6.1f} us per input (x{cpu / base:.2f} of the relay; "
              f"{cpu * 72 * 100:.2f} % of a core per participant at 72 Hz); round trip p50 {trip * 1e3:.2f} ms")


if __name__ == "__main__":
    main()

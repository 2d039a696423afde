"""Stuck consumers under the demo: a subscriber that never reads and 1,000 idle WebSocket pages.

The haptic pipeline of bench_e2e (scene, tactile, motors with emulated boards and `trace: true`,
every node a process; the bench publishes `hand/pose` at 90 Hz) runs beside a `webxr` node, with
the broker in a process of its own (`touch4d bus broker`), twice:

1. baseline: nothing else;
2. stuck: plus a process subscribed to every topic that never reads, and 1,000 WebSocket
   connections to the page server that never read (kept at 1,000: a connection the server closes
   is opened again at once).

For each run it prints the pose -> CAN duty frame latency (p50, p99) and the peak resident memory
of the broker, the webxr node (its page server) and the motor node, sampled every 0.1 s, and the
ratios stuck / baseline. What keeps them bounded: the broker's ZeroMQ high-water mark (the bus
file's `hwm` messages per subscriber), the page server's `max_pages` and its WebSocket heartbeat.

    .venv/bin/python bench/bench_stuck.py [--seconds 60] [--pages 1000]
"""
from __future__ import annotations

import argparse
import asyncio
import os
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import aiohttp
import numpy as np

from bench_e2e import SCENE, Probe, bench_glove
from touch4d.bus.config import load_bus_config
from touch4d.bus.testing import ProcessOutput, free_port, node_process

ROLES = ("broker", "webxr", "motors")


def rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS:"))
    except (OSError, StopIteration):
        return float("nan")


class Peaks(threading.Thread):
    """The largest resident memory of each process, sampled every 0.1 s until stopped."""

    def __init__(self, pids: dict[str, int]):
        super().__init__(daemon=True)
        self.pids, self.peak, self.done = pids, {k: 0.0 for k in pids}, threading.Event()

    def run(self):
        while not self.done.wait(0.1):
            for k, pid in self.pids.items():
                self.peak[k] = max(self.peak[k], rss_mb(pid))

    def stop(self) -> dict[str, float]:
        self.done.set()
        self.join()
        return self.peak


class IdlePages(threading.Thread):
    """`count` WebSocket connections that never read; one the server closes is opened again."""

    def __init__(self, url: str, count: int):
        super().__init__(daemon=True)
        self.url, self.count = url, count
        self.opened = self.refused = 0
        self.stop_flag = threading.Event()

    def run(self):
        asyncio.run(self._main())

    async def _main(self):
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as session:
            held: list = []
            while not self.stop_flag.is_set():
                held = [ws for ws in held if not ws.closed and not ws._reader.exception()]
                missing = self.count - len(held)
                if missing > 0:
                    tries = await asyncio.gather(*[session.ws_connect(self.url, autoping=False)
                                                   for _ in range(missing)], return_exceptions=True)
                    for t in tries:
                        if isinstance(t, BaseException):
                            self.refused += 1
                        else:
                            self.opened += 1
                            held.append(t)
                await asyncio.sleep(0.5)
            for ws in held:
                await ws.close()


def run_phase(probe: Probe, pids: dict[str, int], seconds: float) -> dict:
    peaks = Peaks(pids)
    peaks.start()
    probe.traces.clear()
    published = probe.run(90.0, seconds)
    probe.settle(0.5)
    src, frame = probe.traced()
    mine = np.isin(src, published)
    lat = frame[mine] - src[mine]
    return {"lat": lat, "peak": peaks.stop(), "published": len(published)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds of each run")
    parser.add_argument("--pages", type=int, default=1000, help="idle WebSocket connections")
    args = parser.parse_args()
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())} ({os.cpu_count()} cores)")
    with tempfile.TemporaryDirectory(prefix="bench-stuck-") as tmp:
        tmp = Path(tmp)
        glove = bench_glove(tmp)
        pub_port, sub_port, web_port = free_port(), free_port(), free_port()
        bus_file = tmp / "bus.yaml"
        bus_file.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {pub_port}, sub_port: {sub_port}}}\n"
                            "connect: 127.0.0.1\n")
        bus = load_bus_config(bus_file)
        broker = ProcessOutput(subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "bus", "broker", "--bus",
                                                 str(bus_file)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
        stuck = None
        try:
            broker.wait_for_line("broker: publishers connect", timeout=30)
            with node_process("scene", bus, params={"scene": str(SCENE)}), \
                    node_process("tactile", bus, params={"glove": str(glove)}, realtime=True), \
                    node_process("motors", bus, params={"glove": str(glove), "emulate": True, "trace": True,
                                                        "channel": f"bench-stuck-{uuid.uuid4().hex}"},
                                 realtime=True) as motors, \
                    node_process("webxr", bus, params={"port": web_port, "save_calibration": False}) as webxr:
                webxr.wait_for_line("WebXR page", timeout=60)
                pids = {"broker": broker.pid, "webxr": webxr.pid, "motors": motors.pid}
                probe = Probe(bus)
                try:
                    deadline = time.monotonic() + 30
                    while not probe.traces:
                        if time.monotonic() > deadline:
                            raise SystemExit("no motors/trace within 30 s")
                        probe.run(90.0, 0.2)
                    base = run_phase(probe, pids, args.seconds)
                    stuck = ProcessOutput(subprocess.Popen([sys.executable, "-u", "-c",
                        "import time, zmq; s = zmq.Context().socket(zmq.SUB); s.setsockopt(zmq.SUBSCRIBE, b''); "
                        f"s.connect('tcp://127.0.0.1:{sub_port}'); print('subscribed', flush=True); time.sleep(1e6)"],
                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
                    stuck.wait_for_line("subscribed", timeout=30)
                    pages = IdlePages(f"http://127.0.0.1:{web_port}/ws", args.pages)
                    pages.start()
                    time.sleep(2.0)
                    loaded = run_phase(probe, pids, args.seconds)
                    pages.stop_flag.set()
                    pages.join(30)
                finally:
                    probe.node.shutdown()
        finally:
            for p in (broker, stuck):
                if p is not None:
                    p.proc.kill()
                    p.proc.wait()
                    p.join()
    print(f"\n{args.seconds:.0f} s each at 90 Hz poses; stuck: 1 subscriber that never reads, {args.pages} idle pages "
          f"({pages.opened} connections opened over the run, {pages.refused} refused)")
    print(f"{'':28s}{'baseline':>12s}{'stuck':>12s}{'ratio':>9s}")
    for q in (50, 99):
        b, s = np.percentile(base["lat"], q) * 1e3, np.percentile(loaded["lat"], q) * 1e3
        print(f"{'pose -> CAN p' + str(q) + ' (ms)':28s}{b:12.2f}{s:12.2f}{s / b:8.2f}x")
    for role in ROLES:
        b, s = base["peak"][role], loaded["peak"][role]
        print(f"{'peak memory ' + role + ' (MB)':28s}{b:12.0f}{s:12.0f}{s / b:8.2f}x")
    print(f"load average at end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()

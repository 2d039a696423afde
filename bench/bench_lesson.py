"""Lesson benchmark: a teacher's change -> every student's page, and what each student costs the server.

`touch4d lesson serve` runs as a process; N simulated students (plain WebSocket clients, this process,
each a student of its own through the class link) read every frame and send a tracked input with what
their page played at `--input-hz`, as a headset's page does. The teacher's terminal sends `--changes`
slice commands (`touch4d lesson command`'s function), one every 150 ms; per change and page:

    change -> page   from just before the command connects to the frame of its scene revision arriving
                     at that page's socket (this machine's clock: no clock offset).

Baseline, in the same run: the same changes with one student. Server cost per student: its CPU time
(utime + stime, /proc) and resident memory with N students minus with none, over the same window, /N.
`--delay-ms 50`: the students also through a relay on loopback that holds every chunk that long each
way (touch4d.web.testing.DelayRelay; this kernel has no netem): the change then reaches a page one
delay later, as over a home connection.

    .venv/bin/python bench/bench_lesson.py [--students 30] [--changes 40] [--input-hz 30] [--delay-ms 50]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import aiohttp
import numpy as np

from cpu import cpu_seconds
from touch4d.tracking.calibration import load_calibration
from touch4d.web.lessonserver import send_command
from touch4d.web.protocol import frame_header

REPO = Path(__file__).resolve().parents[1]
PERIOD_S = 0.15
# the relay in a process of its own (in this one it would share the interpreter with the pages)
RELAY = ("import signal, sys, time\nfrom touch4d.web.testing import DelayRelay\n"
         "signal.signal(signal.SIGINT, lambda *_: sys.exit(0))\n"
         "with DelayRelay(int(sys.argv[1]), float(sys.argv[2])) as relay:\n"
         "    print(relay.port, flush=True)\n    while True: time.sleep(60)\n")


def serve(out: Path, students: int):
    proc = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "lesson", "serve",
                             "config/scenes/hypercube.yaml", "--out", str(out), "--port", "0", "--no-record",
                             "--max-students", str(students)], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    links = {}
    while len(links) < 2:
        line = proc.stdout.readline()
        if not line:
            raise SystemExit("the lesson did not start")
        m = re.match(r"(teacher|class) link: (\S+)", line)
        if m:
            links[m.group(1)] = m.group(2)
    said = proc.said = []   # its output read on (a full pipe would stop the server at its next line)
    threading.Thread(target=lambda: said.extend(proc.stdout), daemon=True).start()
    return proc, links


def stop(proc) -> None:
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(20)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def rss_bytes(pid: int) -> int:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class Student:
    """One simulated page: reads every frame (noting when each scene revision arrived) and sends inputs."""

    def __init__(self, session, ws, grip):
        self.session, self.ws, self.arrived = session, ws, {}
        self.input = {"type": "input", "time": 0.0, "tracking": True, "head": None, "played": None,
                      "sources": [{"handedness": "right", "trigger": 0.0, "buttons": [], "grip": grip}]}

    async def read(self):
        async for msg in self.ws:
            if msg.type == aiohttp.WSMsgType.BINARY:
                header = frame_header(msg.data)
                revision = header.get("revision")
                if header.get("kind") == "frame" and revision is not None and revision not in self.arrived:
                    self.arrived[revision] = time.perf_counter()

    async def send(self, hz: float):
        while not self.ws.closed and hz > 0:
            now = time.time() * 1000
            self.input["time"] = now
            self.input["played"] = {"time": now - 14, "intensity": [0.4]}
            await self.ws.send_str(json.dumps(self.input))
            await asyncio.sleep(1 / hz)


async def join(link: str, grip) -> Student:
    session = aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True))
    async with session.get(link) as page:
        await page.read()
    netloc = urlsplit(link).netloc
    ws = await session.ws_connect(f"ws://{netloc}/ws", headers={"Origin": f"http://{netloc}"}, max_msg_size=0)
    return Student(session, ws, grip)


async def run(out: Path, link: str, pid: int, students: int, changes: int, input_hz: float) -> dict:
    cal = load_calibration(None, "hand_in_grip")
    room, quat = cal.controller_from_hand(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    grip = [*room.tolist(), *quat.tolist()]
    idle_cpu, idle_rss, t0 = cpu_seconds(pid), rss_bytes(pid), time.perf_counter()
    await asyncio.sleep(2.0)
    idle_rate = (cpu_seconds(pid) - idle_cpu) / (time.perf_counter() - t0)
    pages, tasks = [], []
    for _ in range(students):   # each reads from its join on: it answers the server's pings, as a browser does
        pages.append(await join(link, grip))
        tasks.append(asyncio.ensure_future(pages[-1].read()))
    tasks += [asyncio.ensure_future(p.send(input_hz)) for p in pages]
    await asyncio.sleep(1.0)
    cpu0, t0 = cpu_seconds(pid), time.perf_counter()
    delays = []
    for k in range(changes):
        sent = time.perf_counter()
        ok, text = await send_command(out, "slice", f"{1.2 + 0.01 * (k % 20):.2f}")
        assert ok, text
        revision = await _revision(pages[0], sent)
        await asyncio.sleep(PERIOD_S)
        for p in pages:
            if revision in p.arrived:
                delays.append(p.arrived[revision] - sent)
    cpu_rate = (cpu_seconds(pid) - cpu0) / (time.perf_counter() - t0)
    rss = rss_bytes(pid)
    for task in tasks:
        task.cancel()
    for p in pages:
        await p.ws.close()
        await p.session.close()
    d = np.array(delays) * 1000
    return {"students": students, "frames": len(d), "expected": students * changes,
            "p50": float(np.percentile(d, 50)), "p99": float(np.percentile(d, 99)), "max": float(d.max()),
            "cpu_per_student": (cpu_rate - idle_rate) / students, "rss_per_student": (rss - idle_rss) / students}


async def _revision(page: Student, since: float) -> int:
    """The revision of the first scene that reached `page` after `since`."""
    for _ in range(2000):
        fresh = [r for r, t in page.arrived.items() if t >= since]
        if fresh:
            return max(fresh)
        await asyncio.sleep(0.001)
    raise SystemExit("no frame of the change arrived within 2 s")


def measure(students: int, changes: int, input_hz: float, delay_ms: float = 0.0) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-lesson-") as tmp:
        out = Path(tmp) / "lesson"
        proc, links = serve(out, max(students, 1))
        try:
            link = links["class"]
            if not delay_ms:
                return asyncio.run(run(out, link, proc.pid, students, changes, input_hz))
            port = urlsplit(link).port
            relay = subprocess.Popen([sys.executable, "-c", RELAY, str(port), str(delay_ms / 1000.0)], cwd=REPO,
                                     stdout=subprocess.PIPE, text=True, start_new_session=True)
            try:
                relay_port = int(relay.stdout.readline())
                link = link.replace(f":{port}/", f":{relay_port}/")
                return {**asyncio.run(run(out, link, proc.pid, students, changes, input_hz)), "delay_ms": delay_ms}
            finally:
                stop(relay)
        finally:
            stop(proc)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--students", type=int, default=30)
    parser.add_argument("--changes", type=int, default=40)
    parser.add_argument("--input-hz", type=float, default=30.0, help="each student's inputs per second")
    parser.add_argument("--delay-ms", type=float, nargs="*", default=[50.0],
                        help="also with the students through a relay adding this delay each way")
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.2f}")
    base = measure(1, args.changes, args.input_hz)
    many = measure(args.students, args.changes, args.input_hz)
    for r in (base, many):
        print(f"{r['students']:3d} students: change -> page p50 {r['p50']:.1f} ms, p99 {r['p99']:.1f} ms, "
              f"max {r['max']:.1f} ms ({r['frames']}/{r['expected']} frames); server per student: "
              f"{100 * r['cpu_per_student']:.2f} % of a core, {r['rss_per_student'] / 1e6:.2f} MB")
    print(f"ratio {args.students} students / 1: p50 {many['p50'] / base['p50']:.2f}x, "
          f"p99 {many['p99'] / base['p99']:.2f}x")
    for delay in args.delay_ms:
        r = measure(args.students, args.changes, args.input_hz, delay)
        print(f"{r['students']:3d} students through {delay:.0f} ms each way: change -> page p50 {r['p50']:.1f} ms, "
              f"p99 {r['p99']:.1f} ms ({r['frames']}/{r['expected']} frames); x{r['p50'] / many['p50']:.2f} p50 of "
              "no delay")
    return 0


if __name__ == "__main__":
    sys.exit(main())

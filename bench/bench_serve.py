"""How many participants one study server holds: N simulated participants join a served study
(`touch4d study serve`, a process of its own) by their links and run it as the WebXR page does: a
frame at 72 Hz each, its touch computed by the page itself (here touch4d's CPU model of the same
eq. 1-7 on the hand's path through the hypercube, looked up per frame; the server's work does not
depend on what they played), played only while the frame's gate allows it, the frames sent in a
"batch" every 0.25 s, each break ended and each trial answered 3 s after its onset. Measured over
a steady stretch once every page has joined:

    server CPU      the server process's CPU time over the stretch / its length (cores), and per
                    participant (ms of CPU per second);
    memory          the server's resident memory after the joins minus before them, per participant;
    nothing lost    after the stop: rows in every trials.csv against the answers sent in a trial's
                    stimulus, poses and touches in every MCAP log against those sent;
    frames          the frames each page got per second (the server's heartbeat: 4 per second).

The server runs at normal priority. The simulated pages run in this process (one asyncio loop, at
the same priority: on two cores the server has one, the pages the other): their CPU is printed beside the server's, being load that a study's headsets
would not put on its server. Baseline, in the same run: the smallest N's CPU per participant (the
ratio says whether a participant costs more as more join).

`--browser`: the page side, Chromium with a Quest 3 emulated by iwer (SwiftShader, not a headset's
GPU), joined through a relay that holds every chunk 0, 50 and 150 ms each way: the time from the pose
a pulse was computed from to the pulse, per delay (its ratio to no delay: the network is not in it).

    .venv/bin/python bench/bench_serve.py [--participants 16 64 256 512] [--seconds 20] [--browser]
                                          [--figure PNG] [--json FILE]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import aiohttp
import numpy as np

from touch4d.geometry.scene import load_scene
from touch4d.log.reader import LogReader
from touch4d.tactile import load_glove
from touch4d.tactile.stimulus import compute_stimulus
from touch4d.web.invites import Invites
from touch4d.web.protocol import frame_header, is_kind

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"
GLOVE = "config/gloves/quest-controller.yaml"
RATE_HZ = 72.0
BATCH_S = 0.25            # the served page's (touch4d.web.served.ServedOptions.batch_s)
ANSWER_AFTER_S = 3.0      # a trial answered this long after its onset (the paper's answers took seconds)
PATH_FRAMES = 72          # the hand's path: a circle through the screen, once a second
TICKS = os.sysconf("SC_CLK_TCK")


def touch_table() -> tuple[np.ndarray, np.ndarray]:
    """The hand's path (screen units) and what the model gives along it in the hypercube: V per frame."""
    glove = load_glove(GLOVE)
    caster = load_scene("config/scenes/hypercube.yaml").ray_caster()
    angles = np.linspace(0, 2 * np.pi, PATH_FRAMES, endpoint=False)
    path = np.stack([0.5 * np.cos(angles), 0.5 * np.sin(angles), np.full(PATH_FRAMES, 0.1)], axis=1)
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    table = np.array([compute_stimulus(glove, caster, p, identity).V for p in path])
    return path, table


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def rss_mb(pid: int) -> float:
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmRSS:\s+(\d+)", text).group(1)) / 1024


class Page:
    """One simulated participant's page."""

    def __init__(self, pid: str, link: str, phase: int):
        self.id, self.link, self.phase = pid, link, phase
        self.study = None           # the latest frame's study fields
        self.touch_on = False
        self.frames = 0
        self.poses = self.touches = self.answers = self.trial_answers = 0
        self.batch = None
        self.answered: set = set()
        self.onset_seen: dict = {}
        self.ws = None
        self.reader = None

    def new_batch(self):
        self.batch = {"type": "batch", "poses": {"time": [], "valid": [], "hand": []},
                      "touches": {"time": [], "intensity": []}}


async def join(session: aiohttp.ClientSession, base: str, page: Page) -> None:
    async with session.get(page.link) as r:
        assert r.status == 200, (page.id, r.status)
    async with session.post(f"{base}/join", allow_redirects=False) as r:
        assert r.status in (303, 302), (page.id, r.status, await r.text())
    page.ws = await session.ws_connect(f"{base}/ws", origin=base, max_msg_size=1 << 22)
    page.new_batch()
    page.reader = asyncio.ensure_future(read(page))   # at once: it answers the server's pings, as a browser does


async def read(page: Page) -> None:
    async for msg in page.ws:
        if msg.type != aiohttp.WSMsgType.BINARY:
            continue
        data = msg.data
        if is_kind(data, "frame"):
            page.frames += 1
            header = frame_header(data)
            page.study = header.get("study")
            page.touch_on = bool(header.get("touch_on"))


async def run_pages(pages: list[Page], path: np.ndarray, table: np.ndarray, stop: asyncio.Event) -> None:
    """Every page's frames at 72 Hz from one ticker (phases of their own), batches every 0.1 s, answers."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    frame = 0
    period = 1.0 / RATE_HZ
    per_batch = round(BATCH_S * RATE_HZ)
    while not stop.is_set():
        frame += 1
        await asyncio.sleep(max(0.0, start + frame * period - loop.time()))
        now_ms = time.time() * 1000.0
        for page in pages:
            k = (page.phase + frame) % PATH_FRAMES
            batch = page.batch
            batch["poses"]["time"].append(now_ms)
            batch["poses"]["valid"].append(True)
            batch["poses"]["hand"].extend((*path[k].tolist(), 0.0, 0.0, 0.0, 1.0))
            batch["touches"]["time"].append(now_ms)
            batch["touches"]["intensity"].extend(table[k].tolist() if page.touch_on else [0.0] * table.shape[1])
            if (frame + page.phase) % per_batch == 0:
                page.poses += len(batch["poses"]["time"])
                page.touches += len(batch["touches"]["time"])
                message, _ = json.dumps(batch), page.new_batch()
                await page.ws.send_str(message)
                await answer(page, now_ms)


async def answer(page: Page, now_ms: float) -> None:
    study = page.study
    if not study or study["index"] < 0:
        return
    key = (study["phase"], study["index"])
    if study["phase"] == "break" and key not in page.answered:
        page.answered.add(key)
        await page.ws.send_str(json.dumps({"type": "response", "index": study["index"], "option": "",
                                           "time": now_ms}))
    elif study["phase"] == "stimulus" and key not in page.answered:
        seen = page.onset_seen.setdefault(key, now_ms)
        if now_ms - seen >= 1000 * ANSWER_AFTER_S:
            page.answered.add(key)
            page.trial_answers += 1
            await page.ws.send_str(json.dumps({"type": "response", "index": study["index"],
                                               "option": study["options"][0], "time": now_ms}))


def start_server(out: Path, n: int) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "study", "serve", STUDY, "--out", str(out),
                             "--port", "0", "--quick", "--max-participants", str(n), "--leave-after", "120",
                             "--iti", "0.3"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    for line in proc.stdout:
        found = re.search(r"serving (http://\S+)/ for", line)
        if found:
            return proc, found.group(1)
    raise RuntimeError(f"the server did not start (exit {proc.wait()})")


def wait_check_done(pid: int, timeout: float = 120.0) -> None:
    """The server's glove check (a process of its own at the lowest priority) finished: it would
    take the pages' core meanwhile."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        kids = "".join(Path(t, "children").read_text() for t in Path(f"/proc/{pid}/task").iterdir())
        if not kids.split():
            return
        time.sleep(0.5)


def count(out: Path) -> dict:
    rows = poses = touches = 0
    for folder in out.iterdir():
        if not folder.is_dir():
            continue
        trials = folder / "trials.csv"
        if trials.exists():
            rows += max(0, len(trials.read_text().splitlines()) - 1)
        for log in folder.glob("*.mcap"):
            reader = LogReader(log)
            poses += sum(len(m.decode()["stamps"]) for m in reader.messages({"hand/poses"}))
            touches += sum(len(m.decode()["source_stamps"]) for m in reader.messages({"tactile/played"}))
    return {"rows": rows, "poses": poses, "touches": touches}


async def round_of(n: int, seconds: float, path, table) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        out = Path(tmp) / "out"
        out.mkdir(mode=0o700)
        invites = Invites(out)
        links = {f"P{k:03d}": invites.issue(f"P{k:03d}") for k in range(1, n + 1)}
        proc, base = start_server(out, n)
        said: list[str] = []
        asyncio.get_running_loop().run_in_executor(None, lambda: [said.append(line) for line in proc.stdout])
        try:
            await asyncio.get_running_loop().run_in_executor(None, wait_check_done, proc.pid)
            rss0 = rss_mb(proc.pid)
            pages = [Page(pid, f"{base}/?participant={pid}&token={token}", k * 7 % PATH_FRAMES)
                     for k, (pid, token) in enumerate(links.items())]
            sessions = [aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) for _ in pages]
            t_join = time.perf_counter()
            for k in range(0, n, 32):   # 32 joins at a time, as a recruitment wave
                await asyncio.gather(*(join(s, base, p) for s, p in zip(sessions[k:k + 32], pages[k:k + 32])))
            join_s = time.perf_counter() - t_join
            readers = [p.reader for p in pages]
            stop = asyncio.Event()
            ticker = asyncio.ensure_future(run_pages(pages, path, table, stop))
            await asyncio.sleep(2.0)                      # settle
            c0, w0, f0, me0 = cpu_s(proc.pid), time.monotonic(), sum(p.frames for p in pages), time.process_time()
            await asyncio.sleep(seconds)
            c1, w1, f1, me1 = cpu_s(proc.pid), time.monotonic(), sum(p.frames for p in pages), time.process_time()
            rss1 = rss_mb(proc.pid)
            token = re.search(r"experimenter\?token=(\S+)", "".join(said)).group(1)
            async with sessions[0].get(f"{base}/experimenter?format=json&token={token}") as r:
                status = await r.json()
            stop.set()
            await ticker
            await asyncio.sleep(1.0)                      # the last batches and answers arrive
            for p in pages:
                await p.ws.close()
            for r in readers:
                r.cancel()
            for s in sessions:
                await s.close()
        except BaseException:
            print("".join(said[-30:]), file=sys.stderr)
            raise
        finally:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(120)
            Path(tempfile.gettempdir(), f"bench-serve-{n}.log").write_text("".join(said))
        got = count(out)
    wall = w1 - w0
    sent = {"poses": sum(p.poses for p in pages), "touches": sum(p.touches for p in pages),
            "answers": sum(p.trial_answers for p in pages)}
    return {"n": n, "cores": (c1 - c0) / wall, "cpu_ms_per_s_each": 1000 * (c1 - c0) / wall / n,
            "mb_each": (rss1 - rss0) / n, "rss_mb": rss1, "join_s": join_s,
            "frames_per_s_each": (f1 - f0) / wall / n, "pages_cores": (me1 - me0) / wall,
            "sent": sent, "written": got,
            "server_frames_each": sum(p["counts"]["frames"] for p in status["participants"] if p["counts"]) / n,
            "server_batches_each": sum(p["counts"]["batches"] for p in status["participants"] if p["counts"]) / n,
            "lost": {"rows": sent["answers"] - got["rows"], "poses": sent["poses"] - got["poses"],
                     "touches": sent["touches"] - got["touches"]}}


def browser_rounds(delays_ms: list[float]) -> list[dict]:
    """Pose -> pulse on the page, through a relay adding each delay each way."""
    sys.path.insert(0, str(REPO / "tests"))
    from test_study_serve_relay_browser import RECORD_PULSES_AND_POSES
    from touch4d.web.testing import DelayRelay, chromium, enter_vr, headset_page, wait_connected

    rows = []
    with chromium() as browser:
        for delay in delays_ms:
            with tempfile.TemporaryDirectory(prefix="bench-serve-page-") as tmp:
                out = Path(tmp) / "out"
                out.mkdir(mode=0o700)
                token = Invites(out).issue("P03")     # P03's first trial touches
                proc, base = start_server(out, 4)
                port = int(base.rsplit(":", 1)[1])
                try:
                    with DelayRelay(port, delay / 1000.0) as relay:
                        page = headset_page(browser, f"http://127.0.0.1:{relay.port}/?participant=P03&token={token}",
                                            320, 180)
                        with page.expect_navigation(timeout=120000):
                            page.click("#join", no_wait_after=True)
                        wait_connected(page, 90)
                        enter_vr(page)
                        page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")
                        page.evaluate(RECORD_PULSES_AND_POSES)
                        page.wait_for_function("touch4d.study && touch4d.study.phase === 'break'", timeout=60000)
                        page.evaluate("xr.controllers.right.updateButtonValue('a-button', 1)")
                        page.wait_for_function("touch4d.study.phase === 'stimulus'", timeout=60000)
                        page.evaluate("xr.controllers.right.updateButtonValue('a-button', 0)")
                        f0 = page.evaluate("[touch4d.xrFrames, performance.now()]")
                        page.evaluate("xr.controllers.right.position.set(0, 1.2, -0.45)")
                        page.wait_for_function("pulses.filter(([v]) => v > 0.05).length >= 60", timeout=60000)
                        f1 = page.evaluate("[touch4d.xrFrames, performance.now()]")
                        played = page.evaluate("pulses")
                        page.context.close()
                finally:
                    os.killpg(proc.pid, signal.SIGINT)
                    proc.wait(60)
            first = {}
            for value, at, pose in played:
                if value > 0.05 and pose is not None:
                    first.setdefault(pose, at - pose)
            lags = np.array(list(first.values()))
            rows.append({"delay_ms": delay, "p50_ms": float(np.median(lags)), "p90_ms": float(np.percentile(lags, 90)),
                         "frame_ms": (f1[1] - f0[1]) / max(1, f1[0] - f0[0]), "poses": len(lags)})
    return rows


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([r["n"] for r in rows])
    cores = np.array([r["cores"] for r in rows])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    a.plot(n, cores, "o-", label="measured (this machine)")
    slope = np.polyfit(n, cores, 1)
    reach = (1.0 - slope[1]) / slope[0]
    xs = np.linspace(0, max(reach, n.max()) * 1.1, 50)
    a.plot(xs, np.polyval(slope, xs), ":", label=f"fit: one core at N = {reach:.0f}")
    a.axhline(1.0, color="grey", lw=0.8)
    a.set_xlabel("participants at once")
    a.set_ylabel("server CPU (cores)")
    a.legend(fontsize=8)
    a.set_title("one server")
    # several servers, each its own --out, behind one reverse proxy that routes by participant
    servers = np.arange(1, 9)
    b.bar(servers, servers * math.floor(reach), color="#7a9")
    b.set_xlabel("servers behind one reverse proxy (each its own --out)")
    b.set_ylabel("participants at once")
    b.set_title("several servers, analysed together")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--participants", type=int, nargs="+", default=[16, 64, 256, 512])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--browser", action="store_true", help="the page side through a relay (0, 50, 150 ms)")
    parser.add_argument("--delays", type=float, nargs="+", default=[0, 50, 150])
    parser.add_argument("--figure", metavar="PNG")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args()
    path, table = touch_table()
    rows = []
    for n in args.participants:
        row = asyncio.run(round_of(n, args.seconds, path, table))
        rows.append(row)
        base = rows[0]["cpu_ms_per_s_each"]
        print(f"N={n:4d}: server {row['cores']:.3f} cores ({row['cpu_ms_per_s_each']:.2f} ms/s each, x{row['cpu_ms_per_s_each'] / base:.2f} "
              f"of N={rows[0]['n']}), {row['mb_each']:.2f} MB each (RSS {row['rss_mb']:.0f} MB), joins {row['join_s']:.1f} s, "
              f"{row['frames_per_s_each']:.1f} frames/s each (server sent {row['server_frames_each']:.0f} each, took {row['server_batches_each']:.0f} batches); pages {row['pages_cores']:.2f} cores; lost {row['lost']} "
              f"of sent {row['sent']}", flush=True)
    page_rows = browser_rounds(args.delays) if args.browser else []
    for r in page_rows:
        print(f"page, relay {r['delay_ms']:.0f} ms each way: pose -> pulse p50 {r['p50_ms']:.1f} ms, p90 {r['p90_ms']:.1f} ms "
              f"(x{r['p50_ms'] / page_rows[0]['p50_ms']:.2f} of no delay; frame {r['frame_ms']:.1f} ms, {r['poses']} poses)",
              flush=True)
    if args.figure:
        figure(rows, Path(args.figure))
    if args.json:
        Path(args.json).write_text(json.dumps({"rounds": rows, "page": page_rows}, indent=1))


if __name__ == "__main__":
    main()

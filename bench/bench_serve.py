"""How many participants one study server holds: simulated participants play pages over the same
WebSocket protocol as the WebXR page, each at 72 Hz, and the bench measures per participant the
CPU and memory of their stack (per process: the launcher and each node), and pose -> pulse inside
the server (its `--wire-trace`, touch4d.web.wiretrace): from the input message that moves the
controller into (or out of) the object reaching the server to the first frame whose `haptic` (the
controller's intensity) follows it leaving the server; and the same seen by the simulated page.
The figures are the measured stretch's, which begins 2 s after the last page joined; the server's
p99 over every move, those made while others were joining included, is given beside it (a join
holds its container's other participants while its nodes are built).

Each participant: a link (`touch4d study invite`), Join, then its socket; its controller goes in and
out of the hypercube's front cell every 300 ms. Each page's frame clock and its moves start at a
phase of its own (seeded per page), as independent headsets do: pages that got their join's answer
in the same instant would otherwise send and move in lockstep, a few participants of one container
moving at the same moment every 300 ms. The stacks run without their study node
(`study:=none`, the page's gate open): what is measured is the per-frame loop that every participant
costs, not the trials (a trial's cost is a scene load every few seconds). Their recorder runs: it
logs the haptic loop at the page's rate, as in every session. Then the same through a
relay on loopback that delays every byte by 25 ms each way (50 ms round trip; this kernel has no
netem). Baseline, in the same run: one participant. The simulated pages run on this machine too
(at a lower priority): the CPU they took in the measured stretch is printed beside the server's,
being load that a study's headsets would not put on its server.

`--per-process K [K ...]`: each round once per K, the participants' stacks sharing processes K at a
time (containers, touch4d.bus.container; the server's default when not given): `--per-process 1 8`
gives a process per participant, the baseline of the CPU and memory that sharing saves, in the
same run.

`--priority realtime normal`: each round once per choice. launch/study-serve.yaml's haptic loop is
`realtime`: where permitted (root, CAP_SYS_NICE) the server's loop thread and each container's run
SCHED_FIFO, each thread alone; `normal` starts the server without that right (CAP_SYS_NICE dropped
with `setpriv`), as a plain user runs it: the baseline, in the same run. Each round says how many of
its processes' loops ran real-time.

`--trials`: the stacks with their study node (the full session), every participant answering each
trial as soon as its frame shows it: trials per second written to the participants' trials.csv,
and rows against answers sent (none lost).

    .venv/bin/python bench/bench_serve.py [--participants 1 4 8 16] [--seconds 10] [--per-process 1 8]
                                          [--priority realtime normal] [--over 32] [--trials]
                                          [--figure PNG] [--json FILE]

The simulated pages run in this process at a lower priority than the server and its stacks
(`--pages-nice`, 10 by default; where the system lets the server's priority be restored, e.g. as
root): they stand in for headsets on other machines, and must not take the cores from the server.
In a round whose server loops run real-time, the pages and the relay run SCHED_FIFO one step below
them (`pages_priority`), so that they send on time without taking a core from the loops.

Each round also says how quick the machine was as it ran (`machine_speed`: one participant's page
input in a tight loop, CPU microseconds, before and after the round): on a shared virtual machine
the same code's CPU per input has varied 2.4-fold within an hour, and the tail with it; a round's
p99 is read beside that figure. And how often the host held the machine's CPUs during the measured
stretch (`PAUSE_PROBE`: a real-time thread's 2 ms sleeps that woke more than 6 ms late; run as root
for real-time priority, else our own load counts too).

`--over N`: then N pages at once against a server left at its default cap (four per core): how many
it admits and refuses (HTTP 503), and whether the admitted keep their touch within the budget.
"""
from __future__ import annotations

import argparse
import asyncio
import csv
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import aiohttp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cpu import cpu_seconds  # noqa: E402

from touch4d import eventloop  # noqa: E402
from touch4d.bus.realtime import LOOP_PRIORITY, raise_loop_priority, reset_thread_priority  # noqa: E402
from touch4d.web.protocol import frame_header  # noqa: E402
from touch4d.web.wiretrace import Move, pose_to_pulse  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"
RATE_HZ = 72.0
INSIDE = [0.0, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]      # the grip at the screen's centre: in the front cell
OUTSIDE = [0.6, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]     # beside the screen
TOGGLE_S = 0.3
DELAY_S = 0.025                                      # each way: 50 ms round trip
PAGES_PRIORITY = LOOP_PRIORITY - 4   # in a real-time round the pages run SCHED_FIFO below the server's loops
PAGES_NICE = 10        # the simulated pages run this much nicer than the server and its stacks: on a real
                       # deployment the headsets are elsewhere; here they share the cores, and must not
                       # take them from the server they measure (the server's priority is restored in
                       # its process before it starts, where the system allows it; see server_nice)
_BASE_NICE = os.getpriority(os.PRIO_PROCESS, 0)


def _server_priority() -> None:
    """In the server's process, before it runs: the bench's own priority, not the pages' (raising a
    priority back needs the right to, e.g. root; without it the server stays at the pages' level)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, _BASE_NICE)
    except OSError:
        pass


# The server and its containers without the right to real-time scheduling: their loops' `realtime`
# (launch/study-serve.yaml) is then refused and they run at normal priority, as for a plain user.
NO_REALTIME = ["setpriv", "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice"]


def server_nice() -> int:
    """The niceness a server started now runs at."""
    out = subprocess.run([sys.executable, "-c", "import os; print(os.nice(0))"], capture_output=True, text=True,
                         preexec_fn=_server_priority, check=True)
    return int(out.stdout)


# ---- the server and its processes -----------------------------------------------------------------------


def start_server(out: Path, participants: int | None, study: bool = False, trace: Path | None = None,
                 per_process: int | None = None, realtime: bool = True):
    """The server; `per_process`: participants' stacks per process (None: the server's default);
    `participants` None: the server's own default cap (four per core); `realtime` False: without the
    right to real-time scheduling (CAP_SYS_NICE dropped), as a server run by a plain user."""
    stack = ["study.iti_s:=0.05"] if study else ["study:=none", "tracker.study_gate:=open"]
    launch = [] if per_process is None else ["--per-process", str(per_process)]
    plain = [] if realtime else NO_REALTIME
    proc = subprocess.Popen([*plain, sys.executable, "-u", "-m", "touch4d.cli", "study", "serve", STUDY, "--out", str(out),
                             *launch, *(["--wire-trace", str(trace)] if trace else []),
                             "--port", "0", *([] if study else ["--quick"]),
                             *([] if participants is None else ["--max-participants", str(participants)]),
                             "--leave-after", "60", *stack],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, preexec_fn=_server_priority)
    for line in proc.stdout:
        match = re.search(r"serving (http://\S+)/ for", line)
        if match:
            return proc, match.group(1)
    raise RuntimeError("the study server did not start")


def stop_server(proc) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(30)
    except (ProcessLookupError, subprocess.TimeoutExpired):
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def invite(out: Path, participant: str) -> str:
    text = subprocess.run([sys.executable, "-m", "touch4d.cli", "study", "invite", str(out), participant, "--no-qr"],
                          cwd=REPO, capture_output=True, text=True, check=True).stdout
    return text.strip().splitlines()[-1]


def children() -> dict[int, list[int]]:
    tree: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            tree.setdefault(ppid, []).append(int(entry.name))
    return tree


def descendants(pid: int) -> list[int]:
    tree, out, todo = children(), [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(tree.get(p, []))
    return out


def pss_mb(pid: int) -> float:
    """A process's proportional set size (shared pages split among their users), MB."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def role(pid: int) -> str:
    """What a process of the server's tree is: a container (participants' stacks), a node's role
    (its --name), a group's name (its --group), a launcher, or the server."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return "?"
    argv = [a.decode(errors="replace") for a in argv]
    if "--container" in argv:
        return "container"
    if "--group" in argv:
        return argv[argv.index("--group") + 1]
    if "--name" in argv:
        return argv[argv.index("--name") + 1]
    return "launcher" if "launch" in argv else "server"


def realtime_loop(pid: int) -> bool:
    """Whether the process's main thread (its loop) runs SCHED_FIFO."""
    try:
        return os.sched_getscheduler(pid) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
    except OSError:
        return False


def cpu(pids) -> float:
    total = 0.0
    for pid in pids:
        try:
            total += cpu_seconds(pid)
        except OSError:
            pass
    return total


def inputs_between(trace: Path, t0: float, t1: float) -> int:
    """Page inputs that reached the server between monotonic t0 and t1 (s): the wire trace's `in`
    rows (its clock is this machine's monotonic clock, as time.monotonic)."""
    lo, hi = int(t0 * 1e9), int(t1 * 1e9)
    with open(trace, newline="") as f:
        return sum(1 for row in csv.reader(f) if row[1] == "in" and lo <= int(row[3]) <= hi)


def count_rows(out: Path) -> int:
    """Rows in every participant's trials.csv."""
    return sum(max(0, len(f.read_text().splitlines()) - 1) for f in out.glob("S*/trials.csv"))


# ---- the delaying relay ---------------------------------------------------------------------------------


async def relay(listen_port_box: list, target_port: int, delay: float) -> asyncio.AbstractServer:
    """A TCP relay on loopback that holds every chunk `delay` seconds in each direction, in order."""
    async def pump(reader, writer):
        queue: asyncio.Queue = asyncio.Queue()

        async def send():
            try:
                while True:
                    due, data = await queue.get()
                    if data is None:
                        break
                    await asyncio.sleep(max(0.0, due - time.monotonic()))
                    writer.write(data)
                    await writer.drain()
            except ConnectionError:
                pass   # the other end went (a round's end): nothing more to pass on
            writer.close()
        sender = asyncio.ensure_future(send())
        try:
            while data := await reader.read(65536):
                queue.put_nowait((time.monotonic() + delay, data))
        except (ConnectionError, asyncio.CancelledError):
            sender.cancel()
            return
        queue.put_nowait((0.0, None))
        await sender

    async def handle(reader, writer):
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", target_port)
            await asyncio.gather(pump(reader, up_writer), pump(up_reader, writer), return_exceptions=True)
        except (ConnectionError, asyncio.CancelledError):
            writer.close()   # the round is over: its connections go

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    listen_port_box.append(server.sockets[0].getsockname()[1])
    return server


# ---- a simulated participant ----------------------------------------------------------------------------


async def participant(base: str, link: str, stop: asyncio.Event, joined: list, latencies: list, lost: list,
                      answered: list, moves: list, pid: str, dropped: list | None = None,
                      refused: list | None = None, phase: tuple[float, float] = (0.0, 0.0)) -> None:
    """Join by `link` (through `base`), then play a page until `stop`: inputs at 72 Hz, the controller
    in and out. A connection the server closes (its heartbeat unanswered on a saturated machine)
    ends the page: its id goes into `dropped`; a join the server refuses as full (503), into `refused`.
    `phase`: where in a frame period and in a move's period (fractions) this page's clock starts."""
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(cookie_jar=jar) as http:
        link = re.sub(r"^http://[^/]+", base, link)
        async with http.get(link) as r:
            await r.read()
        async with http.post(f"{base}/join", timeout=aiohttp.ClientTimeout(total=300)) as r:
            await r.read()
            if r.status == 503 and refused is not None:
                refused.append(pid)
                return
            if r.status != 200:
                raise RuntimeError(f"join: HTTP {r.status}")
        ws_url = base.replace("http://", "ws://") + "/ws"
        async with http.ws_connect(ws_url, origin=base, max_msg_size=0) as ws:
            state = {"want": None, "since": None, "haptic": 0.0, "answered": set()}

            async def read():
                async for msg in ws:
                    if msg.type != aiohttp.WSMsgType.BINARY:
                        continue
                    header = frame_header(msg.data)    # what the page reads; its arrays are not needed
                    if header.get("kind") != "frame":
                        continue
                    trial = header.get("study")
                    key = trial and (trial["phase"], trial["index"], trial.get("message"))
                    if trial and trial["phase"] in ("break", "stimulus") and key not in state["answered"]:
                        # answer at once (a break: go on); the study node takes the first answer per trial
                        state["answered"].add(key)
                        if trial["phase"] == "stimulus":
                            answered.append(trial["index"])
                        option = trial["options"][0] if trial["phase"] == "stimulus" else ""
                        await ws.send_str(json.dumps({"type": "response", "index": trial["index"], "option": option,
                                                      "time": time.time() * 1000.0}))
                    haptic = header.get("haptic", 0.0)
                    want, since = state["want"], state["since"]
                    if since is not None and ((want and haptic > 0.05) or (not want and haptic == 0.0)):
                        latencies.append((since, time.monotonic() - since))
                        state["since"] = None
            reader = asyncio.ensure_future(read())
            joined.append(pid)
            t0 = time.monotonic() + phase[0] / RATE_HZ
            inside, next_toggle, k = False, t0 + 2.0 + phase[1] * TOGGLE_S, 0     # 2 s to settle before the first move
            while not stop.is_set():
                now = time.monotonic()
                if now >= next_toggle:
                    if state["since"] is not None:
                        lost.append(state["since"])          # no frame followed the last move in 300 ms
                    inside = not inside
                    state["want"], state["since"] = inside, now
                    next_toggle = now + TOGGLE_S
                grip = INSIDE if inside else OUTSIDE
                stamp = time.time() * 1000.0     # names the input in the server's wire trace
                if state["since"] == now:
                    moves.append(Move(pid, stamp, inside))
                try:
                    await ws.send_str(json.dumps({"type": "input", "time": stamp, "tracking": True,
                                                  "head": [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0],
                                                  "sources": [{"handedness": "right", "grip": grip, "trigger": 0.0,
                                                               "buttons": [], "joints": None}]}))
                except ConnectionError:
                    if dropped is not None:
                        dropped.append(pid)
                    break
                k += 1
                await asyncio.sleep(max(0.0, t0 + k / RATE_HZ - time.monotonic()))
            reader.cancel()


@contextmanager
def pages_priority(realtime: bool):
    """In a round whose server runs its loops real-time: the simulated pages and the relay (this
    thread) run SCHED_FIFO below those loops, where permitted. They stand in for headsets and a
    network elsewhere, so they must neither take a core from the loops nor wait behind the server's
    background threads (the recorders' writers) to send on time: starved, they sent in bursts, and a
    burst of sixteen inputs queued in the containers. Otherwise they stay as they are (nice 10)."""
    raised = realtime and raise_loop_priority(PAGES_PRIORITY)
    try:
        yield raised
    finally:
        if raised:
            reset_thread_priority()


async def run_round(n: int, seconds: float, delay: float, study: bool = False, per_process: int | None = None,
                    capped: bool = False, realtime: bool = True) -> dict:
    """`capped`: N pages try to join a server with its default cap; the figures are the admitted's."""
    with pages_priority(realtime) as pages_realtime, tempfile.TemporaryDirectory(prefix="bench-serve-") as tmp:
        out = Path(tmp) / "out"
        trace = Path(tmp) / "wire.csv"
        proc, base = start_server(out, None if capped else n, study, trace, per_process, realtime)
        relay_server = None
        try:
            links = [invite(out, f"S{k:02d}") for k in range(n)]
            target = base
            if delay > 0:
                box: list = []
                relay_server = await relay(box, int(base.rsplit(":", 1)[1]), delay)
                target = f"http://127.0.0.1:{box[0]}"
            latencies, lost, answered, moves, joined, dropped, refused = [], [], [], [], [], [], []
            stop = asyncio.Event()
            t_start = time.monotonic()
            tasks = [asyncio.ensure_future(participant(target, link, stop, joined, latencies, lost, answered, moves,
                                                       f"S{k:02d}", dropped, refused,
                                                       tuple(np.random.default_rng(k).random(2))))
                     for k, link in enumerate(links)]
            # CPU and memory over the measured stretch, once every participant plays: every process of
            # the server's tree (the stacks included)
            while len(joined) + len(refused) < n:
                failed = [t for t in tasks if t.done() and t.exception() is not None]
                if failed:                                # a join failed: why, from its stack's log
                    for log in sorted(out.glob("*/serve.log")):
                        said = [line for line in log.read_text(errors="replace").splitlines()
                                if "ERROR" in line or "failed" in line or "Traceback" in line]
                        if said:
                            print(f"{log.parent.name}'s serve.log:", *said[-8:], sep="\n  ", file=sys.stderr)
                    await failed[0]
                await asyncio.sleep(0.2)
            offered, n = n, len(joined)                   # the figures below: the admitted's
            await asyncio.sleep(2.0)
            pids = descendants(proc.pid)
            stacks = [p for p in pids if p != proc.pid]          # the participants' launches and nodes
            roles = {p: role(p) for p in stacks}
            fifo = [p for p in pids if realtime_loop(p)]        # whose loop thread runs SCHED_FIFO
            by_role0 = {r: cpu([p for p in stacks if roles[p] == r]) for r in set(roles.values())}
            probe = start_pause_probe(Path(tmp) / "pauses.txt")
            c0, w0, s0, wall0 = cpu(pids), time.monotonic(), cpu([proc.pid]), time.time()
            pages0 = time.process_time()
            rows0 = count_rows(out)
            await asyncio.sleep(seconds)
            c1, w1, s1, wall1 = cpu(pids), time.monotonic(), cpu([proc.pid]), time.time()
            pages_cpu = (time.process_time() - pages0) / (w1 - w0)   # this process: the simulated pages
            pauses = host_pauses(probe, Path(tmp) / "pauses.txt")
            by_role1 = {r: cpu([p for p in stacks if roles[p] == r]) for r in by_role0}
            rows1 = count_rows(out)
            pss = {p: pss_mb(p) for p in stacks}
            memory = sum(pss.values())
            server_mb = pss_mb(proc.pid)
            stop.set()
            await asyncio.gather(*tasks)
            by_role = {r: ((by_role1[r] - by_role0[r]) / (w1 - w0) / n,
                           sum(pss[p] for p in stacks if roles[p] == r) / n,
                           sum(1 for p in stacks if roles[p] == r) / n) for r in by_role0}
            await asyncio.sleep(1.0)                                 # the last answers' rows
            rows = count_rows(out)
            # the latencies of the measured stretch (every page playing, none joining): a join stalls the
            # pages already playing in its container while it loads, counted apart (`server_p99_joins`)
            lat = np.array([d for since, d in latencies if w0 <= since < w1]) * 1000
            stop_server(proc)                                         # the trace complete
            steady = [m for m in moves if 1000 * wall0 <= m.time_ms < 1000 * wall1]
            inside, missed = pose_to_pulse(trace, steady)
            with_joins, _ = pose_to_pulse(trace, moves)
            # CPU per page input, the load-independent figure: a saturated machine runs fewer inputs
            # per second, not cheaper ones (x 72 Hz: what a participant costs at full rate)
            inputs = inputs_between(trace, w0, w1)
            srv = np.array(inside) * 1000
            pct = lambda a, q: float(np.percentile(a, q)) if len(a) else None  # noqa: E731
            return {"n": n, "offered": offered, "refused": len(refused), "delay_ms": 2000 * delay, "label": ", ".join([*([f"{per_process} per process"] if per_process else []),
                                                                                            *([] if realtime else ["normal priority"])]),
                    "cpu_per_participant": (c1 - c0) / (w1 - w0) / n, "pages_cpu": pages_cpu,
                    "server_p50": pct(srv, 50), "server_p99": pct(srv, 99), "server_moves": len(srv),
                    "server_missed": missed, "by_role": by_role,
                    "realtime_loops": len(fifo), "processes": len(pids), "pages_realtime": pages_realtime,
                    "server_p99_joins": pct(np.array(with_joins) * 1000, 99), "moves_joins": len(with_joins),
                    "server_cpu": (s1 - s0) / (w1 - w0), "server_mb": server_mb,
                    "inputs_per_s": inputs / (w1 - w0) / n,
                    "cpu_ms_per_input": 1000 * (c1 - c0) / max(inputs, 1),
                    "cpu_at_rate": (c1 - c0) / max(inputs, 1) * RATE_HZ,
                    "mb_per_participant": memory / n, "p50": float(np.percentile(lat, 50)) if len(lat) else None,
                    "p99": float(np.percentile(lat, 99)) if len(lat) else None, "moves": len(lat),
                    "lost": sum(1 for since in lost if w0 <= since < w1), "pauses": pauses, "dropped": len(dropped), "wall": time.monotonic() - t_start, "answered": len(set(answered)),
                    "answers": len(answered), "rows": rows, "trials_per_s": (rows1 - rows0) / (w1 - w0)}
        finally:
            if relay_server is not None:
                relay_server.close()
            stop_server(proc)


# A real-time thread that sleeps 2 ms at a time: a wake-up more than 6 ms late means no CPU of this
# machine ran it (at real-time priority nothing of ours comes first): the host held them. Its lines:
# "ms late" per overrun; where real-time priority is refused, "normal" first (then our load counts too).
PAUSE_PROBE = """
import os, sys, time
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
except (OSError, AttributeError):
    print("normal", flush=True)
prev = time.monotonic()
while True:
    time.sleep(0.002)
    now = time.monotonic()
    if now - prev > 0.006:
        print(f"{1000 * (now - prev - 0.002):.1f}", flush=True)
    prev = now
"""


def start_pause_probe(path: Path) -> subprocess.Popen:
    """PAUSE_PROBE in a process of its own, writing to `path` until terminated."""
    return subprocess.Popen([sys.executable, "-c", PAUSE_PROBE], stdout=open(path, "w"), stderr=subprocess.DEVNULL)


def host_pauses(probe: subprocess.Popen, path: Path) -> dict:
    """The probe's overruns: how many, their sum and the longest (ms), and whether it ran real-time."""
    probe.terminate()
    probe.wait()
    lines = path.read_text().split()
    late = [float(x) for x in lines if x != "normal"]
    return {"count": len(late), "ms": sum(late), "longest": max(late, default=0.0), "realtime": "normal" not in lines}


def machine_speed(inputs: int = 600) -> float:
    """CPU microseconds of one participant's page input in a tight loop (bench_participant.py's whole
    path, no sockets): how quick this machine is now, whatever else its host runs."""
    from bench_participant import Participant, events

    Participant().run(events(100))   # warm (first frames, caches)
    seconds, n = Participant().run(events(inputs))
    return seconds / n * 1e6


def figure(rows: list[dict], path: Path) -> None:
    """CPU of the machine's cores, memory and server-side p99 against N: where one server ends."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), constrained_layout=True)
    first: dict = {}
    for r in rows:   # one point per layout, delay and N: the first file given wins (--plot of several runs)
        first.setdefault((r.get("label", ""), r["delay_ms"], r["n"]), r)
    rows = list(first.values())
    groups = sorted({(r.get("label", ""), r["delay_ms"]) for r in rows})
    for k, (name, delay) in enumerate(groups):
        rs = sorted((r for r in rows if (r.get("label", ""), r["delay_ms"]) == (name, delay)), key=lambda r: r["n"])
        n = [r["n"] for r in rs]
        style = ("o-", "s--", "^:", "v-.")[k % 4]
        if not name and any(r.get("realtime_loops") for r in rs):
            name = "real-time loops"
        label = (f"+{delay:.0f} ms round trip" if delay else "loopback") + (f", {name}" if name else "")
        # the server and every stack, per page input, times 72 Hz: what N participants need at full rate
        # (not drawn where fewer than 90 % of the inputs arrived: the bench's pages were starved too)
        axes[0].plot(n, [r["n"] * r.get("cpu_at_rate", r["cpu_per_participant"])
                         if r.get("inputs_per_s", RATE_HZ) >= 0.9 * RATE_HZ else np.nan for r in rs], style, label=label)
        axes[1].plot(n, [r["mb_per_participant"] for r in rs], style, label=label)
        axes[2].plot(n, [r["server_p99"] or np.nan for r in rs], style, label=label)
    cores = os.cpu_count()
    axes[0].axhline(cores, color="k", lw=0.8)
    axes[0].text(1, cores * 0.93, f"{cores} cores: one server ends (less: what others use)", fontsize=8)
    axes[0].set(title=f"CPU at {RATE_HZ:.0f} Hz, all participants (cores)", xlabel="participants on one server")
    axes[1].axhline(150, color="k", lw=0.8)
    axes[1].text(1, 153, "target 150 MB", fontsize=8)
    axes[1].set(title="memory per participant (MB PSS)", xlabel="participants on one server",
                ylim=(0, 1.2 * max([150] + [r["mb_per_participant"] for r in rows])))
    axes[2].axhline(15, color="k", lw=0.8)
    axes[2].text(1, 16, "target 15 ms", fontsize=8)
    axes[2].set(title="pose -> pulse p99 in the server (ms)", xlabel="participants on one server", yscale="log",
                ylim=(1, 3 * max([15] + [r["server_p99"] or 0 for r in rows])))
    for ax in axes:
        ax.set_xscale("log", base=2)
        ax.set_xticks(sorted({r["n"] for r in rows}), [str(v) for v in sorted({r["n"] for r in rows})])
        ax.legend(fontsize=7)
    fig.suptitle(f"bench_serve on a shared {cores}-core machine; more participants: "
                 "more servers, each its own --out, links split among them", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--participants", type=int, nargs="+", default=[1, 4, 8, 16])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--no-delay-round", action="store_true", help="skip the rounds through the 50 ms relay")
    parser.add_argument("--delay-round-only", action="store_true", help="only the rounds through the 50 ms relay")
    parser.add_argument("--figure", metavar="PNG", help="plot the rounds: CPU, memory and p99 against N")
    parser.add_argument("--json", metavar="FILE", help="write the rounds' figures there")
    parser.add_argument("--plot", metavar="JSON", nargs="+", help="no rounds: plot --figure from these --json files")
    parser.add_argument("--per-process", type=int, nargs="+", metavar="K",
                        help="each round once per K: participants' stacks per process (1: a process each, the baseline)")
    parser.add_argument("--over", type=int, metavar="N",
                        help="then N pages against the server's default cap (four per core): admitted and refused")
    parser.add_argument("--pages-nice", type=int, default=PAGES_NICE, metavar="N",
                        help=f"the simulated pages' niceness above the server's (default {PAGES_NICE}; 0: equal)")
    parser.add_argument("--priority", nargs="+", choices=["realtime", "normal"], default=["realtime"],
                        help="each round once per choice: the server as it runs (its loops real-time where "
                             "permitted: root) and/or without the right to (CAP_SYS_NICE dropped: normal priority)")
    parser.add_argument("--trials", action="store_true",
                        help="instead: with the study node, every participant answering at once: trials per second")
    args = parser.parse_args()
    if args.plot:
        figure([r for f in args.plot for r in json.loads(Path(f).read_text())], Path(args.figure))
        return
    os.nice(args.pages_nice)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}; the simulated pages at nice {os.nice(0)}, the server at {server_nice()}; "
          f"its loops {eventloop.kind()}")
    if args.trials:
        for n in sorted(set([1, *args.participants])):
            r = asyncio.run(run_round(n, args.seconds, 0.0, study=True))
            print(f"N={n:>2} with the study node: {r['rows']} trials written, "
                  f"{r['trials_per_s']:.2f} trials/s ({r['trials_per_s'] / n:.2f} per participant); "
                  f"{r['answers']} answers sent, {r['rows']} rows (none lost: rows >= answers - {n}, the last "
                  f"answer of each may still be in flight)", flush=True)
        return
    rows = []
    layouts = [(k, priority == "realtime") for k in args.per_process or [None] for priority in args.priority]
    for delay in ([0.0] if args.no_delay_round else [DELAY_S] if args.delay_round_only else [0.0, DELAY_S]):
        for n, (per_process, realtime) in ((n, k) for n in sorted(set([1, *args.participants])) for k in layouts):
            before = machine_speed()
            r = asyncio.run(run_round(n, args.seconds, delay, per_process=per_process, realtime=realtime))
            r["machine_us"] = (before, machine_speed())
            rows.append(r)
            base = next(x for x in rows if x["n"] == 1 and x["delay_ms"] == r["delay_ms"] and x["label"] == r["label"])
            fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
            if len(layouts) > 1:
                first = next(x for x in rows if x["n"] == n and x["delay_ms"] == r["delay_ms"])
                print(f"{r['label'] or 'as served'}:", flush=True)
                if first is not r:
                    print(f"      against {first['label'] or 'as served'}: memory x{r['mb_per_participant'] / first['mb_per_participant']:.2f}, "
                          f"CPU per input x{r['cpu_ms_per_input'] / max(first['cpu_ms_per_input'], 1e-9):.2f}, "
                          f"p99 in the server x{(r['server_p99'] or 0) / max(first['server_p99'] or 1e-9, 1e-9):.2f}", flush=True)
            print(f"N={n:>2} rtt+{r['delay_ms']:.0f} ms: CPU {100 * r['cpu_per_participant']:.0f}% of a core (the server's "
                  f"share included) and "
                  f"{r['mb_per_participant']:.0f} MB (PSS) per participant (the server itself "
                  f"{100 * r['server_cpu']:.0f}%, {r['server_mb']:.0f} MB); pose->pulse in the server p50 "
                  f"{fmt(r['server_p50'])} ms, p99 {fmt(r['server_p99'])} ms ({r['server_moves']} moves, "
                  f"{r['server_missed']} without a following frame; p99 x{(r['server_p99'] or 0) / max(base['server_p99'] or 1e-9, 1e-9):.2f} "
                  f"of N=1; with the joins {fmt(r['server_p99_joins'])} ms over {r['moves_joins']}); at the client p50 {fmt(r['p50'])} ms, p99 {fmt(r['p99'])} ms ({r['lost']} of "
                  f"{r['moves'] + r['lost']} without a frame in 300 ms; {r['dropped']} pages dropped by the server); load {os.getloadavg()[0]:.1f}", flush=True)
            print(f"      CPU per page input {r['cpu_ms_per_input']:.2f} ms (server and stack; "
                  f"{r['inputs_per_s']:.0f} of {RATE_HZ:.0f} inputs/s per participant arrived): "
                  f"{100 * r['cpu_at_rate']:.0f}% of a core per participant at {RATE_HZ:.0f} Hz, "
                  f"{n * r['cpu_at_rate']:.1f} cores for N={n}; the simulated pages took {100 * r['pages_cpu']:.0f}% of a "
                  "core of this machine beside it", flush=True)
            print(f"      real-time loops (SCHED_FIFO): {r['realtime_loops']} of {r['processes']} processes (the server and its containers); "
                  f"the simulated pages {f'SCHED_FIFO {PAGES_PRIORITY}, below them' if r['pages_realtime'] else f'at nice {os.nice(0)}'}",
                  flush=True)
            print("      per participant: " + ", ".join(
                f"{name} {count:.0f}x {100 * c:.0f}% {mb:.0f} MB" for name, (c, mb, count) in sorted(r["by_role"].items())),
                flush=True)
            pz = r["pauses"]
            print(f"      the machine's speed: a page input in a tight loop {r['machine_us'][0]:.0f} us before the round, "
                  f"{r['machine_us'][1]:.0f} us after (bench_participant.py); the host held its CPUs {pz['count']} "
                  f"times in the measured stretch, {pz['ms']:.0f} ms in all, the longest {pz['longest']:.0f} ms"
                  f"{'' if pz['realtime'] else ' (no real-time priority here: our own load counted too)'}", flush=True)
    if args.over:
        r = asyncio.run(run_round(args.over, args.seconds, 0.0, capped=True))
        r["label"] = "default cap"
        rows.append(r)
        fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        print(f"N={r['offered']} offered to a server with its default cap: {r['n']} admitted, {r['refused']} refused "
              f"(HTTP 503); the admitted: pose->pulse in the server p50 {fmt(r['server_p50'])} ms, p99 "
              f"{fmt(r['server_p99'])} ms ({r['server_moves']} moves, {r['server_missed']} without a following frame), "
              f"{r['lost']} moves without a frame in 300 ms, {r['dropped']} pages dropped; "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    if args.figure:
        figure(rows, Path(args.figure))
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()

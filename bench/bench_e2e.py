"""End-to-end benchmark: `hand/pose` (or `hand/joints`) published -> its CAN duty frame, every node a process.

The bench process runs the broker (a zmq proxy thread) and publishes `hand/pose`; `scene`,
`tactile` and `motors` (emulated boards, `trace: true`) run as separate node processes. The motor
node reports, on `motors/trace`, when each command's last duty frame was accepted by python-can's
virtual bus (the board emulator has it then); latency = that time - the pose's stamp (one clock).
Poses go out at 90 Hz and then at 1 kHz; the hand circles a tesseract's front vertex
(config/scenes/hypercube-vertex.yaml), so nearly every pose changes some motor's duty.

Baseline, in the same run: the same pipeline as plain calls in this process (TactileEngine ->
MotorDriver duty mapping and cantools encode -> python-can virtual send, emulator listening).
The latency is also split at the `tactile/motors` stamp (the bench subscribes to that topic too).

Drops: every pose published that never shows up in the trace, split by cause: skipped by the
tactile node's latest-only subscription, skipped by the motor node's, superseded while the
driver held back a board's change frame (a board gets a change frame at most every half refresh
period), "no frame needed" (its duties were already on the bus), and lost (the rest).

The articulated hand (`--hand joints`, or `both`, the default: the rigid pose, then the joints):
the bench publishes the 25 WebXR joints of the glove's hand curling its fingers (a fist and back
each second) just before the pose of the same instant with the same stamp, as a hand-tracking
tracker does; the tactile node places every sample on its bone from the joints (the pose is
superseded) and the latency runs from that stamp. Its baseline is the same plain calls with the
joints.

Backlog: the p50 latency of the last window of a rate's run over that of the first (`--window`,
60 s; a fifth of the run when shorter). Target at 1 kHz over 5 minutes (`--seconds 300 --rates
1000`): within 1.1x.

    .venv/bin/python bench/bench_e2e.py [--seconds 6] [--rates 90 1000] [--window 60] [--hand both|pose|joints]
"""
from __future__ import annotations

import argparse
import dataclasses
import gc
import math
import os
import signal
import tempfile
import time
import uuid
from pathlib import Path

import can
import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np
import yaml

from cpu import cpu_seconds, thread_seconds
from touch4d.bus import Node
from touch4d.bus.testing import node_process, running_broker, wait_until
from touch4d.geometry.scene import load_scene
from touch4d.boards.config import DEFAULT_GLOVE, load_glove_can
from touch4d.boards.driver import MotorDriver
from touch4d.boards.emulator import GloveEmulator
from touch4d.boards.protocol import GloveProtocol
from touch4d.messages import HandJoints, HandPose, Heartbeat, MotorCommand, MotorTrace
from touch4d.tactile.engine import TactileEngine
from touch4d.tactile.glove import load_glove
from touch4d.hands import HandShape
from touch4d.tracking.paths import Orbit

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "config/scenes/hypercube-vertex.yaml"
PATH = Orbit(center=[0.0, 0.0, 0.3], radius=0.3, period=1.0, plane="xy")  # inside the vertex's projection
NODES = ("scene", "tactile", "motors")


def bench_glove(tmp: Path) -> Path:
    """The default glove with its thermal limit lifted: the hand stays on the object all run long."""
    data = yaml.safe_load(DEFAULT_GLOVE.read_text())
    data["can"]["thermal"] = {"max_on_s": 1e6, "cool_s": 0.0}
    path = tmp / "glove.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def pose_at(t: float, stamp: float = 0.0) -> HandPose:
    s = PATH.sample(t)
    return HandPose(position=s.position, orientation=s.orientation, valid=True, stamp=stamp, source_stamp=stamp)


class JointPath:
    """The glove's hand on PATH curling its fingers (straight -> fist -> straight each second), as the
    joint sets a hand tracker would publish: made once per millisecond of the cycle, before timing."""

    def __init__(self, glove):
        self.glove = glove
        self.sets = []
        for k in range(1000):
            t = k / 1000.0
            s = PATH.sample(t)
            curl = 0.5 - 0.5 * math.cos(2 * math.pi * t)
            js = glove.skeleton.joint_set(s.position, s.orientation, glove.units_per_metre,
                                          HandShape(curl={f: curl for f in ("thumb", "index", "middle", "ring",
                                                                            "little")}))
            self.sets.append(js)

    def at(self, t: float, stamp: float = 0.0) -> HandJoints:
        return self.sets[int(round(t * 1000)) % 1000].message(stamp)


def ms(a) -> str:
    return f"{1e3 * a:7.2f}"


# ---- baseline: the same pipeline as plain calls in one process ------------------------------------

def baseline(glove_file: Path, count: int, joints: JointPath | None = None) -> np.ndarray:
    """Seconds per pose (or joint set): stimulus -> motor command -> duty frames encoded and sent on a
    virtual bus."""
    glove, cfg = load_glove(glove_file), load_glove_can(glove_file)
    cfg = dataclasses.replace(cfg, channel=f"bench-e2e-{uuid.uuid4().hex}")
    engine = TactileEngine(glove)
    engine.set_scene(load_scene(SCENE).to_message())
    protocol = GloveProtocol(cfg)
    driver = MotorDriver(cfg, protocol, now=0.0)
    emulator = GloveEmulator(cfg).start()
    bus = can.Bus(interface="virtual", channel=cfg.channel)
    step = 1.0 / cfg.refresh_hz    # driver time: a full refresh period per pose, so no change frame is held back
    times = np.empty(count)
    try:
        for k in range(count):
            pose = pose_at(k * 0.001) if joints is None else joints.at(k * 0.001)
            t0 = time.perf_counter()
            _, motors = engine.messages(pose)
            now = (k + 1) * step
            driver.command(motors.names, motors.intensity, now)
            for out in driver.outgoing(now):
                bus.send(out.msg, timeout=cfg.send_timeout_s)
                driver.sent(out, now)
            times[k] = time.perf_counter() - t0
    finally:
        bus.shutdown()
        emulator.stop()
    return times


# ---- end to end ----------------------------------------------------------------------------------

class Probe:
    """The bench's node: publishes poses, collects traces and heartbeats."""

    def __init__(self, bus, joints: JointPath):
        self.node = Node("bench", bus=bus, heartbeat=False)
        self.pub = self.node.create_publisher("hand/pose", HandPose)
        self.joints_pub = self.node.create_publisher("hand/joints", HandJoints)
        self.joints = joints
        self.traces: list[MotorTrace] = []
        self.beats: dict[str, Heartbeat] = {}
        self.commands: dict[float, float] = {}   # source_stamp -> stamp of tactile/motors, to split the latency
        self.node.create_subscription("tactile/motors", MotorCommand,
                                      lambda m: self.commands.__setitem__(m.source_stamp, m.stamp))
        self.node.create_subscription("motors/trace", MotorTrace, self.traces.append)
        self.node.create_subscription("node/heartbeat", Heartbeat, lambda m: self.beats.__setitem__(m.node, m))

    def traced(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.traces:
            return np.zeros(0), np.zeros(0)
        return (np.concatenate([t.source_stamps for t in self.traces]),
                np.concatenate([t.frame_times for t in self.traces]))

    def settle(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.node.spin_once(0.01)

    def fresh_stats(self, timeout: float = 5.0) -> dict[str, dict]:
        """Every node's heartbeat stats, from heartbeats sent after now."""
        since = time.time()
        wait_until(lambda: all(n in self.beats and self.beats[n].stamp > since for n in NODES),
                   timeout, spin=self.node)
        return {n: dict(self.beats[n].stats) for n in NODES}

    def run(self, rate: float, seconds: float, hand: str = "pose") -> np.ndarray:
        """Publish poses (with `hand` "joints", each just after the joint set of its instant, the same
        stamp) at `rate` for `seconds` (absolute schedule); returns their stamps."""
        stamps = []
        period = 1.0 / rate
        start = time.perf_counter()
        k = 0
        while True:
            due = start + k * period
            if due - start >= seconds:
                break
            while (left := due - time.perf_counter()) > 0:   # collect traces meanwhile, without busy-waiting
                if left > 0.0015:
                    self.node.spin_once(left - 0.001)          # waits whole milliseconds, rounded up
                else:
                    self.node.spin_once(0)
                    time.sleep(max(0.0, due - time.perf_counter()))
            stamp = time.time()
            if hand == "joints":
                self.joints_pub.publish(self.joints.at(k * period, stamp))
            self.pub.publish(pose_at(k * period, stamp))
            stamps.append(stamp)
            k += 1
        return np.array(stamps)


def idle_cpu(probe: Probe, pids: dict[str, int], seconds: float) -> dict[str, float]:
    """Each process's CPU share with no poses: the motor node still refreshes every board at
    refresh_hz; its process also runs the board emulator (a thread of its own, split out)."""
    cpu0 = {n: cpu_seconds(p) for n, p in pids.items()}
    motors0 = thread_seconds(pids["motors"])
    wall0 = time.monotonic()
    probe.settle(seconds)
    wall = time.monotonic() - wall0
    out = {n: (cpu_seconds(p) - cpu0[n]) / wall for n, p in pids.items()}
    motors1 = thread_seconds(pids["motors"])
    out["motors: node thread"] = (motors1["main"] - motors0["main"]) / wall
    out["motors: emulator"] = (motors1["other"] - motors0["other"]) / wall
    return out


def phase(probe: Probe, pids: dict[str, int], rate: float, seconds: float, window: float, hand: str = "pose") -> dict:
    before = probe.fresh_stats()
    probe.traces.clear()
    probe.commands.clear()
    cpu0 = {n: cpu_seconds(p) for n, p in pids.items()}
    wall0 = time.monotonic()
    published = probe.run(rate, seconds, hand)
    wall = time.monotonic() - wall0
    cpu = {n: (cpu_seconds(p) - cpu0[n]) / wall for n, p in pids.items()}
    probe.settle(0.5)   # the last batches of the trace
    after = probe.fresh_stats()
    src, frame = probe.traced()
    mine = np.isin(src, published)
    src, lat = src[mine], frame[mine] - src[mine]
    cmd = np.array([probe.commands.get(s, np.nan) for s in src])
    split = np.isfinite(cmd)
    tactile_part, motors_part = cmd[split] - src[split], (frame[mine] - cmd)[split]

    def delta(node, key):
        return after[node].get(key, 0) - before[node].get(key, 0)

    causes = {
        # with joints, a pose is superseded by the joint set of its instant: only a skipped joint set is lost
        "tactile latest-only skip": delta("tactile", "hand/pose:dropped" if hand == "pose" else "hand/joints:dropped"),
        "motors latest-only skip": delta("motors", "tactile/motors:dropped"),
        "superseded (change held back)": delta("motors", "trace_superseded"),
        "no frame needed (unchanged)": delta("motors", "trace_unchanged"),
    }
    causes["lost (rest)"] = len(published) - len(src) - sum(causes.values())
    second = np.floor(src - published[0]).astype(int)
    per_second = [lat[second == k] for k in range(int(math.ceil(published[-1] - published[0])))]
    span = published[-1] - published[0]
    w = min(window, span / 5)
    windows = (lat[src - published[0] < w], lat[src - published[0] >= span - w])
    return {"rate": rate, "hand": hand, "joints_used": delta("tactile", "joints"),
            "published": len(published), "actual_rate": len(published) / wall,
            "traced": len(src), "lat": lat, "causes": causes, "cpu": cpu, "window": w, "windows": windows,
            "per_second": per_second, "tactile_part": tactile_part, "motors_part": motors_part}


def report(res: dict, base: np.ndarray) -> None:
    lat, n = res["lat"], res["published"]
    what = "poses" if res["hand"] == "pose" else f"joint sets (+ poses; {res['joints_used']} joint sets computed)"
    print(f"\n== {res['rate']:.0f} Hz {what} ({res['actual_rate']:.0f}/s achieved, {n} published) ==")
    if len(lat) == 0:
        print("  no pose reached the bus")
        return
    p50, p99 = np.percentile(lat, 50), np.percentile(lat, 99)
    b50, b99 = np.percentile(base, 50), np.percentile(base, 99)
    print(f"  latency {res['hand']:6s} -> last duty frame on the bus p50 {ms(p50)} ms   p99 {ms(p99)} ms   max {ms(lat.max())} ms")
    print(f"  plain calls in one process (baseline)        p50 {ms(b50)} ms   p99 {ms(b99)} ms")
    print(f"  ratio e2e / plain                            p50 {p50 / b50:7.1f} x   p99 {p99 / b99:7.1f} x")
    for label, part in (("pose -> tactile/motors published", res["tactile_part"]),
                        ("tactile/motors published -> frame", res["motors_part"])):
        if len(part):
            print(f"    {label:40s}   p50 {ms(np.percentile(part, 50))} ms   p99 {ms(np.percentile(part, 99))} ms")
    drops = n - res["traced"]
    unchanged = res["causes"]["no frame needed (unchanged)"]
    print(f"  traced {res['traced']}  drop rate {100 * drops / n:5.1f} % of poses "
          f"({100 * (drops - unchanged) / max(n - unchanged, 1):5.1f} % not counting 'no frame needed'):")
    for cause, count in res["causes"].items():
        print(f"    {cause:32s} {count:6d}  {100 * count / n:5.1f} %")
    seconds = [x for x in res["per_second"] if len(x)]
    if len(seconds) >= 2:
        p50s = [np.percentile(x, 50) for x in seconds]
        slope = np.polyfit(np.arange(len(p50s)), p50s, 1)[0]
        shown = p50s if len(p50s) <= 12 else p50s[:6] + [float("nan")] + p50s[-5:]
        print(f"  backlog trend: p50 per second {' '.join('...' if v != v else f'{1e3 * v:.2f}' for v in shown)} ms; "
              f"fitted slope {1e3 * slope:+.4f} ms per s")
    first, last = res["windows"]
    if len(first) and len(last):
        f50, l50 = np.percentile(first, 50), np.percentile(last, 50)
        print(f"  p50 over the last {res['window']:.0f} s {ms(l50)} ms / over the first {ms(f50)} ms = "
              f"{l50 / f50:.2f} x (target <= 1.1x; p99 {ms(np.percentile(last, 99))} / {ms(np.percentile(first, 99))} ms)")
    print("  CPU (share of one core): " + "  ".join(f"{k} {100 * v:5.1f} %" for k, v in res["cpu"].items()))


def interrupted(signum, frame):
    """Ctrl+C and SIGTERM unwind, so every context manager stops the process it started; a second
    Ctrl+C must not cut that cleanup short, so both are ignored from here on."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    raise KeyboardInterrupt


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="seconds per pose rate")
    parser.add_argument("--rates", type=float, nargs="+", default=[90.0, 1000.0])
    parser.add_argument("--baseline-count", type=int, default=3000)
    parser.add_argument("--window", type=float, default=60.0, help="seconds of the first and last windows compared")
    parser.add_argument("--hand", choices=("both", "pose", "joints"), default="both",
                        help="the rigid hand/pose, the articulated hand/joints, or both in turn")
    parser.add_argument("--no-realtime", dest="realtime", action="store_false",
                        help="run tactile and motors at normal priority (the demo gives them SCHED_FIFO)")
    args = parser.parse_args()
    for sig in (signal.SIGINT, signal.SIGTERM):   # also when started with SIGINT ignored (a background job)
        signal.signal(sig, interrupted)
    load0 = os.getloadavg()
    print(f"load average at start: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f} ({os.cpu_count()} cores)")
    print(f"tactile and motors at {'real-time (SCHED_FIFO, when permitted)' if args.realtime else 'normal'} priority")
    with tempfile.TemporaryDirectory(prefix="bench-e2e-") as tmp:
        glove = bench_glove(Path(tmp))
        joint_path = JointPath(load_glove(glove))
        hands = ("pose", "joints") if args.hand == "both" else (args.hand,)
        bases = {h: baseline(glove, args.baseline_count, joint_path if h == "joints" else None) for h in hands}
        channel = f"bench-e2e-{uuid.uuid4().hex}"
        with running_broker() as bus, \
                node_process("scene", bus, params={"scene": str(SCENE)}) as scene, \
                node_process("tactile", bus, params={"glove": str(glove)}, realtime=args.realtime) as tactile, \
                node_process("motors", bus, params={"glove": str(glove), "channel": channel,
                                                    "emulate": True, "trace": True},
                             realtime=args.realtime) as motors:
            pids = {"scene": scene.pid, "tactile": tactile.pid, "motors": motors.pid, "bench+broker": os.getpid()}
            probe = Probe(bus, joint_path)
            try:
                # warm up: until poses come back as traced frames (every node up, the scene known)
                deadline = time.monotonic() + 30
                while not probe.traces:
                    if time.monotonic() > deadline:
                        raise SystemExit("no motors/trace within 30 s:\n" +
                                         "\n".join(p.text for p in (scene, tactile, motors)))
                    probe.run(90.0, 0.2)
                probe.settle(0.3)
                idle = idle_cpu(probe, pids, 4.0)
                gc.freeze()   # this process's own collections then stay short however long the run
                results = [phase(probe, pids, rate, args.seconds, args.window, hand) for hand in hands
                           for rate in args.rates]
            finally:
                probe.node.shutdown()
        load1 = os.getloadavg()
        print("\nidle, no poses (CPU, share of one core): " + "  ".join(f"{k} {100 * v:5.1f} %" for k, v in idle.items()))
        for res in results:
            report(res, bases[res["hand"]])
        print(f"\nload average at end: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
        print("targets: p99 < 5 ms at 90 Hz, poses and joints alike; at 1 kHz no growing backlog (latency per second "
              "flat, nothing lost)")


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        print("interrupted; every process this bench started is stopped")
        raise SystemExit(130)

"""Motor node benchmark: a `tactile/motors` update in -> the CAN duty frames out, p50/p99.

Three figures in one run, on python-can's virtual bus (a listener bus receives the frames):
- bare: python-can `send` of the same four duty frames, pre-encoded (the baseline);
- node callback: the motor node's `on_command` for one MotorCommand (name mapping, duty, thermal
  limit, change detection, cantools encode of every changed board, the four sends);
- end to end: publish on the topic bus -> broker -> motor node (spinning in its own thread) ->
  the last of the four frames received by the listener.
Every update changes every board. The default glove is used with its thermal limit lifted (the
run keeps every motor on for longer than max_on_s).

Idle: the motor node as its own process with no command coming (it still refreshes every board,
at idle_refresh_hz once all is off and sent, publishes its status, traces and heartbeats), CPU
share of one core:
- bare (the baselines): a plain loop that sleeps to each refresh tick and sends the same frames,
  pre-encoded, with python-can, and polls the bus for answers; at idle_refresh_hz (the node's
  idle rate: the ratio is to this one) and at refresh_hz (what an idle node cost before it slowed);
- the node alone (nothing else on its virtual bus): the node's own cost. Target: under 3 %;
- the node with the board emulator in its process (as in the demo): the process, split into the
  node's thread and the emulator's (python-can's virtual bus copies every frame to it and wakes it).
Run: .venv/bin/python bench/bench_motors.py [--idle-seconds 8] [--idle-rounds 3]
"""
from __future__ import annotations

import argparse
import atexit
import logging
import os
import subprocess
import sys
import tempfile
import threading
import time
import uuid

import can
import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np
import yaml

from cpu import cpu_seconds, thread_seconds
from touch4d.bus import Broker, BusConfig, Node
from touch4d.bus.testing import node_process, running_broker, wait_until
from touch4d.boards.config import DEFAULT_GLOVE
from touch4d.boards.duty import duty_to_levels, intensity_to_duty
from touch4d.messages import MotorCommand, MotorStatus
from touch4d.nodes.motors import MotorsNode


def pct(samples_s):
    a = np.asarray(samples_s) * 1e6
    return np.percentile(a, 50), np.percentile(a, 99)


def patterns(n_motors, count, seed=1):
    """Intensities where consecutive updates differ on every board."""
    rng = np.random.default_rng(seed)
    out = rng.uniform(0.1, 1.0, size=(count, n_motors))
    out[1::2] = np.clip(out[::2][: len(out[1::2])] * 0.5, 0.1, 1.0)
    return out


# ---- idle --------------------------------------------------------------------------------------

def bare_loop(seconds: float, channel: str, rate: str) -> None:
    """The baseline of the idle figures: sleep to each tick of the glove's `rate` (refresh_hz or
    idle_refresh_hz), send the boards' pre-encoded duty frames with python-can, poll for answers."""
    from touch4d.boards.config import load_glove_can
    from touch4d.boards.protocol import GloveProtocol

    cfg = load_glove_can(None)
    protocol = GloveProtocol(cfg)
    frames = [protocol.duty(b.id, [0] * b.channels, 0) for b in cfg.boards]
    bus = can.Bus(interface="virtual", channel=channel)
    period = 1.0 / getattr(cfg, rate)
    tick = time.monotonic()
    end = tick + seconds
    while tick < end:
        tick += period
        time.sleep(max(0.0, tick - time.monotonic()))
        for frame in frames:
            bus.send(frame, timeout=cfg.send_timeout_s)
        while bus.recv(timeout=0) is not None:
            pass
    bus.shutdown()


def idle_share(pid: int, seconds: float) -> dict[str, float]:
    """CPU share of one core of a process over `seconds`: the whole process and its threads."""
    p0, t0, w0 = cpu_seconds(pid), thread_seconds(pid), time.monotonic()
    time.sleep(seconds)
    p1, t1, wall = cpu_seconds(pid), thread_seconds(pid), time.monotonic() - w0
    return {"process": (p1 - p0) / wall, **{k: (t1[k] - t0[k]) / wall for k in t0}}


def idle_node(bus, glove: str, emulate: bool, seconds: float) -> dict[str, float]:
    params = {"glove": glove, "channel": f"bench-idle-{uuid.uuid4().hex}", "emulate": emulate, "trace": True}
    with node_process("motors", bus, params=params) as proc:
        probe = Node("bench", bus=bus, heartbeat=False)
        seen = []
        probe.create_subscription("motors/status", MotorStatus, seen.append)
        try:
            wait_until(lambda: len(seen) >= 3, timeout=60, spin=probe)   # up and refreshing
        finally:
            probe.shutdown()
        time.sleep(1.0)
        return idle_share(proc.pid, seconds)


def idle(glove: str, seconds: float, rounds: int) -> None:
    results: dict[str, list] = {"idle_refresh_hz": [], "refresh_hz": [], "alone": [], "emulated": []}
    with running_broker() as bus:
        for _ in range(rounds):   # interleaved, so a burst of load hits every setup alike
            for rate in ("idle_refresh_hz", "refresh_hz"):
                channel = f"bench-idle-{uuid.uuid4().hex}"
                proc = subprocess.Popen([sys.executable, __file__, "--bare-loop", str(seconds + 1.5), channel, rate])
                time.sleep(1.0)
                results[rate].append(idle_share(proc.pid, seconds))
                proc.wait(30)
            results["alone"].append(idle_node(bus, glove, False, seconds))
            results["emulated"].append(idle_node(bus, glove, True, seconds))
    med = {k: {m: 100 * float(np.median([r[m] for r in v])) for m in v[0]} for k, v in results.items()}
    print(f"\nidle, no command ({rounds} interleaved rounds of {seconds:g} s, medians; CPU share of one core)")
    from touch4d.boards.config import load_glove_can
    cfg = load_glove_can(None)
    bare, fast = med["idle_refresh_hz"]["process"], med["refresh_hz"]["process"]
    print(f"  bare loop sending the same frames at {cfg.idle_refresh_hz:g} Hz (baseline) {bare:6.2f} %   "
          f"(at {cfg.refresh_hz:g} Hz: {fast:.2f} %)")
    alone = med["alone"]["process"]
    print(f"  motor node alone                                 {alone:6.2f} %   ratio {alone / bare:.1f}x   "
          f"(target < 3 %: {'met' if alone < 3 else 'MISSED'})")
    e = med["emulated"]
    print(f"  motor node with the board emulator (as in demo)  {e['process']:6.2f} %   node thread {e['main']:.2f} %, "
          f"emulator {e['other']:.2f} %, ZeroMQ {e['zmq']:.2f} %")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=2000)
    parser.add_argument("--idle-seconds", type=float, default=8.0)
    parser.add_argument("--idle-rounds", type=int, default=3)
    parser.add_argument("--bare-loop", nargs=3, metavar=("SECONDS", "CHANNEL", "RATE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.bare_loop:
        bare_loop(float(args.bare_loop[0]), args.bare_loop[1], args.bare_loop[2])
        return
    load = os.getloadavg()
    print(f"load average at start: {load[0]:.2f} ({os.cpu_count()} cores)")
    logging.getLogger("motors").setLevel(logging.ERROR)  # no boards on this bus: only frames are timed
    channel = f"bench-motors-{uuid.uuid4().hex}"
    glove = yaml.safe_load(DEFAULT_GLOVE.read_text())
    glove["can"]["thermal"] = {"max_on_s": 1e6, "cool_s": 0.0}
    glove_file = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    yaml.safe_dump(glove, glove_file)
    glove_file.close()
    atexit.register(os.unlink, glove_file.name)

    with Broker(BusConfig(pub_port=0, sub_port=0)) as endpoints:
        node = MotorsNode(params={"glove": glove_file.name, "channel": channel, "status_hz": 1.0}, bus=endpoints)
        cfg = node.cfg
        names = list(cfg.motor_names)
        listener = can.Bus(interface="virtual", channel=channel)
        sender = can.Bus(interface="virtual", channel=channel)
        try:
            data = patterns(len(names), args.count)
            period = 1.0 / cfg.refresh_hz
            gap = 0.6 * period  # a board is not sent twice within half a refresh period

            # -- node callback: on_command, timed in this thread (the node is not spinning) --------
            cb = []
            for v in data:
                msg = MotorCommand(names=names, intensity=v, source_stamp=time.time())  # fresh: not stale
                t0 = time.perf_counter()
                node.on_command(msg)
                cb.append(time.perf_counter() - t0)
                time.sleep(gap)
            frames_per_update = len(cfg.boards)
            while listener.recv(timeout=0) is not None:
                pass

            # -- bare python-can send of the same frames ------------------------------------------
            bare = []
            for i, v in enumerate(data):
                levels = duty_to_levels(intensity_to_duty(v, cfg.duty))
                msgs = []
                for b in cfg.boards:
                    lv = np.zeros(b.channels, dtype=int)
                    for k, c in cfg.motors_of(b.id):
                        lv[c] = levels[k]
                    msgs.append(node.protocol.duty(b.id, lv.tolist(), i))
                t0 = time.perf_counter()
                for m in msgs:
                    sender.send(m, timeout=cfg.send_timeout_s)
                bare.append(time.perf_counter() - t0)
                while listener.recv(timeout=0) is not None:
                    pass

            # -- end to end through the topic bus, the node spinning in its own thread ------------
            tester = Node("bench", bus=endpoints, heartbeat=False)
            pub = tester.create_publisher("tactile/motors", MotorCommand)
            stop = threading.Event()

            def spin():
                while not stop.is_set():
                    node.spin_once(0.01)

            thread = threading.Thread(target=spin, daemon=True)
            thread.start()
            time.sleep(0.5)  # subscriptions settled
            e2e, lost = [], 0
            for v in data[: max(200, args.count // 4)]:
                want = {}
                levels = duty_to_levels(intensity_to_duty(v, cfg.duty))
                for b in cfg.boards:
                    lv = [0] * b.channels
                    for k, c in cfg.motors_of(b.id):
                        lv[c] = int(levels[k])
                    want[cfg.ids.duty + b.id] = lv
                while listener.recv(timeout=0) is not None:
                    pass
                t0 = time.perf_counter()
                pub.publish(MotorCommand(names=names, intensity=v))
                deadline = t0 + 1.0
                while want and time.perf_counter() < deadline:
                    m = listener.recv(timeout=0.05)
                    if m is None or m.arbitration_id not in want:
                        continue
                    f = node.protocol.decode(m)
                    if node.protocol.levels(f, len(want[m.arbitration_id])) == want[m.arbitration_id]:
                        del want[m.arbitration_id]
                if want:
                    lost += 1
                else:
                    e2e.append(time.perf_counter() - t0)
                time.sleep(gap)
            stop.set()
            thread.join()
            tester.shutdown()
        finally:
            node.shutdown()
            listener.shutdown()
            sender.shutdown()

    b50, b99 = pct(bare)
    c50, c99 = pct(cb)
    e50, e99 = pct(e2e)
    print(f"motor node, {len(names)} motors on {len(cfg.boards)} boards, {frames_per_update} frames per update, "
          f"python-can virtual bus, {len(data)} updates")
    print(f"  bare python-can send of the frames  p50 {b50:7.1f} us   p99 {b99:7.1f} us   (baseline)")
    print(f"  node callback (message in -> sent)  p50 {c50:7.1f} us   p99 {c99:7.1f} us   "
          f"ratio p50 {c50 / b50:.1f}x  p99 {c99 / b99:.1f}x")
    print(f"  end to end (publish -> last frame)  p50 {e50:7.1f} us   p99 {e99:7.1f} us   "
          f"ratio p50 {e50 / b50:.1f}x  ({len(e2e)} updates, {lost} not seen within 1 s)")
    print(f"  bus load of the configuration: {100 * node.load.fraction:.1f} % worst case")
    idle(glove_file.name, args.idle_seconds, args.idle_rounds)
    load = os.getloadavg()
    print(f"load average at the end: {load[0]:.2f}")


if __name__ == "__main__":
    main()

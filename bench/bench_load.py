"""Under load: hand pose -> duty frame on the CAN bus in the demo stack while the machine is busy.

Runs the demo (launch/demo.yaml: scripted tracker at 90 Hz, scene, tactile, motors with emulated
boards and `trace`, the renderer drawing, the monitor) while two CPU-bound processes (`stress-ng
--cpu 2`, installed with apt-get when missing) load the machine, and reports the latency from each
pose's stamp to the time its last duty frame was on the bus (the motor node's `motors/trace`):
once with the demo's real-time priority for the haptic loop (tracker, tactile, motors and the
broker SCHED_FIFO, when permitted) and once without (the same launch with `realtime: false`),
the second being the baseline of the ratio. Target: p99 <= 5 ms with real-time priority.

    .venv/bin/python bench/bench_load.py [--seconds 20] [--stressors 2]
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.bus import Node
from touch4d.bus.realtime import realtime_permitted
from touch4d.bus.testing import launch_process, wait_until
from touch4d.messages import MotorTrace

REPO = Path(__file__).resolve().parents[1]
LOOP = ("tracker", "tactile", "motors")


def ensure_stress_ng() -> str:
    """The stress-ng command, installed with apt-get (as root, or with sudo) when missing."""
    found = shutil.which("stress-ng")
    if found:
        return found
    sudo = [] if os.geteuid() == 0 else ["sudo"]
    print("installing stress-ng (apt-get)", flush=True)
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "install", "-y", "-qq", "stress-ng"], ["apt-get", "update", "-qq"],
                ["apt-get", "install", "-y", "-qq", "stress-ng"]):
        done = subprocess.run(sudo + cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if done.returncode == 0 and shutil.which("stress-ng"):
            return shutil.which("stress-ng")
    raise SystemExit("stress-ng is missing and could not be installed with apt-get (needs root or sudo)")


def without_realtime(tmp: Path) -> Path:
    """The demo launch with the haptic loop at normal priority."""
    path = tmp / "demo-normal-priority.yaml"
    nodes = "\n".join(f"  {role}: {{realtime: false}}" for role in LOOP)
    path.write_text(f"include: [{REPO / 'launch/demo.yaml'}]\nnodes:\n{nodes}\n")
    return path


def measure(launch_file: Path, seconds: float, warmup: float = 8.0) -> dict:
    """Run the launch; latency of every traced pose after `warmup`, for `seconds`."""
    with launch_process([str(launch_file), "--duration", str(warmup + seconds + 30)]) as run:
        probe = Node("bench", bus=run.bus, heartbeat=False)
        traces: list[MotorTrace] = []
        probe.create_subscription("motors/trace", MotorTrace, traces.append)
        try:
            wait_until(lambda: traces, timeout=60, spin=probe)   # every node up, poses reaching the boards
            end = time.monotonic() + warmup
            while time.monotonic() < end:
                probe.spin_once(0.05)
            traces.clear()
            start = time.time()
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                probe.spin_once(0.05)
            probe.spin(0.3)
        finally:
            probe.shutdown()
        realtime = "real-time priority (SCHED_FIFO" in run.text
    src = np.concatenate([t.source_stamps for t in traces]) if traces else np.zeros(0)
    sent = np.concatenate([t.frame_times for t in traces]) if traces else np.zeros(0)
    keep = src >= start
    lat = (sent - src)[keep]
    return {"lat": lat, "count": len(lat), "realtime": realtime}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds measured per setting")
    parser.add_argument("--stressors", type=int, default=2, help="CPU-bound stress-ng processes")
    args = parser.parse_args()
    stress_ng = ensure_stress_ng()
    load = os.getloadavg()
    print(f"load average before: {load[0]:.2f} ({os.cpu_count()} cores); real-time priority "
          f"{'permitted' if realtime_permitted() else 'NOT permitted (root or CAP_SYS_NICE needed)'}")
    print(f"demo stack (renderer drawing, {'display' if os.environ.get('DISPLAY') else 'offscreen'}) with "
          f"{args.stressors} x stress-ng --cpu; {args.seconds:g} s measured per setting")
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench-load-") as tmp:
        stress = subprocess.Popen([stress_ng, "--cpu", str(args.stressors), "--timeout", "3600", "--quiet"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            time.sleep(1.0)
            for label, launch_file in (("real-time priority", REPO / "launch/demo.yaml"),
                                       ("normal priority", without_realtime(Path(tmp)))):
                results[label] = measure(launch_file, args.seconds)
            load = os.getloadavg()
        finally:
            os.killpg(stress.pid, 9)
            stress.wait()
    print("pose -> last duty frame on the CAN bus, under load:")
    for label, r in results.items():
        lat = r["lat"]
        if not len(lat):
            print(f"  {label:20s} no pose traced")
            continue
        print(f"  {label:20s} p50 {1e3 * np.percentile(lat, 50):6.2f} ms   p99 {1e3 * np.percentile(lat, 99):6.2f} ms   "
              f"max {1e3 * lat.max():7.2f} ms   ({r['count']} poses{'' if r['realtime'] or 'normal' in label else ', real-time NOT applied'})")
    rt, normal = results["real-time priority"]["lat"], results["normal priority"]["lat"]
    if len(rt) and len(normal):
        p99 = np.percentile(rt, 99)
        print(f"  ratio real-time / normal: p50 {np.percentile(rt, 50) / np.percentile(normal, 50):.2f}x   "
              f"p99 {p99 / np.percentile(normal, 99):.2f}x")
        print(f"  target p99 <= 5 ms with real-time priority: {'met' if p99 <= 5e-3 else 'MISSED'} ({1e3 * p99:.2f} ms)")
    print(f"load average during: {load[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

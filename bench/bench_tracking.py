"""Tracking benchmarks: the scene node's update, the scripted tracker's tick, and its rate on the bus.

Each figure is printed beside a baseline measured in the same run:
  scene update  SceneControl.on_controller (one held-trigger sample -> new orientation)
                vs geometry.rotation.controller_rotation alone (the §4.4 mapping it calls)
  tracker tick  path sample + calibration + both messages encoded
                vs encoding one ready-made HandPose
  bus rate      scripted tracker at 1 kHz and 90 Hz, poses/s received by a subscriber
                vs the rate asked for
Run: .venv/bin/python bench/bench_tracking.py
"""
from __future__ import annotations

import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.geometry.rotation import controller_rotation
from touch4d.geometry.scene import load_scene
from touch4d.messages import HandPose
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import CONFIG_DIR
from touch4d.tracking.outputs import from_hand
from touch4d.tracking.paths import load_path, looped
from touch4d.tracking.scene_control import SceneControl


def per_call(fn, n: int) -> float:
    """Median over 5 rounds of the mean time per call, microseconds."""
    rounds = []
    for _ in range(5):
        start = time.perf_counter()
        for i in range(n):
            fn(i)
        rounds.append((time.perf_counter() - start) / n * 1e6)
    return float(np.median(rounds))


def bench_scene_update(n: int = 400) -> None:
    control = SceneControl(load_scene(CONFIG_DIR / "scenes" / "hypercube.yaml"), load_calibration())
    rng = np.random.default_rng(0)
    positions = np.cumsum(rng.normal(0, 0.002, (n + 1, 3)), axis=0) + [0, 1.2, -0.45]
    quats = (Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.01, (n + 1, 3)), axis=0))).as_quat()
    control.on_controller(positions[0], quats[0], 1.0, [])
    update = per_call(lambda i: control.on_controller(positions[i % n + 1], quats[i % n + 1], 1.0, []), n)
    d_t, d_r = rng.normal(0, 0.002, 3), rng.normal(0, 0.01, 3)
    base = per_call(lambda i: controller_rotation(d_t, d_r, (6.0, 1.0)), n)
    print(f"scene update:  {update:8.1f} us per controller sample; controller_rotation alone {base:8.1f} us; "
          f"ratio {update / base:.2f}")


def bench_tracker_tick(n: int = 2000) -> None:
    path, cal = load_path("demo"), load_calibration()

    def tick(i):
        hand, ctrl = from_hand(looped(path, i / 90.0), cal, stamp=1.0)
        hand.encode()
        ctrl.encode()

    pose = HandPose(position=np.zeros(3), orientation=np.array([0, 0, 0, 1.0]), valid=True, stamp=1.0)
    t_tick = per_call(tick, n)
    t_base = per_call(lambda i: pose.encode(), n)
    print(f"tracker tick:  {t_tick:8.1f} us per pose (sample, calibrate, 2 messages); one HandPose encode "
          f"{t_base:8.1f} us; ratio {t_tick / t_base:.2f}")


def bench_bus_rate(rate: float, seconds: float = 3.0) -> None:
    with running_broker() as bus:
        probe = Node("probe", bus=bus)
        try:
            hands = collect(probe, "hand/pose", HandPose)
            with node_process("scripted_tracker", bus, params={"path": "orbit", "rate": rate}):
                wait_until(lambda: len(hands) > 5, timeout=60, spin=probe)
                first = len(hands)
                start = time.monotonic()
                probe.spin(seconds)
                got = (len(hands) - first) / (time.monotonic() - start)
            seqs = [m.seq for m in hands]
            gaps = sum(b - a - 1 for a, b in zip(seqs, seqs[1:]))
        finally:
            probe.shutdown()
    print(f"bus rate:      {got:8.1f} poses/s received at rate {rate:g} Hz; ratio {got / rate:.3f}; "
          f"{gaps} lost by seq")


if __name__ == "__main__":
    bench_scene_update()
    bench_tracker_tick()
    bench_bus_rate(90.0)
    bench_bus_rate(1000.0)

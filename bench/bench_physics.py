"""4D physics step time: 1, 8, 64 and 256 bodies, free, resting on a floor and colliding, with contacts per
step; beside a plain numpy version of the same free-body integrator (vectorised over the bodies) and the
same compiled step run as plain Python (numba disabled, in a subprocess).

Goal: 64 bodies in contact at 1 kHz on one core (a step under 1 ms).

    .venv/bin/python bench/bench_physics.py            # every figure
    .venv/bin/python bench/bench_physics.py --quick    # fewer steps
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from touch4d.physics import bivector as bv
from touch4d.physics.bivector import PA, PB
from touch4d.physics.world import from_data, run, step

FLOOR = {"name": "floor", "halfspaces": [[1, 0, 0, 0, 20], [-1, 0, 0, 0, 20], [0, 1, 0, 0, -0.5], [0, -1, 0, 0, 2],
                                         [0, 0, 1, 0, 20], [0, 0, -1, 0, 20], [0, 0, 0, 1, 20], [0, 0, 0, -1, 20]],
         "physics": {"static": True}}


def grid(n: int, spacing: float) -> np.ndarray:
    """n points on a square grid in the floor's x, z, w (one layer)."""
    side = int(np.ceil(n ** (1 / 3)))
    idx = np.array([(i, j, k) for i in range(side) for j in range(side) for k in range(side)][:n], dtype=float)
    return ((idx - (side - 1) / 2) * spacing).tolist()      # plain floats, as a scene file holds


def scene(n: int, kind: str, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    a = 0.4
    objects = [FLOOR]
    if kind == "free":
        for k, p in enumerate(grid(n, 1.0)):
            objects.append({"name": f"b{k}", "shape": "tesseract", "size": a, "position": [p[0], 5, p[1], p[2]],
                            "physics": {"angular_velocity": [["xy", 30], ["zw", 50], ["xw", 7]],
                                        "velocity": [0.1, 0, 0, 0]}})
        return {"physics": {"gravity": [0, 0, 0, 0]}, "objects": objects[1:]}
    for k, p in enumerate(grid(n, a * 1.6)):
        if kind == "resting":
            objects.append({"name": f"b{k}", "shape": "tesseract", "size": a, "position": [p[0], -0.5 + a / 2, p[1], p[2]]})
        else:   # colliding: tilted bodies dropped in two layers onto the floor and onto each other
            layer = k % 2
            objects.append({"name": f"b{k}", "shape": "tesseract", "size": a,
                            "position": [p[0] + 0.1 * layer, -0.5 + a + 0.45 * layer + 0.3 * float(rng.random()), p[1],
                                         p[2]],
                            "rotation": [["xy", float(rng.uniform(0, 40))], ["zw", float(rng.uniform(0, 40))],
                                         ["yw", float(rng.uniform(0, 40))]],
                            "physics": {"restitution": 0.2, "velocity": [0, -1.0, 0, 0]}})
    return {"physics": {"gravity": [0, -9.81, 0, 0]}, "objects": objects}


def numpy_free_step(x, v, r, L, axes, iso_inv, excess, dt):
    """The same free-body step (split rotation flow) with numpy, vectorised over the bodies."""
    x = x + dt * v
    w = r @ axes
    half = 0.5 * dt

    def planes(w, order):
        for j in order:
            if not excess[:, j].any():
                continue
            lp = np.einsum("nij,ni->nj", bv.compound(w), L)
            phi = excess[:, j] * lp[:, j] * half
            c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
            a, b = PA[j], PB[j]
            wa, wb = w[:, :, a].copy(), w[:, :, b].copy()
            w[:, :, a] = c * wa + s * wb
            w[:, :, b] = -s * wa + c * wb
        return w

    w = planes(w.copy(), range(6))
    w = bv.exp(L * (iso_inv[:, None] * dt)) @ w
    w = planes(w, range(5, -1, -1))
    r = w @ np.swapaxes(axes, 1, 2)
    e = np.swapaxes(r, 1, 2) @ r - 3 * np.eye(4)
    return x, v, -0.5 * (r @ e), L


def time_steps(world, state, steps: int) -> tuple[float, float, object]:
    """Mean seconds per step (best of three rounds) and mean contact points per step."""
    best = np.inf
    contacts = 0
    for _ in range(3):
        s = state
        count = 0
        t0 = time.process_time()
        for _ in range(steps):
            s, c = step(world, s)
            count += len(c)
        best = min(best, (time.process_time() - t0) / steps)
        contacts = count / steps
    return best, contacts, s


def python_step_time(n: int, kind: str, steps: int) -> float:
    """The same step with numba disabled (plain Python loops), in a subprocess."""
    code = (f"import sys; sys.path.insert(0, {os.path.dirname(__file__)!r}); import bench_physics as b; "
            f"print(b.python_inner({n}, {kind!r}, {steps}))")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    return float(out.stdout.strip().splitlines()[-1])


def python_inner(n: int, kind: str, steps: int) -> float:
    world, state = from_data(scene(n, kind))
    state = run(world, state, 3)
    t0 = time.process_time()
    run(world, state, steps)
    return (time.process_time() - t0) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = parser.parse_args()
    steps = 50 if args.quick else 200
    figures = {}
    print("4D physics, one step (1 ms): CPU time of this process (the machine is shared), best of 3 rounds; one thread")
    print(f"{'bodies':>6}  {'free':>9}  {'numpy ref':>9}  {'ratio':>5}  {'resting':>9}  {'contacts':>8}  "
          f"{'colliding':>9}  {'contacts':>8}")
    for n in (1, 8, 64, 256):
        world, state = from_data(scene(n, "free"))
        step(world, state)                                   # compiled (or loaded from numba's cache)
        free, _, _ = time_steps(world, state, steps)
        x, v, r, L = state.x, state.v, state.r, state.L
        t0 = time.process_time()
        for _ in range(steps):
            x, v, r, L = numpy_free_step(x, v, r, L, world.axes, world.iso_inv, world.excess, world.dt)
        ref = (time.process_time() - t0) / steps
        check = run(world, state, 10)
        xr, vr, rr, lr = state.x, state.v, state.r, state.L
        for _ in range(10):
            xr, vr, rr, lr = numpy_free_step(xr, vr, rr, lr, world.axes, world.iso_inv, world.excess, world.dt)
        agree = float(np.abs(rr - check.r).max())
        world, state = from_data(scene(n, "resting"))
        state = run(world, state, 100)
        resting, rc, _ = time_steps(world, state, steps)
        world, state = from_data(scene(n, "colliding"))
        state = run(world, state, 150)                       # landing on the floor and on each other
        colliding, cc, _ = time_steps(world, state, steps)
        figures[n] = {"free_ms": free * 1e3, "numpy_free_ms": ref * 1e3, "resting_ms": resting * 1e3,
                      "resting_contacts": rc, "colliding_ms": colliding * 1e3, "colliding_contacts": cc,
                      "numpy_agrees_to": agree}
        print(f"{n:>6}  {free * 1e3:7.3f}ms  {ref * 1e3:7.3f}ms  {ref / free:5.1f}  {resting * 1e3:7.3f}ms  "
              f"{rc:8.1f}  {colliding * 1e3:7.3f}ms  {cc:8.1f}   (numpy and compiled orientations agree to {agree:.0e})")
    py_steps = 3 if args.quick else 10
    for n in (1, 8):
        t = python_step_time(n, "resting", py_steps)
        figures[n]["python_resting_ms"] = t * 1e3
        print(f"plain Python (numba disabled), {n} resting: {t * 1e3:.1f} ms per step = "
              f"{t / figures[n]['resting_ms'] * 1e3:.0f}x the compiled step")
    ok = figures[64]["colliding_ms"] < 1.0 and figures[64]["resting_ms"] < 1.0
    print(f"64 bodies in contact at 1 kHz on one core: {'yes' if ok else 'no'} "
          f"(resting {figures[64]['resting_ms']:.2f} ms, colliding {figures[64]['colliding_ms']:.2f} ms per 1 ms step)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1)


if __name__ == "__main__":
    main()

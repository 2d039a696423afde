"""4D physics step time: 1, 8, 64 and 256 bodies, free, resting on a floor and colliding, with contacts per
step; beside a plain numpy version of the same free-body integrator (vectorised over the bodies) and the
same compiled step run as plain Python (numba disabled, in a subprocess); and 64 resting bodies beside the
step as it was before it was split in stages (its kernels read from git history, compiled in this process,
the two steps timed in interleaved blocks).

Goals: 64 bodies in contact at 1 kHz on one core (a step under 1 ms); the staged step no slower than the
single compiled step it replaced.

    .venv/bin/python bench/bench_physics.py            # every figure
    .venv/bin/python bench/bench_physics.py --quick    # fewer steps
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

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


PRESPLIT = "ac271bb"    # the commit before "The physics step in stages": one compiled step of 35 arguments


def presplit_kernels():
    """The pre-split step's kernels module, read from git history (old code is not kept in the tree) and
    imported from a cache folder (numba caches its compilation beside it); None without the history."""
    root = Path(__file__).resolve().parent.parent
    try:
        src = subprocess.run(["git", "-C", str(root), "show", f"{PRESPLIT}:touch4d/physics/kernels.py"],
                             capture_output=True, text=True, check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    # today's tree: the bivector kernel imported absolutely, the geometry kernels compiled on first use
    src = src.replace("from .bivector", "from touch4d.physics.bivector")
    for module, name in (("rotation", "renormalize"), ("segment", "clip_segment")):
        line = f"from touch4d.geometry.{module} import {name}"
        src = src.replace(line, f"{line}\n{name} = {name}.compiled")
    folder = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "touch4d" / "bench_presplit"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "presplit_kernels.py"
    if not path.exists() or path.read_text() != src:
        path.write_text(src)
    sys.path.insert(0, str(folder))
    try:
        return importlib.import_module("presplit_kernels")
    finally:
        sys.path.remove(str(folder))


def versus_presplit(old, n: int, rounds: int, block: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Seconds per step of today's step and of the pre-split one, `rounds` blocks of `block` steps each,
    interleaved (so both see the same load), on the same resting scene."""
    world, state = from_data(scene(n, "resting"))
    state = run(world, state, 100)
    o = world.options
    opts = np.zeros(old.N_OPTIONS)
    for index, value in ((old.OPT_ITERATIONS, o.iterations), (old.OPT_POSITION_ITERATIONS, o.position_iterations),
                         (old.OPT_MARGIN, o.margin), (old.OPT_SLOP, o.slop), (old.OPT_BAUMGARTE, o.baumgarte),
                         (old.OPT_RESTITUTION_SPEED, o.bounce_speed), (old.OPT_STICK_SPEED, o.stick_speed)):
        opts[index] = value
    none = np.zeros((0, 9))

    def old_step(motion, rows):
        *motion, rows = old.step(*motion, world.inv_mass, world.axes, world.inv_plane, world.iso_inv, world.excess,
                                 world.gravity_scale, *world.parts, world.friction_static, world.friction_kinetic,
                                 world.restitution, world.gravity, world.dt, opts, none, rows)
        return motion, rows

    motion, rows, new = (state.x, state.v, state.r, state.L), np.zeros((0, old.C_WIDTH)), state
    for _ in range(block):                                  # compiled (or loaded), contacts warm
        motion, rows = old_step(motion, rows)
        new, _ = step(world, new)
    if len(rows) != len(new.contacts.a) or np.abs(motion[0] - new.x).max() > 1e-6:
        raise SystemExit("the pre-split step and today's disagree on the resting scene")
    today, before = [], []
    for _ in range(rounds):
        t0 = time.process_time()
        for _ in range(block):
            motion, rows = old_step(motion, rows)
        t1 = time.process_time()
        for _ in range(block):
            new, _ = step(world, new)
        t2 = time.process_time()
        before.append((t1 - t0) / block)
        today.append((t2 - t1) / block)
    return np.array(today), np.array(before)


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
    old = presplit_kernels()
    if old is None:
        print(f"the pre-split step ({PRESPLIT}) is not in this checkout's history: no comparison")
    else:
        for n in (1, 64):
            today, before = versus_presplit(old, n, 10 if args.quick else 40)
            ratio = today / before
            q1, med, q3 = np.percentile(ratio, [25, 50, 75])
            figures[n]["presplit_resting_ms"] = float(np.median(before)) * 1e3
            figures[n]["versus_presplit"] = float(med)
            print(f"{n} resting, today's staged step vs the pre-split step ({PRESPLIT}), {len(ratio)} interleaved "
                  f"blocks: {np.median(today) * 1e3:.3f} ms vs {np.median(before) * 1e3:.3f} ms (medians), "
                  f"ratio {med:.2f}x (quartiles {q1:.2f}-{q3:.2f})"
                  + ("; target <= 1" if n == 64 else "; one body: mostly the call's cost, more arrays in and out"))
    ok = figures[64]["colliding_ms"] < 1.0 and figures[64]["resting_ms"] < 1.0
    print(f"64 bodies in contact at 1 kHz on one core: {'yes' if ok else 'no'} "
          f"(resting {figures[64]['resting_ms']:.2f} ms, colliding {figures[64]['colliding_ms']:.2f} ms per 1 ms step)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1)


if __name__ == "__main__":
    main()

"""Geometry benchmarks: ray casting 242 hand samples (paper §6) and a renderer's visibility frame build.

Each figure is printed beside a baseline measured in the same run: for ray casting, a plain numpy
broadcast of the same half-space test over (points, parts, half-spaces); for visibility, one frame
budget at 90 Hz. Run: .venv/bin/python bench/bench_geometry.py
"""
from __future__ import annotations

import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.shapes import get_shape
from touch4d.geometry.visibility import clip_units, relations, visible_edges, visible_faces

POINTS = 242


def best_of(fn, repeat=7, number=None) -> float:
    """Seconds per call: the best of `repeat` timings of `number` calls."""
    if number is None:
        number, t0 = 1, time.perf_counter()
        fn()
        once = time.perf_counter() - t0
        number = max(1, int(0.05 / max(once, 1e-7)))
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t0) / number)
    return min(times)


def broadcast_cast(parts, points):
    """Baseline: the half-space test as one plain broadcast over (points, parts, half-spaces)."""
    k = max(len(p.offsets) for _, p in parts)
    n = np.zeros((len(parts), k, 4))
    c = np.ones((len(parts), k))
    for i, (_, p) in enumerate(parts):
        n[i, :len(p.offsets)], c[i, :len(p.offsets)] = p.normals, p.offsets
    num = c[None] - np.einsum("pkj,nj->npk", n[:, :, :3], points)
    den = np.broadcast_to(n[None, :, :, 3], num.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = num / den
    enter = np.where(den < 0, ratio, -np.inf).max(axis=2)
    leave = np.where(den > 0, ratio, np.inf).min(axis=2)
    blocked = ((den == 0) & (num < 0)).any(axis=2)
    enter = np.maximum(enter, 0)
    t = np.where((enter <= leave) & ~blocked, enter, np.inf)
    best = t.min(axis=1)
    return np.where(np.isfinite(best), best, np.nan)


def scene_parts(name):
    rng = np.random.default_rng(0)
    if name == "tesseract":
        return [(0, get_shape("tesseract").parts[0].transformed(rotation_from_list([["xw", 20], ["yw", 10]]), [0, 0, 0, 1.5]))]
    if name == "120-cell":
        return [(0, get_shape("120-cell").parts[0].transformed(rotation_from_list([["xw", 20]]), [0, 0, 0, 1.5], 1.5))]
    names = ["tesseract", "5-cell", "16-cell", "24-cell", "pyramid", "cone", "duoprism", "prism"]
    parts = []
    for i in range(20):
        r = rotation_from_list([[p, rng.uniform(0, 360)] for p in ("xw", "yw", "zw", "yz")])
        pos = [*rng.uniform(-0.7, 0.7, 3), rng.uniform(0.5, 3)]
        parts += [(i, p.transformed(r, pos, 0.4)) for p in get_shape(names[i % len(names)]).parts]
    return parts


def bench_raycast():
    points = np.random.default_rng(1).uniform(-0.8, 0.8, (POINTS, 3))
    print(f"ray casting {POINTS} points (target: 120-cell under 0.2 ms)")
    for name in ("tesseract", "120-cell", "20 objects"):
        parts = scene_parts(name)
        caster = RayCaster(parts)
        t, _ = caster.cast(points)
        assert np.allclose(np.nan_to_num(t, nan=-1), np.nan_to_num(broadcast_cast(parts, points), nan=-1))
        ours = best_of(lambda: caster.cast(points))
        base = best_of(lambda: broadcast_cast(parts, points))
        persp = RayCaster(parts, eye_distance=3.0)
        ours_p = best_of(lambda: persp.cast(points))
        build = best_of(lambda: RayCaster(parts), repeat=3)
        halfspaces = sum(len(p.offsets) for _, p in parts)
        print(f"  {name:<11} ({halfspaces:4d} half-spaces): {ours * 1e3:7.3f} ms  perspective {ours_p * 1e3:7.3f} ms  "
              f"broadcast baseline {base * 1e3:7.3f} ms  ratio {base / ours:5.1f}x  (build {build * 1e3:.2f} ms)")


def bench_visibility():
    rng = np.random.default_rng(2)
    tess = get_shape("tesseract").parts[0]
    grid = np.linspace(-0.75, 0.75, 4)
    objects = [tess.transformed(rotation_from_list([["xw", rng.uniform(0, 90)], ["yz", rng.uniform(0, 90)]]),
                                [x, y, z, 1.5 + 0.3 * rng.uniform()], 0.3) for x in grid for y in grid for z in grid]
    budget = 1 / 90

    def frame(eye):
        units = []
        for p in objects:
            units.append(clip_units(p, eye))
            visible_faces(p, eye)
            visible_edges(p, eye)
        return relations(objects, eye, units)

    print("visibility for 64 tesseracts in a 4x4x4 grid (renderer frame budget at 90 Hz: 11.1 ms)")
    for label, fn in (("culling + clip units", lambda: [(clip_units(p), visible_faces(p), visible_edges(p)) for p in objects]),
                      ("front/behind (all pairs)", lambda: relations(objects)),
                      ("whole frame, orthographic", lambda: frame(None)),
                      ("whole frame, perspective", lambda: frame(3.0))):
        t = best_of(fn, repeat=5)
        print(f"  {label:<26} {t * 1e3:7.2f} ms  = {t / budget:5.2f} of a frame")
    stacked = [tess.transformed(rotation_from_list([["xw", rng.uniform(-30, 30)], ["yw", rng.uniform(-30, 30)]]),
                                [*rng.uniform(-0.3, 0.3, 3), 1.0 + 0.4 * k], 0.4) for k in range(16)]
    t = best_of(lambda: relations(stacked), repeat=3)
    print(f"  {'front/behind, 16 stacked':<26} {t * 1e3:7.2f} ms  = {t / budget:5.2f} of a frame")


def bench_hulls():
    from touch4d.geometry import shapes
    t0 = time.perf_counter()
    shapes._six_hundred_cell.cache_clear()
    shapes._cached.cache_clear()
    shapes.get_shape("120-cell")
    t = time.perf_counter() - t0
    print(f"building the 600-cell and 120-cell (Qhull, once per process): {t * 1e3:.0f} ms")


if __name__ == "__main__":
    bench_raycast()
    bench_visibility()
    bench_hulls()

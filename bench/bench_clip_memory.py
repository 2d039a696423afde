"""Clip-unit build memory: a 120-cell beside the hollow-front object (80 small convex parts).

Every part is padded to the scene's widest body (the 120-cell: 144 clip units, 600 vertices), and
the pairs of overlapping parts number thousands; in one batch their plane values took 4.6 GB. The
builder evaluates them in batches of at most `arrays.BATCH_FLOATS` values, each trimmed to its own
bodies' widths. Figures: peak traced memory (tracemalloc) and time of one build, batched, beside
the same build in one batch (the baseline: BATCH_FLOATS unbounded), in the same run.
Run: .venv/bin/python bench/bench_clip_memory.py [--quick]   (--quick: the batched build only)
"""
from __future__ import annotations

import sys
import time
import tracemalloc

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.shapes import get_shape
from touch4d.render.clip import Body, MeshBuilder, arrays


def bodies() -> list[Body]:
    cell = get_shape("120-cell").parts[0]
    out = [Body(cell, rotation_from_list([["xw", 10], ["yw", 5]]), np.array([-0.5, 0, 0, 1.5]), 1.0, np.ones(4), 0)]
    return out + [Body(p, np.eye(4), np.array([0.5, 0, 0, 1.5]), 1.0, np.ones(4), 1)
                  for p in get_shape("hollow-front").parts]


def measure(limit: int) -> tuple[float, float]:
    """(peak MB, seconds) of one fresh build with batches of at most `limit` values."""
    arrays.BATCH_FLOATS = limit
    scene = bodies()
    tracemalloc.start()
    t = time.perf_counter()
    MeshBuilder().build(scene)
    seconds = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return peak, seconds


def main() -> None:
    batched = measure(arrays.BATCH_FLOATS)
    print(f"120-cell + hollow-front ({len(bodies())} bodies), one clip build (tracemalloc on: times are slow)")
    print(f"  batched ({arrays.BATCH_FLOATS} values a batch): peak {batched[0]:7.0f} MB, {batched[1]:6.2f} s")
    if "--quick" not in sys.argv:
        whole = measure(1 << 62)
        print(f"  one batch (baseline):                 peak {whole[0]:7.0f} MB, {whole[1]:6.2f} s")
        print(f"  ratio batched / one batch: memory {batched[0] / whole[0]:.3f}, time {batched[1] / whole[1]:.2f}")


if __name__ == "__main__":
    main()

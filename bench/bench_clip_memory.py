"""Clip-unit build memory: a 120-cell beside the hollow-front object (80 small convex parts).

The occluders' arrays pad every part to the scene's widest body (the 120-cell: 144 clip units, 600
vertices), and the pairs of overlapping parts number thousands. The builder evaluates plane values
in batches of at most `arrays.BATCH_FLOATS` values, each trimmed to its own bodies' clip units and
vertices. Figures: peak traced memory (tracemalloc) and time of one build, beside the same build
(1) in one batch and (2) in one batch over the padded arrays, as the builder once did (the baseline),
in the same run. Run: .venv/bin/python bench/bench_clip_memory.py [--quick]  (--quick: no baseline,
which needs about 5 GB)
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
from touch4d.render.clip.occluders import Occluders

ORDER = Occluders._order


def bodies() -> list[Body]:
    cell = get_shape("120-cell").parts[0]
    out = [Body(cell, rotation_from_list([["xw", 10], ["yw", 5]]), np.array([-0.5, 0, 0, 1.5]), 1.0, np.ones(4), 0)]
    return out + [Body(p, np.eye(4), np.array([0.5, 0, 0, 1.5]), 1.0, np.ones(4), 1)
                  for p in get_shape("hollow-front").parts]


def padded_order(self, overlap, previous):
    """Occluders that see every body as wide as the widest (no trimming): the baseline's arrays. Set
    where the constructor first uses them, its ordering of the bodies."""
    self.n_planes[:], self.n_vertices[:] = self.planes.shape[1], self.vertices.shape[1]
    return ORDER(self, overlap, previous)


def measure(limit: int, trimmed: bool = True) -> tuple[float, float]:
    """(peak MB, seconds) of one fresh build with batches of at most `limit` values."""
    arrays.BATCH_FLOATS = limit
    Occluders._order = ORDER if trimmed else padded_order
    scene = bodies()
    tracemalloc.start()
    t = time.perf_counter()
    MeshBuilder().build(scene)
    seconds = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return peak, seconds


def main() -> None:
    limit = arrays.BATCH_FLOATS
    print(f"120-cell + hollow-front ({len(bodies())} bodies), one clip build (tracemalloc on: times are slow)")
    batched = measure(limit)
    print(f"  batched ({limit} values a batch), trimmed: peak {batched[0]:7.0f} MB, {batched[1]:6.2f} s")
    whole = measure(1 << 62)
    print(f"  one batch, trimmed:                      peak {whole[0]:7.0f} MB, {whole[1]:6.2f} s")
    if "--quick" not in sys.argv:
        base = measure(1 << 62, trimmed=False)
        print(f"  one batch, padded (baseline):            peak {base[0]:7.0f} MB, {base[1]:6.2f} s")
        print(f"  ratio batched / baseline: memory {batched[0] / base[0]:.3f}, time {batched[1] / base[1]:.2f}")


if __name__ == "__main__":
    main()

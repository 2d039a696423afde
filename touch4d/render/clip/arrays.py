"""Array helpers of the clip-unit frame build: row gathers, padding, bounding boxes.

The build's arrays are small and its passes short, so numpy's per-call cost dominates: hot paths
gather rows with `take`/`compress` (about twice as fast as fancy or boolean indexing on rows of a
few floats) and reduce short axes after moving them first (`short_axis_first`).
"""
from __future__ import annotations

import numpy as np


def compress(mask: np.ndarray, *arrays: np.ndarray) -> tuple:
    """The items (first axis) of each array where `mask` holds; `compress` copies rows about twice
    as fast as boolean indexing."""
    return tuple(a.compress(mask, axis=0) for a in arrays)


def short_axis_first(a: np.ndarray, axis: int = 1) -> np.ndarray:
    """`a` with its short `axis` moved first, as a contiguous copy, to be reduced over axis 0.

    numpy reduces a short axis lying inside each row several times slower than one running across
    long contiguous rows; the copy costs less than the difference (measured 3-4x on the builder's
    vertex arrays)."""
    return np.ascontiguousarray(np.moveaxis(a, axis, 0))


def extent(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Screen bounding boxes (lo, hi), each (N, 3), of point sets v (N, K, >=3)."""
    u = short_axis_first(v[..., :3])
    return u.min(axis=0), u.max(axis=0)


def pad_width(v: np.ndarray, width: int) -> np.ndarray:
    """Pad polygons (P, K, 4) to `width` vertices by repeating each polygon's first vertex."""
    if v.shape[1] >= width:
        return v
    return np.concatenate([v, np.repeat(v[:, :1], width - v.shape[1], axis=1)], axis=1)




# The most float64 values one batch of plane values holds (32 MB): a scene's widest body (a 120-cell's
# 144 clip units, 600 vertices) times thousands of overlapping pairs would otherwise take gigabytes.
BATCH_FLOATS = 1 << 22


def batches(cost: np.ndarray, limit: int | None = None) -> list[np.ndarray]:
    """The indices of items of `cost` floats each, in batches of at most `limit` floats (BATCH_FLOATS;
    at least one item): cheap items together and dear ones together (sorted by cost), so that a batch
    trimmed to its widest item wastes little."""
    limit = BATCH_FLOATS if limit is None else limit
    if len(cost) * int(cost.max(initial=0)) <= limit:
        return [np.arange(len(cost))]                # the usual case: one batch, in order
    order = np.argsort(cost, kind="stable")
    ranked = np.maximum(cost.take(order), 1)
    out, start = [], 0
    while start < len(order):
        # ranked ascends, so a batch costs its size times its last item
        end = start + max(1, int(limit // ranked[start]))
        end = min(end, len(order))
        while end - start > 1 and (end - start) * ranked[end - 1] > limit:
            end = start + max(1, (end - start) // 2)
        out.append(order[start:end])
        start = end
    return out


# One 4D point (4 float64) as a single opaque item: numpy gathers and scatters such items 2-4x faster
# than rows of a (N, 4) float array, and the splitting loop moves little else.
POINT = np.dtype((np.void, 4 * 8))


def as_points(a: np.ndarray) -> np.ndarray:
    """View (N, 4) float64 points as N opaque items (copying first if not contiguous)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(POINT)[:, 0]


def take_points(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a[index] for points a (N, 4): float64 array of shape index.shape + (4,)."""
    return as_points(a).take(index).view(np.float64).reshape(*np.shape(index), 4)



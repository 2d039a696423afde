"""Removing what other bodies hide from convex polygons and segments, in batches: a body's outline
(its clip units) cuts an item into pieces, and the piece inside is dropped where it lies deeper
than the body's front (Sutherland-Hodgman for polygons, Cyrus-Beck for segments)."""
from __future__ import annotations

import numpy as np

from .arrays import POINT, as_points, batches, compress, extent, pad_width, short_axis_first, take_points
from .occluders import TOUCH, Occluders, plane_values


def cut_polygons(v: np.ndarray, count: np.ndarray, body: np.ndarray, occ: Occluders):
    """Remove what other bodies hide from convex polygons; returns pieces and each piece's source index."""
    src = np.arange(len(v))
    if len(v) == 0:
        return v, count, src
    item, b, rank = occ.candidates(*extent(v), body)
    # Drop pairs where the polygon lies outside one clip unit; keep each pair's straddled units.
    # A polygon lying on the outline's boundary counts as inside, so coplanar faces get hidden.
    near = np.zeros(len(item), bool)
    for rows in batches(occ.n_planes.take(b) * v.shape[1]):
        s = plane_values(occ.planes_of(b.take(rows)), v.take(item.take(rows), axis=0))
        near[rows] = (s.min(axis=1) <= TOUCH).all(axis=0)
    item, b = item[near], b[near]
    if len(item) == 0:
        return v, count, src
    rank = np.arange(len(item)) - np.searchsorted(item, item)

    # Only polygons some body may hide take part; the others pass unchanged.
    touched = np.zeros(len(v), bool)
    touched[item] = True
    work_src = np.nonzero(touched)[0]
    wv, wc = v.take(work_src, axis=0), count.take(work_src)
    for r in range(int(rank.max()) + 1):
        at = rank == r
        pair_of_src = np.full(len(v), -1)
        pair_of_src[item[at]] = np.nonzero(at)[0]
        pair = pair_of_src[work_src]
        act = pair >= 0
        pv, pc, parent = _subtract_batched(*compress(act, wv, wc), b[pair[act]], occ)
        rest_v, rest_c, rest_src = compress(~act, wv, wc, work_src)
        wv = np.concatenate([pad_width(rest_v, pv.shape[1]), pad_width(pv, wv.shape[1])])
        wc = np.concatenate([rest_c, pc])
        work_src = np.concatenate([rest_src, work_src[act][parent]])
    keep = ~touched
    width = max(v.shape[1], wv.shape[1])
    v, count, src = compress(keep, v, count, src)
    return (np.concatenate([pad_width(v, width), pad_width(wv, width)]),
            np.concatenate([count, wc]), np.concatenate([src, work_src]))


def _subtract_batched(v, count, body, occ: Occluders):
    """`_subtract` in batches of bounded memory (its plane values are polygons x vertices x units)."""
    parts = [(_subtract(v.take(rows, axis=0), count.take(rows), body.take(rows), occ), rows)
             for rows in batches(occ.n_planes.take(body) * v.shape[1])]
    if len(parts) == 1:
        (pv, pc, parent), rows = parts[0]
        return pv, pc, rows.take(parent)
    width = max(p[0][0].shape[1] for p in parts)
    return (np.concatenate([pad_width(pv, width) for (pv, _, _), _ in parts]),
            np.concatenate([pc for (_, pc, _), _ in parts]),
            np.concatenate([rows.take(parent) for (_, _, parent), rows in parts]))


def _subtract(v, count, body, occ: Occluders):
    """Pieces of each polygon outside `body`'s outline if it is behind the body there.

    Only the clip units that cross a polygon cut it, one after the other: piece j lies inside units
    1..j-1 and outside unit j; what is left is inside the outline. Returns (pieces, counts, parent
    index into the inputs)."""
    planes = occ.planes_of(body)
    s_all = plane_values(planes, v)                                           # (M, K, Q)
    low, high = s_all.min(axis=1), s_all.max(axis=1)                           # (M, Q)
    straddle = (high > TOUCH) & (low < -TOUCH)
    # Per polygon, the units crossing it, the one it reaches farthest beyond first: the big cuts
    # come early and often leave the rest inside later units, which then need no cut (fewer pieces).
    order = np.argsort(np.where(straddle, -high, np.inf), axis=0, kind="stable")
    apart = (low > TOUCH).any(axis=0)                           # outside one unit: nothing hidden
    n_cuts = np.where(apart, 0, straddle.sum(axis=0))
    rem_v, rem_c = v.copy(), np.where(apart, 0, count)
    outs_v, outs_c, outs_p = [], [], []
    for j in range(int(n_cuts.max(initial=0))):
        rows = np.nonzero((n_cuts > j) & (rem_c >= 3))[0]
        if len(rows) == 0:
            break
        if j == 0:
            s = s_all[order[0, rows], :, rows]
        else:
            plane = planes[rows, order[j, rows]]
            s = np.matmul(rem_v.take(rows, axis=0)[..., :3], plane[:, :3, None])[..., 0] - plane[:, 3:4]
            need = s.max(axis=1) > TOUCH             # earlier cuts may have left it inside this unit
            rows, s = rows[need], s[need]
            if len(rows) == 0:
                continue
        in_v, in_c, out_v, out_c = _split(rem_v.take(rows, axis=0), rem_c[rows], s, rem_v.shape[1])
        outs_v.append(out_v)
        outs_c.append(out_c)
        outs_p.append(rows)
        rem_v = pad_width(rem_v, in_v.shape[1])        # grows only when a cut adds a vertex
        rem_v[rows] = in_v
        rem_c[rows] = in_c
    # Depth test at an interior point of the overlap: the mean of the remainder's vertices.
    overlap = rem_c >= 3
    k = np.arange(rem_v.shape[1])[None] < rem_c[:, None]
    mean = short_axis_first(rem_v * k[..., None]).sum(axis=0) / np.maximum(rem_c, 1)[:, None]
    hidden = overlap & (mean[:, 3] > occ.front_depth(body, mean[:, :3]) + 1e-9)

    width = max([o.shape[1] for o in outs_v] + [v.shape[1]])
    shown_v, shown_c = compress(~hidden, v, count)
    keep_v, keep_c, keep_p = [pad_width(shown_v, width)], [shown_c], [np.nonzero(~hidden)[0]]
    for ov, oc, op in zip(outs_v, outs_c, outs_p):
        h = hidden[op] & (oc >= 3)
        keep_v.append(pad_width(ov.compress(h, axis=0), width))
        keep_c.append(oc[h])
        keep_p.append(op[h])
    return np.concatenate(keep_v), np.concatenate(keep_c), np.concatenate(keep_p)


def _split(v: np.ndarray, count: np.ndarray, s: np.ndarray, width: int = 1):
    """Sutherland-Hodgman for a batch of convex polygons, each against its own plane.

    Returns the pieces with s <= 0 and with s >= 0, as (vertices, counts) each, at least `width`
    vertices wide."""
    q, k = s.shape
    rows = np.arange(q)[:, None]
    col = np.arange(k)[None]
    valid = col < count[:, None]
    nxt = rows * k + (col + 1) % np.maximum(count, 1)[:, None]   # flat index of the next vertex
    s_n = s.reshape(-1).take(nxt)
    inside = s <= 0
    cross = valid & (inside != (s_n <= 0))
    t = s / np.where(cross, s - s_n, 1.0)       # only used where the edge crosses
    # Each vertex emits itself (if on the kept side) and then the crossing on its edge (if any).
    pts = np.empty((q, k, 2, 4))
    pts[:, :, 0] = v
    pts[:, :, 1] = v + t[..., None] * (take_points(v.reshape(-1, 4), nxt) - v)
    emit = np.empty((2, q, k, 2), bool)
    emit[0, :, :, 0] = valid & inside
    emit[1, :, :, 0] = valid & ~inside
    emit[:, :, :, 1] = cross
    out, new_count = _compact(pts.reshape(q, 2 * k, 4), emit.reshape(2, q, 2 * k), width)
    return out[0], new_count[0], out[1], new_count[1]


def _compact(pts: np.ndarray, emit: np.ndarray, min_width: int = 1):
    """Keep the emitted points (emit (S, Q, L)) of each row of pts (Q, L, 4) in order, padded with
    the row's first kept point; returns (S, Q, width >= min_width, 4) and counts (S, Q).

    Built by one gather: output slot c of a row takes the row's c-th emitted point (its first one
    past the end); rows with no point are zeros."""
    n_sides, q, length = emit.shape
    flat = np.flatnonzero(emit)                                  # sorted: row by row, in order
    per_row = np.bincount(flat // length, minlength=n_sides * q)   # not a sum over the short axis: slow
    counts = per_row.reshape(n_sides, q)
    width = max(int(per_row.max(initial=0)), min_width)
    if len(flat) == 0:
        return np.zeros((n_sides, q, width, 4)), counts
    starts = np.cumsum(per_row) - per_row
    col = np.arange(width)
    slot = np.minimum(starts[:, None] + np.where(col < per_row[:, None], col, 0), len(flat) - 1)
    out = as_points(pts.reshape(-1, 4)).take((flat % (q * length)).take(slot))
    empty = per_row == 0
    if empty.any():
        out[empty] = np.zeros((), POINT)
    return out.view(np.float64).reshape(n_sides, q, width, 4), counts

def cut_segments(v: np.ndarray, body: np.ndarray, occ: Occluders):
    """Remove what other bodies hide from segments (S, 2, 4); returns pieces and source indices."""
    src = np.arange(len(v))
    if len(v) == 0:
        return v, src
    item, b, rank = occ.candidates(*extent(v), body)
    for r in range(int(rank.max(initial=-1)) + 1):
        at = rank == r
        pair_of_src = np.full(len(body), -1)
        pair_of_src[item[at]] = b[at]
        occluder = pair_of_src[src]
        act = occluder >= 0
        if not act.any():
            continue
        sv, sb = v.compress(act, axis=0), occluder[act]
        done = [(_subtract_segments(sv.take(rows, axis=0), sb.take(rows), occ), rows)
                for rows in batches(occ.n_planes.take(sb) * 2)]          # bounded memory, as for polygons
        pv = np.concatenate([p for (p, _), _ in done])
        parent = np.concatenate([rows.take(par) for (_, par), rows in done])
        rest_v, rest_src = compress(~act, v, src)
        v = np.concatenate([rest_v, pv])
        src = np.concatenate([rest_src, src[act][parent]])
    return v, src


def _subtract_segments(v: np.ndarray, body: np.ndarray, occ: Occluders):
    """Cyrus-Beck: the part of each segment inside the body's outline, dropped where behind the body."""
    a, d = v[:, 0], v[:, 1] - v[:, 0]
    s = plane_values(occ.planes_of(body), v)                        # (M, 2, Q): units along rows
    sa, sb = s[:, 0], s[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = sa / (sa - sb)
    t0 = np.where((sa > 0) & (sb <= 0), t, 0.0).max(axis=0)
    t1 = np.where((sb > 0) & (sa <= 0), t, 1.0).min(axis=0)
    outside = ((sa > TOUCH) & (sb > TOUCH)).any(axis=0)
    overlap = ~outside & (t1 - t0 > 1e-9)
    mid = a + 0.5 * (t0 + t1)[:, None] * d
    hidden = overlap & (mid[:, 3] > occ.front_depth(body, mid[:, :3]) + 1e-9)
    idx = np.arange(len(v))
    head = hidden & (t0 > 1e-9)
    tail = hidden & (t1 < 1 - 1e-9)
    pieces = np.concatenate([
        v[~hidden],
        np.stack([a[head], a[head] + t0[head, None] * d[head]], axis=1),
        np.stack([a[tail] + t1[tail, None] * d[tail], v[tail, 1]], axis=1),
    ])
    parent = np.concatenate([idx[~hidden], idx[head], idx[tail]])
    return pieces, parent



"""Where convex parts touch (compiled with numba): the parts placed in the world, the broad phase, and the
narrow phase that gives a pair's contact normal and points (docs/physics.md, "Contacts").

The separating axis of least penetration among the cell normals of the two parts and the axes orthogonal to
an edge of one and a 2-face of the other gives the contact normal; the contact points are the edges of each
part clipped to the other (grown by the speculative margin and the shared tolerance), deduplicated, at most
MAX_POINTS per pair (the deepest, then the spread).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from touch4d.geometry import segment
from touch4d.geometry.tolerance import ANGLE, POINT, RELATIVE

from .arrays import Contacts, Parts, Placed

clip_segment = segment.clip_segment.compiled     # called inside the compiled narrow phase

MAX_POINTS = 12                        # contact points kept per pair of convex parts
MAX_CANDIDATES = 512                   # clipped edge end points examined per pair
EDGE_PREFERENCE = 1e-6                 # relative to the parts' size: an edge x face axis must separate this much
                                       # more than the best cell's to be taken (a cell's contact is steadier)

cache = dict(cache=True, nogil=True)


@njit(**cache)
def place_parts(parts: Parts, x, r) -> Placed:
    """The parts' vertices, cell planes, edge directions and 2-face planes in the world: body frame turned
    by r and moved to x (a stage of the step)."""
    verts = np.empty_like(parts.verts)
    normals = np.empty_like(parts.normals)
    offsets = np.empty_like(parts.offsets)
    dirs = np.empty_like(parts.dirs)
    spans = np.empty_like(parts.spans)
    for p in range(len(parts.body)):
        b = parts.body[p]
        rb_ = r[b]
        for vv in range(parts.v_start[p], parts.v_start[p] + parts.v_count[p]):
            for k in range(4):
                verts[vv, k] = (rb_[k, 0] * parts.verts[vv, 0] + rb_[k, 1] * parts.verts[vv, 1]
                                + rb_[k, 2] * parts.verts[vv, 2] + rb_[k, 3] * parts.verts[vv, 3] + x[b, k])
        for c in range(parts.c_start[p], parts.c_start[p] + parts.c_count[p]):
            acc = parts.offsets[c]
            for k in range(4):
                nk = (rb_[k, 0] * parts.normals[c, 0] + rb_[k, 1] * parts.normals[c, 1]
                      + rb_[k, 2] * parts.normals[c, 2] + rb_[k, 3] * parts.normals[c, 3])
                normals[c, k] = nk
                acc += nk * x[b, k]
            offsets[c] = acc
        for d in range(parts.d_start[p], parts.d_start[p] + parts.d_count[p]):
            for k in range(4):
                dirs[d, k] = (rb_[k, 0] * parts.dirs[d, 0] + rb_[k, 1] * parts.dirs[d, 1]
                              + rb_[k, 2] * parts.dirs[d, 2] + rb_[k, 3] * parts.dirs[d, 3])
        for f in range(parts.f_start[p], parts.f_start[p] + parts.f_count[p]):
            for h in range(2):
                for k in range(4):
                    spans[f, h, k] = (rb_[k, 0] * parts.spans[f, h, 0] + rb_[k, 1] * parts.spans[f, h, 1]
                                      + rb_[k, 2] * parts.spans[f, h, 2] + rb_[k, 3] * parts.spans[f, h, 3])
    return Placed(verts, normals, offsets, dirs, spans)


@njit(**cache)
def collide(parts: Parts, placed: Placed, dynamic, x, r, margin) -> Contacts:
    """Every contact point of the step (a stage): pairs from the broad phase in a fixed order, each pair's
    points from the narrow phase, with the point in b's frame to find it again; impulses and speeds 0."""
    n_parts = len(parts.body)
    lo, hi = part_bounds(parts.body, parts.v_start, parts.v_count, placed.verts, margin)
    pairs = broad_phase(parts.body, dynamic, lo, hi)
    cap = len(pairs) * MAX_POINTS
    a_ = np.empty(cap, np.int64)
    b_ = np.empty(cap, np.int64)
    point = np.empty((cap, 4))
    normal_ = np.empty((cap, 4))
    depth_ = np.empty(cap)
    key_ = np.empty(cap, np.int64)
    local = np.empty((cap, 4))
    pts = np.empty((MAX_POINTS, 4))
    depth = np.empty(MAX_POINTS)
    normal = np.empty(4)
    m = 0
    for q in range(len(pairs)):
        pa, pb = pairs[q, 0], pairs[q, 1]
        k = narrow_phase(pa, pb, parts, placed, margin, pts, depth, normal)
        a, b = parts.body[pa], parts.body[pb]
        for j in range(k):
            a_[m], b_[m], key_[m], depth_[m] = a, b, pa * n_parts + pb, depth[j]
            for kk in range(4):
                point[m, kk] = pts[j, kk]
                normal_[m, kk] = normal[kk]
            for kk in range(4):      # r_b^T (p - x_b)
                local[m, kk] = (r[b, 0, kk] * (pts[j, 0] - x[b, 0]) + r[b, 1, kk] * (pts[j, 1] - x[b, 1])
                                + r[b, 2, kk] * (pts[j, 2] - x[b, 2]) + r[b, 3, kk] * (pts[j, 3] - x[b, 3]))
            m += 1
    return Contacts(a_[:m], b_[:m], point[:m], normal_[:m], depth_[:m], np.zeros(m), np.zeros((m, 4)), np.zeros(m),
                    key_[:m], local[:m])


# ---- broad phase ----------------------------------------------------------------------------------


@njit(**cache)
def part_bounds(part_body, v_start, v_count, verts_world, margin):
    n = len(part_body)
    lo = np.empty((n, 4))
    hi = np.empty((n, 4))
    for p in range(n):
        for k in range(4):
            lo[p, k] = np.inf
            hi[p, k] = -np.inf
        for v in range(v_start[p], v_start[p] + v_count[p]):
            for k in range(4):
                x = verts_world[v, k]
                if x < lo[p, k]:
                    lo[p, k] = x
                if x > hi[p, k]:
                    hi[p, k] = x
        for k in range(4):
            lo[p, k] -= 0.5 * margin
            hi[p, k] += 0.5 * margin
    return lo, hi


@njit(**cache)
def broad_phase(part_body, dynamic, lo, hi):
    """Pairs of parts of different bodies, at least one dynamic, whose boxes overlap (sweep along x)."""
    n = len(part_body)
    order = np.argsort(lo[:, 0], kind="mergesort")
    pairs = np.empty((max(16, 4 * n), 2), dtype=np.int64)
    count = 0
    for ii in range(n):
        i = order[ii]
        for jj in range(ii + 1, n):
            j = order[jj]
            if lo[j, 0] > hi[i, 0]:
                break
            bi, bj = part_body[i], part_body[j]
            if bi == bj or not (dynamic[bi] or dynamic[bj]):
                continue
            if hi[i, 1] < lo[j, 1] or hi[j, 1] < lo[i, 1] or hi[i, 2] < lo[j, 2] or hi[j, 2] < lo[i, 2] \
                    or hi[i, 3] < lo[j, 3] or hi[j, 3] < lo[i, 3]:
                continue
            if count == len(pairs):
                grown = np.empty((2 * len(pairs), 2), dtype=np.int64)
                grown[:count] = pairs[:count]
                pairs = grown
            a, b = (i, j) if i < j else (j, i)
            pairs[count, 0] = a
            pairs[count, 1] = b
            count += 1
    pairs = pairs[:count]
    # a fixed order whatever the sweep found first: the solver's order, and so the result, depends on it
    key = pairs[:, 0] * n + pairs[:, 1]
    return pairs[np.argsort(key, kind="mergesort")]


# ---- narrow phase ---------------------------------------------------------------------------------


@njit(**cache)
def _separation(na, oa, ca_start, ca_count, vb, vb_start, vb_count):
    """Largest separation of B's vertices beyond a cell plane of A, and which cell."""
    best, which = -np.inf, -1
    for c in range(ca_start, ca_start + ca_count):
        low = np.inf
        for v in range(vb_start, vb_start + vb_count):
            d = na[c, 0] * vb[v, 0] + na[c, 1] * vb[v, 1] + na[c, 2] * vb[v, 2] + na[c, 3] * vb[v, 3]
            if d < low:
                low = d
        sep = low - oa[c]
        if sep > best:
            best, which = sep, c
    return best, which


@njit(**cache)
def _clip_edges(verts, edges, e_start, e_count, normals, offsets, c_start, c_count, margin, facing, tol, pts, count):
    """End points of the edges (of one part) clipped to the other part, whose cells are grown by margin
    times how much they face `facing` (the direction the edges' part lies in), so a point may hover up to
    margin above the contact, never beside it, and by the tolerance tol, so an edge lying on a cell is kept."""
    # the loops index the arrays rather than take row views: each view costs two atomic reference counts
    n_cells = normals[c_start:c_start + c_count]
    grown = np.empty(c_count)
    for c in range(c_count):
        grow = (n_cells[c, 0] * facing[0] + n_cells[c, 1] * facing[1] + n_cells[c, 2] * facing[2]
                + n_cells[c, 3] * facing[3])
        grown[c] = offsets[c_start + c] + margin * max(grow, 0.0)
    p0 = np.empty(4)
    p1 = np.empty(4)
    for e in range(e_start, e_start + e_count):
        for k in range(4):
            p0[k] = verts[edges[e, 0], k]
            p1[k] = verts[edges[e, 1], k]
        t0, t1 = clip_segment(p0, p1, n_cells, grown, tol)
        if t0 > t1:
            continue
        for t in (t0, t1):
            if count >= MAX_CANDIDATES:
                return count
            for k in range(4):
                pts[count, k] = p0[k] + t * (p1[k] - p0[k])
            count += 1
            if t1 - t0 < 1e-12:
                break
    return count


@njit(**cache)
def _exit_depth(pts, i, direction, normals, offsets, c_start, c_count):
    """How far the point pts[i] must move along `direction` to leave the part (negative: it is outside, that
    far). Indexed, not sliced: a row view per cell would cost more than the arithmetic."""
    best = np.inf
    for c in range(c_start, c_start + c_count):
        along = (normals[c, 0] * direction[0] + normals[c, 1] * direction[1] + normals[c, 2] * direction[2]
                 + normals[c, 3] * direction[3])
        if along > ANGLE:
            t = (offsets[c] - (normals[c, 0] * pts[i, 0] + normals[c, 1] * pts[i, 1] + normals[c, 2] * pts[i, 2]
                               + normals[c, 3] * pts[i, 3])) / along
            if t < best:
                best = t
    return best


@njit(**cache)
def _cross3(a, b, c, out):
    """The vector orthogonal to a, b, c (4D): cofactors of the rows a, b, c; its length the 3-volume."""
    m01 = b[0] * c[1] - b[1] * c[0]
    m02 = b[0] * c[2] - b[2] * c[0]
    m03 = b[0] * c[3] - b[3] * c[0]
    m12 = b[1] * c[2] - b[2] * c[1]
    m13 = b[1] * c[3] - b[3] * c[1]
    m23 = b[2] * c[3] - b[3] * c[2]
    out[0] = a[1] * m23 - a[2] * m13 + a[3] * m12
    out[1] = -(a[0] * m23 - a[2] * m03 + a[3] * m02)
    out[2] = a[0] * m13 - a[1] * m03 + a[3] * m01
    out[3] = -(a[0] * m12 - a[1] * m02 + a[2] * m01)


@njit(**cache)
def _extent(n, verts, start, count):
    lo, hi = np.inf, -np.inf
    for v in range(start, start + count):
        d = n[0] * verts[v, 0] + n[1] * verts[v, 1] + n[2] * verts[v, 2] + n[3] * verts[v, 3]
        lo = min(lo, d)
        hi = max(hi, d)
    return lo, hi


@njit(**cache)
def _edge_face_axes(verts, pa_v, pa_vc, pb_v, pb_vc, dirs, d_s, d_c, spans, f_s, f_c, best, axis):
    """Separating axes orthogonal to an edge direction of one part and a 2-face of the other: the largest
    separation (b beyond a) found above `best`, its axis (from a to b) written into `axis`."""
    n = np.empty(4)
    for i in range(d_s, d_s + d_c):
        for j in range(f_s, f_s + f_c):
            _cross3(dirs[i], spans[j, 0], spans[j, 1], n)
            size = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2] + n[3] * n[3])
            if size < 1e-6:
                continue                       # the edge lies in the face's plane: no axis
            for k in range(4):
                n[k] /= size
            lo_a, hi_a = _extent(n, verts, pa_v, pa_vc)
            lo_b, hi_b = _extent(n, verts, pb_v, pb_vc)
            plus, minus = lo_b - hi_a, lo_a - hi_b
            sep = max(plus, minus)
            if sep > best:
                best = sep
                sign = 1.0 if plus >= minus else -1.0
                for k in range(4):
                    axis[k] = sign * n[k]
    return best


@njit(**cache)
def _support_mid(verts, start, count, n, sign, tol, out):
    """The centre of a part's vertices that lie farthest along sign * n (its supporting vertex, edge or face)."""
    top = -np.inf
    for v in range(start, start + count):
        d = sign * (n[0] * verts[v, 0] + n[1] * verts[v, 1] + n[2] * verts[v, 2] + n[3] * verts[v, 3])
        top = max(top, d)
    m = 0
    for k in range(4):
        out[k] = 0.0
    for v in range(start, start + count):
        d = sign * (n[0] * verts[v, 0] + n[1] * verts[v, 1] + n[2] * verts[v, 2] + n[3] * verts[v, 3])
        if d >= top - tol:
            for k in range(4):
                out[k] += verts[v, k]
            m += 1
    for k in range(4):
        out[k] /= m


@njit(**cache)
def _cell_axis(pa, pb, verts, v_start, v_count, normals, offsets, c_start, c_count, margin, tol, n):
    """The cell of either part that the other's vertices lie least beyond: its separation, written as the
    normal n (from a to b), and the part whose cells were not chosen (-1: apart by more than margin). A's
    cell is preferred unless B's is clearly better: equal axes (face on face) must not flip-flop."""
    sep_a, cell_a = _separation(normals, offsets, c_start[pa], c_count[pa], verts, v_start[pb], v_count[pb])
    if sep_a > margin:
        return sep_a, -1
    sep_b, cell_b = _separation(normals, offsets, c_start[pb], c_count[pb], verts, v_start[pa], v_count[pa])
    if sep_b > margin:
        return sep_b, -1
    if sep_b > sep_a + tol:
        for k in range(4):
            n[k] = -normals[cell_b, k]
        return sep_b, pa
    for k in range(4):
        n[k] = normals[cell_a, k]
    return sep_a, pb


@njit(**cache)
def _lies_flat(other, pb, normals, c_start, c_count, n):
    """Whether a cell of `other` (the part whose cells were not chosen) lies flat against the chosen cell."""
    sign = 1.0 if other == pb else -1.0
    for c in range(c_start[other], c_start[other] + c_count[other]):
        along = sign * (normals[c, 0] * n[0] + normals[c, 1] * n[1] + normals[c, 2] * n[2] + normals[c, 3] * n[3])
        if along < -1.0 + ANGLE:
            return True
    return False


@njit(**cache)
def _edge_axis(pa, pb, verts, v_start, v_count, dirs, d_start, d_count, spans, f_start, f_count, best, scale,
               margin, n):
    """The edge x 2-face axes of both parts (the caller has found no cell of one flat against the other's):
    returns the separation and what it is along: 0 the cell's axis (kept), 1 an edge-face axis that
    separates clearly more (written into n), -1 such an axis that separates them by more than margin."""
    if not (d_count[pa] > 0 and f_count[pb] > 0 or d_count[pb] > 0 and f_count[pa] > 0):
        return best, 0
    axis = np.empty(4)
    edge_best = _edge_face_axes(verts, v_start[pa], v_count[pa], v_start[pb], v_count[pb], dirs, d_start[pa],
                                d_count[pa], spans, f_start[pb], f_count[pb], best + EDGE_PREFERENCE * scale, axis)
    edge_best = _edge_face_axes(verts, v_start[pa], v_count[pa], v_start[pb], v_count[pb], dirs, d_start[pb],
                                d_count[pb], spans, f_start[pa], f_count[pa], edge_best, axis)
    if not edge_best > best + EDGE_PREFERENCE * scale:
        return best, 0
    if edge_best > margin:
        return edge_best, -1                   # separated along an edge-face axis
    for k in range(4):
        n[k] = axis[k]
    return edge_best, 1


@njit(**cache)
def _keep_distinct(pa, pb, normals, offsets, c_start, c_count, margin, same, n, minus, cand, count, split, depth,
                   keep):
    """Which candidates (b's clipped edges' end points, then from `split` a's) are contact points (keep) and
    how deep (depth): inside the other part, or out of it by under 0.9 margin, and not the same place across
    the normal (within `same`) as one kept before (which then takes the deeper depth of the two). Returns how
    many are kept."""
    kept = 0
    for i in range(count):
        if i < split:    # a point of b inside a: b must move along +n to leave a
            d = _exit_depth(cand, i, n, normals, offsets, c_start[pa], c_count[pa])
        else:            # a point of a inside b: b leaves it by moving a along -n
            d = _exit_depth(cand, i, minus, normals, offsets, c_start[pb], c_count[pb])
        if not d > -0.9 * margin:
            continue
        dup = False
        for j in range(i):
            if keep[j]:
                dist = 0.0
                along = 0.0
                for k in range(4):
                    dist += (cand[i, k] - cand[j, k]) ** 2
                    along += (cand[i, k] - cand[j, k]) * n[k]
                if dist - along * along < same * same:      # the same place across the normal: one point
                    dup = True
                    if d > depth[j]:
                        depth[j] = d
                    break
        if dup:
            continue
        depth[i] = d
        keep[i] = True
        kept += 1
    return kept


@njit(**cache)
def _edge_point(pa, pb, verts, v_start, v_count, n, tol, best, out_pts, out_depth, scratch):
    """An edge against a 2-face meet where no edge of either is inside the other (the overlap's corners are
    where 2-faces cross): one point between the two parts' supporting features, at the axis' depth."""
    _support_mid(verts, v_start[pa], v_count[pa], n, 1.0, tol, out_pts[0])
    _support_mid(verts, v_start[pb], v_count[pb], n, -1.0, tol, scratch)
    for k in range(4):
        out_pts[0, k] = 0.5 * (out_pts[0, k] + scratch[k])
    out_depth[0] = -best
    return 1


@njit(**cache)
def _reduce(cand, depth, keep, count, kept, n, out_pts, out_depth):
    """The kept points into out_pts and out_depth, at most MAX_POINTS: when there are more, the deepest, then
    each time the point farthest (across the normal) from those chosen. Returns how many."""
    idx = np.empty(kept, dtype=np.int64)
    m = 0
    for i in range(count):
        if keep[i]:
            idx[m] = i
            m += 1
    if kept <= MAX_POINTS:
        for m in range(kept):
            out_pts[m] = cand[idx[m]]
            out_depth[m] = depth[idx[m]]
        return kept
    chosen = np.zeros(kept, dtype=np.bool_)
    far = np.full(kept, np.inf)
    first = 0
    for m in range(kept):
        if depth[idx[m]] > depth[idx[first]]:
            first = m
    pick = first
    for slot in range(MAX_POINTS):
        chosen[pick] = True
        out_pts[slot] = cand[idx[pick]]
        out_depth[slot] = depth[idx[pick]]
        best, nxt = -1.0, -1
        for m in range(kept):
            if chosen[m]:
                continue
            diff = cand[idx[m]] - cand[idx[pick]]
            along = diff[0] * n[0] + diff[1] * n[1] + diff[2] * n[2] + diff[3] * n[3]
            dist = diff[0] ** 2 + diff[1] ** 2 + diff[2] ** 2 + diff[3] ** 2 - along * along
            if dist < far[m]:
                far[m] = dist
            if far[m] > best:
                best, nxt = far[m], m
        if nxt < 0:
            return slot + 1
        pick = nxt
    return MAX_POINTS


@njit(**cache)
def narrow_phase(pa, pb, parts, placed, margin, out_pts, out_depth, out_normal):
    """Contact points of two convex parts: returns their number (0: apart by more than margin);
    fills out_pts (K, 4), out_depth (K,) (> 0 penetrating) and out_normal (4,) from a to b. The tolerances
    scale with the larger part's size. In stages, as Box2D's polygon collider: the axis of least
    penetration (`_cell_axis`; `_edge_axis` unless a cell `_lies_flat` on the chosen one), the edges of
    each part clipped to the other (`_clip_edges`), the points kept (`_keep_distinct`, or `_edge_point` for
    an edge on a 2-face), at most MAX_POINTS of them (`_reduce`). The stages are given arrays, not the
    parts' tuples: taking an array from a tuple costs two atomic reference counts, per pair."""
    v_start, v_count, c_start, c_count = parts.v_start, parts.v_count, parts.c_start, parts.c_count
    e_start, e_count, d_start, d_count = parts.e_start, parts.e_count, parts.d_start, parts.d_count
    f_start, f_count, edges = parts.f_start, parts.f_count, parts.edges
    verts, normals, offsets, dirs, spans = placed.verts, placed.normals, placed.offsets, placed.dirs, placed.spans
    scale = max(parts.size[pa], parts.size[pb])
    tol = RELATIVE * scale
    n = out_normal
    best, other = _cell_axis(pa, pb, verts, v_start, v_count, normals, offsets, c_start, c_count, margin, tol, n)
    if other < 0:
        return 0
    along = 0
    if not _lies_flat(other, pb, normals, c_start, c_count, n):
        best, along = _edge_axis(pa, pb, verts, v_start, v_count, dirs, d_start, d_count, spans, f_start, f_count,
                                 best, scale, margin, n)
        if along < 0:
            return 0
    minus = -n
    cand = np.empty((MAX_CANDIDATES, 4))
    depth = np.empty(MAX_CANDIDATES)
    count = _clip_edges(verts, edges, e_start[pb], e_count[pb], normals, offsets, c_start[pa], c_count[pa],
                        margin, n, tol, cand, 0)
    split = count
    count = _clip_edges(verts, edges, e_start[pa], e_count[pa], normals, offsets, c_start[pb], c_count[pb],
                        margin, minus, tol, cand, count)
    keep = np.zeros(MAX_CANDIDATES, dtype=np.bool_)
    kept = _keep_distinct(pa, pb, normals, offsets, c_start, c_count, margin, POINT * scale, n, minus, cand, count,
                          split, depth, keep)
    if kept == 0:
        if along == 0:
            return 0
        return _edge_point(pa, pb, verts, v_start, v_count, n, tol, best, out_pts, out_depth, cand[0])
    return _reduce(cand, depth, keep, count, kept, n, out_pts, out_depth)

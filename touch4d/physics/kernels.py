"""The step's loops, compiled with numba: rotation flow, broad and narrow phase, the impulse solver.

Everything here works on flat arrays (no Python objects) so numba compiles it; `world.step` is the
Python face. Conventions are those of `bivector`: a bivector is a 6-vector over xy, xz, xw, yz, yw, zw,
w_ab turns axis a toward axis b, a point r of a body turning at w moves at W r, an impulse P at r
changes the angular momentum by r ^ P.

Contacts (docs/physics.md): the separating axis of least penetration among the cell normals of the two
convex parts and the axes orthogonal to an edge of one and a 2-face of the other gives the contact
normal; the contact points are the edges of each part clipped to the other (grown by the speculative
margin), deduplicated, at most MAX_POINTS per pair (the deepest, then the spread).
The solver is sequential impulses: a normal impulse >= 0 per point with restitution and speculative
targets, a tangential impulse vector in the 3D tangent space held inside the Coulomb disc of radius
mu * normal impulse (static mu while the point sticks, kinetic while it slides), then a separate
pass of pseudo-velocities that removes penetration without adding energy (split impulse).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from touch4d.geometry.rotation import renormalize
from touch4d.geometry.segment import clip_segment
from touch4d.geometry.tolerance import ANGLE, POINT, RELATIVE

from .bivector import PA, PB, compound_into, exp_into, turn_into, wedge_into

MAX_POINTS = 12                        # contact points kept per pair of convex parts
MAX_CANDIDATES = 512                   # clipped edge end points examined per pair

# solver options, in this order in the `options` array
OPT_ITERATIONS, OPT_POSITION_ITERATIONS, OPT_MARGIN, OPT_SLOP, OPT_BAUMGARTE, OPT_RESTITUTION_SPEED, \
    OPT_STICK_SPEED = range(7)
N_OPTIONS = 7

# columns of the contact array (one row per contact point); KEY (the pair of parts) and LOCAL (the point
# in body b's frame) find a point again in the next step, whose impulses then start from this step's
C_A, C_B, C_PX, C_NX, C_DEPTH, C_LAMBDA, C_TX, C_SPEED, C_KEY, C_LOCAL = 0, 1, 2, 6, 10, 11, 12, 16, 17, 18
C_WIDTH = 22
WARM_DISTANCE = 0.005                  # a point moved less than this (body frame) is the same point
EDGE_PREFERENCE = 1e-6                 # relative to the parts' size: an edge x face axis must separate this much
                                       # more than the best cell's to be taken (a cell's contact is steadier)


cache = dict(cache=True, nogil=True)


@njit(**cache)
def world_inverse_inertia(r, axes, inv_plane, out):
    """R Q diag(1 / I) (R Q)^T on bivectors: the world inverse inertia (6x6) of one body."""
    w = r @ axes
    c = np.empty((6, 6))
    compound_into(w, c)
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for k in range(6):
                acc += c[i, k] * inv_plane[k] * c[j, k]
            out[i, j] = acc


@njit(**cache)
def _plane_momentum(w, L, lp):
    c = np.empty((6, 6))
    compound_into(w, c)
    for j in range(6):
        acc = 0.0
        for i in range(6):
            acc += c[i, j] * L[i]
        lp[j] = acc


@njit(**cache)
def _turn_columns(w, a, b, phi):
    c, s = math.cos(phi), math.sin(phi)
    for k in range(4):
        wa, wb = w[k, a], w[k, b]
        w[k, a] = c * wa + s * wb
        w[k, b] = -s * wa + c * wb


@njit(**cache)
def rotate_free(r, axes, L, iso_inv, excess, dt):
    """The orientation after dt of a free body with world angular momentum L (which it keeps).

    Kinetic energy L^2 / (2 I0) + sum_ab excess_ab Lp_ab^2 / 2 (Lp: L in principal axes, excess_ab =
    1 / I_ab - 1 / I0) is split into its isotropic part, an exact rotation exp(L dt / I0) in the world,
    and one part per principal plane, each an exact rotation in that plane of the body: a symmetric
    (Strang) composition, so symplectic, second order, L kept exactly, energy without drift; a body
    with equal inertia in every plane (all excess 0) turns exactly.
    """
    e = np.empty((4, 4))
    if not excess.any():                       # equal inertia in every plane: one exact rotation
        exp_into(L * (iso_inv * dt), e)
        return renormalize(e @ r)
    w = r @ axes
    lp = np.empty(6)
    half = 0.5 * dt
    for j in range(6):
        if excess[j] != 0.0:
            _plane_momentum(w, L, lp)
            _turn_columns(w, PA[j], PB[j], excess[j] * lp[j] * half)
    exp_into(L * (iso_inv * dt), e)
    w = e @ w
    for j in range(5, -1, -1):
        if excess[j] != 0.0:
            _plane_momentum(w, L, lp)
            _turn_columns(w, PA[j], PB[j], excess[j] * lp[j] * half)
    return renormalize(w @ axes.T)


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
    n_cells = normals[c_start:c_start + c_count]
    grown = np.empty(c_count)
    for c in range(c_count):
        n = n_cells[c]
        grow = n[0] * facing[0] + n[1] * facing[1] + n[2] * facing[2] + n[3] * facing[3]
        grown[c] = offsets[c_start + c] + margin * max(grow, 0.0)
    for e in range(e_start, e_start + e_count):
        p0 = verts[edges[e, 0]]
        p1 = verts[edges[e, 1]]
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
def _exit_depth(q, direction, normals, offsets, c_start, c_count):
    """How far q must move along `direction` to leave the part (negative: q is outside, that far)."""
    best = np.inf
    for c in range(c_start, c_start + c_count):
        n = normals[c]
        along = n[0] * direction[0] + n[1] * direction[1] + n[2] * direction[2] + n[3] * direction[3]
        if along > ANGLE:
            t = (offsets[c] - (n[0] * q[0] + n[1] * q[1] + n[2] * q[2] + n[3] * q[3])) / along
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
def narrow_phase(pa, pb, v_start, v_count, c_start, c_count, e_start, e_count, verts, normals, offsets,
                 edges, d_start, d_count, dirs, f_start, f_count, spans, size, margin, out_pts, out_depth, out_normal):
    """Contact points of two convex parts: returns their number (0: apart by more than margin);
    fills out_pts (K, 4), out_depth (K,) (> 0 penetrating) and out_normal (4,) from a to b.
    size: every part's size (`tolerance.size` of its vertices), which scales the tolerances."""
    scale = max(size[pa], size[pb])
    tol = RELATIVE * scale
    sep_a, cell_a = _separation(normals, offsets, c_start[pa], c_count[pa], verts, v_start[pb], v_count[pb])
    if sep_a > margin:
        return 0
    sep_b, cell_b = _separation(normals, offsets, c_start[pb], c_count[pb], verts, v_start[pa], v_count[pa])
    if sep_b > margin:
        return 0
    # prefer a's axis unless b's is clearly better: equal axes (face on face) must not flip-flop
    if sep_b > sep_a + tol:
        for k in range(4):
            out_normal[k] = -normals[cell_b, k]
        best, other, o_start, o_count = sep_b, pa, c_start[pa], c_count[pa]
    else:
        for k in range(4):
            out_normal[k] = normals[cell_a, k]
        best, other, o_start, o_count = sep_a, pb, c_start[pb], c_count[pb]
    n = out_normal
    edge_contact = False
    # edge x 2-face axes, unless a cell of the other part lies flat against the reference cell (cell on
    # cell: no such axis separates more)
    flat = False
    sign = 1.0 if other == pb else -1.0
    for c in range(o_start, o_start + o_count):
        along = sign * (normals[c, 0] * n[0] + normals[c, 1] * n[1] + normals[c, 2] * n[2] + normals[c, 3] * n[3])
        if along < -1.0 + ANGLE:
            flat = True
            break
    if not flat and (d_count[pa] > 0 and f_count[pb] > 0 or d_count[pb] > 0 and f_count[pa] > 0):
        axis = np.empty(4)
        edge_best = _edge_face_axes(verts, v_start[pa], v_count[pa], v_start[pb], v_count[pb], dirs, d_start[pa],
                                    d_count[pa], spans, f_start[pb], f_count[pb], best + EDGE_PREFERENCE * scale, axis)
        edge_best = _edge_face_axes(verts, v_start[pa], v_count[pa], v_start[pb], v_count[pb], dirs, d_start[pb],
                                    d_count[pb], spans, f_start[pa], f_count[pa], edge_best, axis)
        if edge_best > best + EDGE_PREFERENCE * scale:
            if edge_best > margin:
                return 0                       # separated along an edge-face axis
            for k in range(4):
                n[k] = axis[k]
            edge_contact = True
            best = edge_best
    minus = -n
    cand = np.empty((MAX_CANDIDATES, 4))
    depth = np.empty(MAX_CANDIDATES)
    count = _clip_edges(verts, edges, e_start[pb], e_count[pb], normals, offsets, c_start[pa], c_count[pa],
                        margin, n, tol, cand, 0)
    split = count
    count = _clip_edges(verts, edges, e_start[pa], e_count[pa], normals, offsets, c_start[pb], c_count[pb],
                        margin, minus, tol, cand, count)
    keep = np.zeros(MAX_CANDIDATES, dtype=np.bool_)
    same = POINT * scale
    kept = 0
    for i in range(count):
        if i < split:    # a point of b inside a: b must move along +n to leave a
            d = _exit_depth(cand[i], n, normals, offsets, c_start[pa], c_count[pa])
        else:            # a point of a inside b: b leaves it by moving a along -n
            d = _exit_depth(cand[i], minus, normals, offsets, c_start[pb], c_count[pb])
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
    if kept == 0:
        if not edge_contact:
            return 0
        # an edge against a 2-face meet where no edge of either is inside the other (the overlap's corners are
        # where 2-faces cross): one point between the two parts' supporting features, at the axis' depth
        _support_mid(verts, v_start[pa], v_count[pa], n, 1.0, tol, out_pts[0])
        _support_mid(verts, v_start[pb], v_count[pb], n, -1.0, tol, cand[0])
        for k in range(4):
            out_pts[0, k] = 0.5 * (out_pts[0, k] + cand[0, k])
        out_depth[0] = -best
        return 1
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
    # too many: the deepest, then each time the point farthest (across the normal) from those chosen
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


# ---- the step -------------------------------------------------------------------------------------


@njit(**cache)
def _apply(body, p, r, sign, v, w, dL, inv_mass, inv_inertia, tmp6):
    """Impulse sign * p at offset r on one body: its velocity, angular velocity and momentum change."""
    if inv_mass[body] == 0.0:
        return
    for k in range(4):
        v[body, k] += sign * inv_mass[body] * p[k]
    wedge_into(r, p, tmp6)
    for i in range(6):
        dL[body, i] += sign * tmp6[i]
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += inv_inertia[body, i, j] * tmp6[j]
        w[body, i] += sign * acc


@njit(**cache)
def _point_velocity(body, r, v, w, out, tmp):
    turn_into(w[body], r, tmp)
    for k in range(4):
        out[k] = v[body, k] + tmp[k]


@njit(**cache)
def _tangent_basis(n, out):
    """out[0] = n, out[1:4] an orthonormal basis of the tangent space (from the axes least along n)."""
    big = 0
    for k in range(1, 4):
        if abs(n[k]) > abs(n[big]):
            big = k
    out[0] = n
    row = 1
    for axis in range(4):
        if axis == big:
            continue
        t = np.zeros(4)
        t[axis] = 1.0
        for j in range(row):
            dot = t[0] * out[j, 0] + t[1] * out[j, 1] + t[2] * out[j, 2] + t[3] * out[j, 3]
            for k in range(4):
                t[k] -= dot * out[j, k]
        size = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + t[3] * t[3])
        for k in range(4):
            out[row, k] = t[k] / size
        row += 1


@njit(**cache)
def _row_velocity(c, d, a, b, basis, ang, v, w):
    """Relative velocity of the bodies at contact c along its row d (b's minus a's)."""
    acc = 0.0
    for k in range(4):
        acc += basis[c, d, k] * (v[b, k] - v[a, k])
    for i in range(6):
        acc += ang[c, d, 1, i] * w[b, i] - ang[c, d, 0, i] * w[a, i]
    return acc


@njit(**cache)
def _apply_row(c, d, delta, a, b, basis, ang, inv_ang, inv_mass, v, w, dL):
    """An impulse delta along row d of contact c: +delta on b, -delta on a."""
    for k in range(4):
        v[b, k] += inv_mass[b] * delta * basis[c, d, k]
        v[a, k] -= inv_mass[a] * delta * basis[c, d, k]
    for i in range(6):
        w[b, i] += delta * inv_ang[c, d, 1, i]
        w[a, i] -= delta * inv_ang[c, d, 0, i]
        dL[b, i] += delta * ang[c, d, 1, i]
        dL[a, i] -= delta * ang[c, d, 0, i]


@njit(**cache)
def step(x, v, r, L, inv_mass, axes, inv_plane, iso_inv, excess, gravity_scale,
         part_body, v_start, v_count, c_start, c_count, e_start, e_count, local_verts, local_normals,
         local_offsets, edges, d_start, d_count, local_dirs, f_start, f_count, local_spans, part_size,
         friction_static, friction_kinetic, restitution,
         gravity, dt, options, impulses, previous):
    """One step: state (x, v, r, L) in, new state and the contact rows out (see module doc).

    impulses: (K, 9) rows [body, px, py, pz, pw (world point), jx, jy, jz, jw] applied at the start.
    previous: the contact rows of the step before (warm start: a point found again starts from its
    impulses, so a stack's solution carries over from step to step instead of being found anew).
    """
    n = len(x)
    iterations = int(options[OPT_ITERATIONS])
    position_iterations = int(options[OPT_POSITION_ITERATIONS])
    margin = options[OPT_MARGIN]
    slop = options[OPT_SLOP]
    baumgarte = options[OPT_BAUMGARTE]
    bounce_speed = options[OPT_RESTITUTION_SPEED]
    stick_speed = options[OPT_STICK_SPEED]
    x = x.copy()
    v = v.copy()
    L = L.copy()
    r = r.copy()
    dynamic = inv_mass > 0.0
    isotropic = np.empty(n, dtype=np.bool_)
    for i in range(n):
        isotropic[i] = not excess[i].any()
    tmp6 = np.empty(6)
    tmp4 = np.empty(4)
    tmpw = np.empty(4)
    # world inertia, angular velocity
    inv_inertia = np.zeros((n, 6, 6))
    w = np.zeros((n, 6))
    for i in range(n):
        if not dynamic[i]:
            continue
        if isotropic[i]:
            for j in range(6):
                inv_inertia[i, j, j] = iso_inv[i]
                w[i, j] = iso_inv[i] * L[i, j]
        else:
            world_inverse_inertia(r[i], axes[i], inv_plane[i], inv_inertia[i])
            for j in range(6):
                acc = 0.0
                for k in range(6):
                    acc += inv_inertia[i, j, k] * L[i, k]
                w[i, j] = acc
    dL = np.zeros((n, 6))
    # external impulses (the hand), then gravity
    for k in range(len(impulses)):
        body = int(impulses[k, 0])
        rr = impulses[k, 1:5] - x[body]
        _apply(body, impulses[k, 5:9].copy(), rr, 1.0, v, w, dL, inv_mass, inv_inertia, tmp6)
    for i in range(n):
        if dynamic[i]:
            for k in range(4):
                v[i, k] += gravity_scale[i] * gravity[k] * dt
    # world geometry of every part
    n_parts = len(part_body)
    verts = np.empty_like(local_verts)
    normals = np.empty_like(local_normals)
    offsets = np.empty_like(local_offsets)
    dirs = np.empty_like(local_dirs)
    spans = np.empty_like(local_spans)
    for p in range(n_parts):
        b = part_body[p]
        rb_ = r[b]
        for vv in range(v_start[p], v_start[p] + v_count[p]):
            for k in range(4):
                verts[vv, k] = (rb_[k, 0] * local_verts[vv, 0] + rb_[k, 1] * local_verts[vv, 1]
                                + rb_[k, 2] * local_verts[vv, 2] + rb_[k, 3] * local_verts[vv, 3] + x[b, k])
        for c in range(c_start[p], c_start[p] + c_count[p]):
            acc = local_offsets[c]
            for k in range(4):
                nk = (rb_[k, 0] * local_normals[c, 0] + rb_[k, 1] * local_normals[c, 1]
                      + rb_[k, 2] * local_normals[c, 2] + rb_[k, 3] * local_normals[c, 3])
                normals[c, k] = nk
                acc += nk * x[b, k]
            offsets[c] = acc
        for d in range(d_start[p], d_start[p] + d_count[p]):
            for k in range(4):
                dirs[d, k] = (rb_[k, 0] * local_dirs[d, 0] + rb_[k, 1] * local_dirs[d, 1]
                              + rb_[k, 2] * local_dirs[d, 2] + rb_[k, 3] * local_dirs[d, 3])
        for f in range(f_start[p], f_start[p] + f_count[p]):
            for h in range(2):
                for k in range(4):
                    spans[f, h, k] = (rb_[k, 0] * local_spans[f, h, 0] + rb_[k, 1] * local_spans[f, h, 1]
                                      + rb_[k, 2] * local_spans[f, h, 2] + rb_[k, 3] * local_spans[f, h, 3])
    lo, hi = part_bounds(part_body, v_start, v_count, verts, margin)
    pairs = broad_phase(part_body, dynamic, lo, hi)
    rows = np.zeros((len(pairs) * MAX_POINTS, C_WIDTH))
    ra_all = np.empty((len(rows), 4))
    rb_all = np.empty((len(rows), 4))
    target = np.empty(len(rows))
    mu = np.empty(len(rows))
    pts = np.empty((MAX_POINTS, 4))
    depth = np.empty(MAX_POINTS)
    normal = np.empty(4)
    va = np.empty(4)
    vb = np.empty(4)
    m = 0
    cursor = 0
    for q in range(len(pairs)):
        pa, pb = pairs[q, 0], pairs[q, 1]
        key = pa * n_parts + pb
        while cursor < len(previous) and previous[cursor, C_KEY] < key:
            cursor += 1
        k = narrow_phase(pa, pb, v_start, v_count, c_start, c_count, e_start, e_count, verts, normals, offsets,
                         edges, d_start, d_count, dirs, f_start, f_count, spans, part_size, margin, pts, depth, normal)
        a, b = part_body[pa], part_body[pb]
        mus = math.sqrt(friction_static[a] * friction_static[b])
        muk = math.sqrt(friction_kinetic[a] * friction_kinetic[b])
        e = max(restitution[a], restitution[b])
        for j in range(k):
            row = rows[m]
            row[C_A] = a
            row[C_B] = b
            row[C_PX:C_PX + 4] = pts[j]
            row[C_NX:C_NX + 4] = normal
            row[C_DEPTH] = depth[j]
            for kk in range(4):
                ra_all[m, kk] = pts[j, kk] - x[a, kk]
                rb_all[m, kk] = pts[j, kk] - x[b, kk]
            _point_velocity(a, ra_all[m], v, w, va, tmp4)
            _point_velocity(b, rb_all[m], v, w, vb, tmp4)
            vn = 0.0
            for kk in range(4):
                vn += (vb[kk] - va[kk]) * normal[kk]
            row[C_SPEED] = vn
            gap = max(-depth[j], 0.0)
            target[m] = -gap / dt                     # speculative: may close the gap, no more
            slide = 0.0
            for kk in range(4):
                slide += (vb[kk] - va[kk] - vn * normal[kk]) ** 2
            mu[m] = mus if math.sqrt(slide) < stick_speed else muk
            row[C_KEY] = key
            local = tmpw
            for kk in range(4):
                local[kk] = (r[b, 0, kk] * rb_all[m, 0] + r[b, 1, kk] * rb_all[m, 1] + r[b, 2, kk] * rb_all[m, 2]
                             + r[b, 3, kk] * rb_all[m, 3])
                row[C_LOCAL + kk] = local[kk]
            # warm start from the same point of the step before
            best = WARM_DISTANCE * WARM_DISTANCE
            found = -1
            prev = cursor
            while prev < len(previous) and previous[prev, C_KEY] == key:
                dd = 0.0
                for kk in range(4):
                    dd += (previous[prev, C_LOCAL + kk] - local[kk]) ** 2
                if dd < best:
                    best, found = dd, prev
                prev += 1
            if found >= 0 and previous[found, C_SPEED] >= -bounce_speed:   # an impact's impulse is not a load
                row[C_LAMBDA] = previous[found, C_LAMBDA]
                along = 0.0
                for kk in range(4):
                    along += previous[found, C_TX + kk] * normal[kk]
                for kk in range(4):
                    row[C_TX + kk] = previous[found, C_TX + kk] - along * normal[kk]
            m += 1
        # restitution: when any point of the pair closes its gap within this step, every point of the pair
        # that approaches faster than bounce_speed (and is no further than the margin) bounces, so a face
        # striking a face bounces as one whatever rounding does to each point's gap
        if e > 0.0 and k > 0:
            impact = False
            for c in range(m - k, m):
                if rows[c, C_SPEED] < target[c]:
                    impact = True
            if impact:
                for c in range(m - k, m):
                    vn = rows[c, C_SPEED]
                    if vn < -bounce_speed and vn * dt - rows[c, C_DEPTH] < margin:
                        target[c] = -e * vn
    rows = rows[:m]
    # Jacobians of every row (normal, three tangents) with the inverse inertia applied, computed once:
    # each solver visit is then a few dot products and no allocation
    basis = np.empty((m, 4, 4))                     # n, t1, t2, t3
    ang = np.zeros((m, 4, 2, 6))                    # r_a ^ d, r_b ^ d
    inv_ang = np.zeros((m, 4, 2, 6))                # I^-1 (r ^ d) per body
    k_row = np.empty((m, 4))                        # effective mass of each row
    lam = np.zeros((m, 4))                          # accumulated impulses along the rows
    for c in range(m):
        a, b = int(rows[c, C_A]), int(rows[c, C_B])
        _tangent_basis(rows[c, C_NX:C_NX + 4], basis[c])
        for d in range(4):
            inv_k = inv_mass[a] + inv_mass[b]
            for side in range(2):
                body = a if side == 0 else b
                rr = ra_all[c] if side == 0 else rb_all[c]
                if inv_mass[body] == 0.0:
                    continue
                dvec = basis[c, d]
                wedge_into(rr, dvec, ang[c, d, side])
                for i in range(6):
                    if isotropic[body]:
                        acc = iso_inv[body] * ang[c, d, side, i]
                    else:
                        acc = 0.0
                        for j in range(6):
                            acc += inv_inertia[body, i, j] * ang[c, d, side, j]
                    inv_ang[c, d, side, i] = acc
                    inv_k += ang[c, d, side, i] * acc
            k_row[c, d] = 1.0 / inv_k
        lam[c, 0] = rows[c, C_LAMBDA]
        for d in range(1, 4):
            acc = 0.0
            for kk in range(4):
                acc += rows[c, C_TX + kk] * basis[c, d, kk]
            lam[c, d] = acc
        for d in range(4):                          # warm start
            if lam[c, d] != 0.0:
                _apply_row(c, d, lam[c, d], a, b, basis, ang, inv_ang, inv_mass, v, w, dL)
    rel = np.empty(4)
    for it in range(iterations):
        for c in range(m):
            a, b = int(rows[c, C_A]), int(rows[c, C_B])
            vn = _row_velocity(c, 0, a, b, basis, ang, v, w)
            old = lam[c, 0]
            new = max(old + k_row[c, 0] * (target[c] - vn), 0.0)
            lam[c, 0] = new
            if new != old:
                _apply_row(c, 0, new - old, a, b, basis, ang, inv_ang, inv_mass, v, w, dL)
            # friction: the tangential impulse (3 rows) held inside the disc of radius mu * normal impulse
            limit = mu[c] * new
            if limit <= 0.0 and lam[c, 1] == 0.0 and lam[c, 2] == 0.0 and lam[c, 3] == 0.0:
                continue
            size = 0.0
            for d in range(1, 4):
                rel[d] = lam[c, d] - k_row[c, d] * _row_velocity(c, d, a, b, basis, ang, v, w)
                size += rel[d] * rel[d]
            size = math.sqrt(size)
            scale = limit / size if size > limit else 1.0
            for d in range(1, 4):
                new_t = rel[d] * scale
                if new_t != lam[c, d]:
                    _apply_row(c, d, new_t - lam[c, d], a, b, basis, ang, inv_ang, inv_mass, v, w, dL)
                    lam[c, d] = new_t
    for c in range(m):
        rows[c, C_LAMBDA] = lam[c, 0]
        for kk in range(4):
            rows[c, C_TX + kk] = lam[c, 1] * basis[c, 1, kk] + lam[c, 2] * basis[c, 2, kk] + lam[c, 3] * basis[c, 3, kk]
    # the new momentum: exactly the old plus the impulses' moments
    held = np.zeros(n, dtype=np.bool_)
    for c in range(m):
        if rows[c, C_LAMBDA] > 0.0:
            held[int(rows[c, C_A])] = True
            held[int(rows[c, C_B])] = True
    for i in range(n):
        L[i] += dL[i]
    # positions: a body no contact pushed follows its parabola exactly; one held moves with its new
    # velocity (symplectic Euler), which keeps resting contact still
    for i in range(n):
        if not dynamic[i]:
            continue
        for k in range(4):
            x[i, k] += dt * v[i, k]
            if not held[i]:
                x[i, k] -= 0.5 * dt * dt * gravity_scale[i] * gravity[k]
        r[i] = rotate_free(r[i], axes[i], L[i], iso_inv[i], excess[i], dt)
    # split impulse: pseudo-velocities push penetrating bodies apart, touching positions only
    if position_iterations > 0 and m > 0:
        pv = np.zeros((n, 4))
        pw = np.zeros((n, 6))
        pdl = np.zeros((n, 6))
        plam = np.zeros(m)
        for it in range(position_iterations):
            for c in range(m):
                excess_depth = rows[c, C_DEPTH] - slop
                if excess_depth <= 0.0:
                    continue
                a, b = int(rows[c, C_A]), int(rows[c, C_B])
                vn = _row_velocity(c, 0, a, b, basis, ang, pv, pw)
                old = plam[c]
                new = max(old + k_row[c, 0] * (baumgarte * excess_depth / dt - vn), 0.0)
                plam[c] = new
                if new != old:
                    _apply_row(c, 0, new - old, a, b, basis, ang, inv_ang, inv_mass, pv, pw, pdl)
        turn_by = np.empty((4, 4))
        for i in range(n):
            if dynamic[i] and (pv[i].any() or pw[i].any()):
                x[i] += dt * pv[i]
                exp_into(pw[i] * dt, turn_by)
                r[i] = renormalize(turn_by @ r[i])
    return x, v, r, L, rows


@njit(**cache)
def angular_velocities(r, L, axes, inv_plane):
    """World angular velocity (N, 6) of every body from its momentum."""
    n = len(r)
    out = np.zeros((n, 6))
    inv = np.empty((6, 6))
    for i in range(n):
        world_inverse_inertia(r[i], axes[i], inv_plane[i], inv)
        out[i] = inv @ L[i]
    return out

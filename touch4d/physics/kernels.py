"""The physics step in stages, each compiled with numba and tested on its own (as Box2D splits its island
and contact solver): `velocities`, `collide.place_parts` (part transforms), `collide.collide`, `rows`,
`solve`, `integrate`, `split_impulse`; `step` runs them in that order, `world.step` is the Python face.

The stages pass named tuples of arrays (`arrays`). Conventions are those of `bivector`: a bivector is a
6-vector over xy, xz, xw, yz, yw, zw, w_ab turns axis a toward axis b, a point r of a body turning at w
moves at W r, an impulse P at r changes the angular momentum by r ^ P.

The solver is sequential impulses: a normal impulse >= 0 per point with restitution and speculative
targets, a tangential impulse vector in the 3D tangent space held inside the Coulomb disc of radius
mu * normal impulse (static mu while the point sticks, kinetic while it slides), then a separate
pass of pseudo-velocities that removes penetration without adding energy (split impulse).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from touch4d.geometry import rotation

from .arrays import Bodies, Contacts, Motion, Options, Parts, Rows, Velocities
from .bivector import PA, PB, compound_into, exp_into, turn_into, wedge_into
from .collide import collide, place_parts

renormalize = rotation.renormalize.compiled     # called inside the compiled step

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
def _point_velocity(body, r, v, w, out, w_body, tmp):
    """out = the velocity of body's point at offset r (w_body, tmp: scratch, so no row view is taken)."""
    for i in range(6):
        w_body[i] = w[body, i]
    turn_into(w_body, r, tmp)
    for k in range(4):
        out[k] = v[body, k] + tmp[k]


@njit(**cache)
def _tangent_basis(normal, c, basis, t):
    """basis[c, 0] = normal[c], basis[c, 1:4] an orthonormal basis of the tangent space (from the axes least
    along it); t: scratch (4,). Indexed rather than sliced, as the solver's loops are."""
    big = 0
    for k in range(1, 4):
        if abs(normal[c, k]) > abs(normal[c, big]):
            big = k
    for k in range(4):
        basis[c, 0, k] = normal[c, k]
    row = 1
    for axis in range(4):
        if axis == big:
            continue
        for k in range(4):
            t[k] = 0.0
        t[axis] = 1.0
        for j in range(row):
            dot = t[0] * basis[c, j, 0] + t[1] * basis[c, j, 1] + t[2] * basis[c, j, 2] + t[3] * basis[c, j, 3]
            for k in range(4):
                t[k] -= dot * basis[c, j, k]
        size = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + t[3] * t[3])
        for k in range(4):
            basis[c, row, k] = t[k] / size
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
def velocities(bodies: Bodies, motion: Motion, impulses, gravity, dt) -> Velocities:
    """The bodies' world inverse inertia and angular velocity, then the external impulses (the hand) and
    gravity applied (a stage). impulses: (K, 9) rows [body, point (4, world), impulse (4)]."""
    x, L = motion.x, motion.L
    n = len(x)
    v = motion.v.copy()
    isotropic = np.empty(n, dtype=np.bool_)
    for i in range(n):
        isotropic[i] = not bodies.excess[i].any()
    inv_inertia = np.zeros((n, 6, 6))
    w = np.zeros((n, 6))
    for i in range(n):
        if bodies.inv_mass[i] == 0.0:
            continue
        if isotropic[i]:
            for j in range(6):
                inv_inertia[i, j, j] = bodies.iso_inv[i]
                w[i, j] = bodies.iso_inv[i] * L[i, j]
        else:
            world_inverse_inertia(motion.r[i], bodies.axes[i], bodies.inv_plane[i], inv_inertia[i])
            for j in range(6):
                acc = 0.0
                for k in range(6):
                    acc += inv_inertia[i, j, k] * L[i, k]
                w[i, j] = acc
    dL = np.zeros((n, 6))
    tmp6 = np.empty(6)
    for k in range(len(impulses)):
        body = int(impulses[k, 0])
        rr = impulses[k, 1:5] - x[body]
        _apply(body, impulses[k, 5:9].copy(), rr, 1.0, v, w, dL, bodies.inv_mass, inv_inertia, tmp6)
    for i in range(n):
        if bodies.inv_mass[i] > 0.0:
            for k in range(4):
                v[i, k] += bodies.gravity_scale[i] * gravity[k] * dt
    return Velocities(v, w, inv_inertia, dL, isotropic)


@njit(**cache)
def _pair_end(key_of, start):
    """The end of the run of contacts from `start` that share its pair of parts (contacts come by key)."""
    end = start
    while end < len(key_of) and key_of[end] == key_of[start]:
        end += 1
    return end


@njit(**cache)
def _approach(start, end, a, b, contacts: Contacts, x, vel: Velocities, options: Options, mus, muk, ra, rb, target,
              mu):
    """The lever arms, approach speed (into contacts.speed), speculative target (close the gap, no more) and
    friction coefficient (static while the point sticks, kinetic while it slides) of the contacts start..end,
    one pair of parts (a, b). The loop copies rows into scratch vectors rather than take row views (each view
    costs two atomic reference counts, more than the arithmetic)."""
    point, normal, depth, speed, v, w = contacts.point, contacts.normal, contacts.depth, contacts.speed, vel.v, vel.w
    dt, stick_speed = options.dt, options.stick_speed
    va = np.empty(4)
    vb = np.empty(4)
    r4 = np.empty(4)
    tmp4 = np.empty(4)
    w6 = np.empty(6)
    for c in range(start, end):
        for kk in range(4):
            ra[c, kk] = point[c, kk] - x[a, kk]
            rb[c, kk] = point[c, kk] - x[b, kk]
            r4[kk] = ra[c, kk]
        _point_velocity(a, r4, v, w, va, w6, tmp4)
        for kk in range(4):
            r4[kk] = rb[c, kk]
        _point_velocity(b, r4, v, w, vb, w6, tmp4)
        vn = 0.0
        for kk in range(4):
            vn += (vb[kk] - va[kk]) * normal[c, kk]
        speed[c] = vn
        gap = max(-depth[c], 0.0)
        target[c] = -gap / dt
        slide = 0.0
        for kk in range(4):
            slide += (vb[kk] - va[kk] - vn * normal[c, kk]) ** 2
        mu[c] = mus if math.sqrt(slide) < stick_speed else muk


@njit(**cache)
def _warm_match(start, end, cursor, contacts: Contacts, previous: Contacts, options: Options, lam, tangent):
    """The impulses of the step before for the contacts start..end (one pair of parts): for each, the nearest
    point of the same pair in `previous` (from `cursor`, its first of the pair) within options.warm_distance in
    b's frame, unless it struck (an impact's impulse is not a load); its tangential impulse turned into this
    step's tangent space."""
    key, local, normal = contacts.key, contacts.local, contacts.normal
    p_key, p_local, p_speed, p_impulse, p_tangent = (previous.key, previous.local, previous.speed, previous.impulse,
                                                     previous.tangent)
    for c in range(start, end):
        best = options.warm_distance * options.warm_distance
        found = -1
        prev = cursor
        while prev < len(p_key) and p_key[prev] == key[c]:
            dd = 0.0
            for kk in range(4):
                dd += (p_local[prev, kk] - local[c, kk]) ** 2
            if dd < best:
                best, found = dd, prev
            prev += 1
        if found >= 0 and p_speed[found] >= -options.bounce_speed:
            lam[c, 0] = p_impulse[found]
            along = 0.0
            for kk in range(4):
                along += p_tangent[found, kk] * normal[c, kk]
            for kk in range(4):
                tangent[c, kk] = p_tangent[found, kk] - along * normal[c, kk]


@njit(**cache)
def _restitution(start, end, e, contacts: Contacts, options: Options, target):
    """When any point of the pair (contacts start..end) closes its gap within this step, every point of the
    pair that approaches faster than bounce_speed (and is no further than the margin) bounces with
    restitution e, so a face striking a face bounces as one whatever rounding does to each point's gap."""
    speed, depth = contacts.speed, contacts.depth
    impact = False
    for c in range(start, end):
        if speed[c] < target[c]:
            impact = True
    if impact:
        for c in range(start, end):
            vn = speed[c]
            if vn < -options.bounce_speed and vn * options.dt - depth[c] < options.margin:
                target[c] = -e * vn


@njit(**cache)
def _jacobians(contacts: Contacts, bodies: Bodies, vel: Velocities, ra, rb):
    """Every row's Jacobian (normal, three tangents: basis, and the lever arms' moments ang), the inverse
    inertia applied to it (inv_ang) and its effective mass, computed once: each solver visit is then a few
    dot products and no allocation."""
    m = len(contacts.a)
    body_a, body_b, normal = contacts.a, contacts.b, contacts.normal
    inv_mass, iso_inv, isotropic, inv_inertia = bodies.inv_mass, bodies.iso_inv, vel.isotropic, vel.inv_inertia
    basis = np.empty((m, 4, 4))
    ang = np.zeros((m, 4, 2, 6))
    inv_ang = np.zeros((m, 4, 2, 6))
    mass = np.empty((m, 4))
    tmp4 = np.empty(4)
    r4 = np.empty(4)
    d4 = np.empty(4)
    tmp6 = np.empty(6)
    for c in range(m):
        a, b = body_a[c], body_b[c]
        _tangent_basis(normal, c, basis, tmp4)
        for d in range(4):
            inv_k = inv_mass[a] + inv_mass[b]
            for side in range(2):
                body = a if side == 0 else b
                if inv_mass[body] == 0.0:
                    continue
                for kk in range(4):
                    r4[kk] = ra[c, kk] if side == 0 else rb[c, kk]
                    d4[kk] = basis[c, d, kk]
                wedge_into(r4, d4, tmp6)
                for i in range(6):
                    ang[c, d, side, i] = tmp6[i]
                for i in range(6):
                    if isotropic[body]:
                        acc = iso_inv[body] * ang[c, d, side, i]
                    else:
                        acc = 0.0
                        for j in range(6):
                            acc += inv_inertia[body, i, j] * ang[c, d, side, j]
                    inv_ang[c, d, side, i] = acc
                    inv_k += ang[c, d, side, i] * acc
            mass[c, d] = 1.0 / inv_k
    return basis, ang, inv_ang, mass


@njit(**cache)
def _warm_start(contacts: Contacts, inv_mass, basis, ang, inv_ang, tangent, lam, vel: Velocities):
    """The tangential impulses carried over (tangent) on this step's tangent rows, then every carried
    impulse applied to the bodies, as the solver would."""
    body_a, body_b, v, w, dL = contacts.a, contacts.b, vel.v, vel.w, vel.dL   # taken once: each costs two atomic counts
    for c in range(len(body_a)):
        a, b = body_a[c], body_b[c]
        for d in range(1, 4):
            acc = 0.0
            for kk in range(4):
                acc += tangent[c, kk] * basis[c, d, kk]
            lam[c, d] = acc
        for d in range(4):
            if lam[c, d] != 0.0:
                _apply_row(c, d, lam[c, d], a, b, basis, ang, inv_ang, inv_mass, v, w, dL)


@njit(**cache)
def rows(contacts: Contacts, previous: Contacts, bodies: Bodies, vel: Velocities, x, options: Options) -> Rows:
    """The solver's rows of this step's contacts (a stage), in the stages Box2D's contact solver has: per pair
    of parts, each point's approach and target (`_approach`), its impulses of the step before (`_warm_match`:
    a point found again in `previous`, same pair, within options.warm_distance in b's frame) and restitution
    once any point of the pair strikes (`_restitution`); then every row's Jacobian (`_jacobians`) and the warm
    start applied (`_warm_start`)."""
    m = len(contacts.a)
    ra = np.empty((m, 4))
    rb = np.empty((m, 4))
    target = np.empty(m)
    mu = np.empty(m)
    lam = np.zeros((m, 4))
    tangent = np.zeros((m, 4))
    # the arrays the loop reads, taken from their tuples once (each taking costs two atomic reference counts)
    key_of, body_a, body_b, p_key = contacts.key, contacts.a, contacts.b, previous.key
    f_static, f_kinetic, restitution = bodies.friction_static, bodies.friction_kinetic, bodies.restitution
    cursor = 0
    start = 0
    while start < m:                                  # one pair of parts at a time
        end = _pair_end(key_of, start)
        a, b = body_a[start], body_b[start]
        mus = math.sqrt(f_static[a] * f_static[b])
        muk = math.sqrt(f_kinetic[a] * f_kinetic[b])
        e = max(restitution[a], restitution[b])
        while cursor < len(p_key) and p_key[cursor] < key_of[start]:
            cursor += 1
        _approach(start, end, a, b, contacts, x, vel, options, mus, muk, ra, rb, target, mu)
        _warm_match(start, end, cursor, contacts, previous, options, lam, tangent)
        if e > 0.0:
            _restitution(start, end, e, contacts, options, target)
        start = end
    basis, ang, inv_ang, mass = _jacobians(contacts, bodies, vel, ra, rb)
    _warm_start(contacts, bodies.inv_mass, basis, ang, inv_ang, tangent, lam, vel)
    return Rows(ra, rb, basis, ang, inv_ang, mass, lam, target, mu)


@njit(**cache)
def solve(contacts: Contacts, rows: Rows, inv_mass, vel: Velocities, iterations):
    """Sequential impulses over the rows, `iterations` passes (a stage): the normal impulse >= 0 toward the
    target, the tangential impulse inside the disc of radius mu * normal impulse; the impulses found are
    written into contacts.impulse and contacts.tangent."""
    m = len(contacts.a)
    basis, ang, inv_ang, k_row, lam = rows.basis, rows.ang, rows.inv_ang, rows.mass, rows.lam
    target, mu, body_a, body_b = rows.target, rows.mu, contacts.a, contacts.b
    v, w, dL = vel.v, vel.w, vel.dL
    rel = np.empty(4)
    for it in range(iterations):
        for c in range(m):
            a, b = body_a[c], body_b[c]
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
    impulse, tangent = contacts.impulse, contacts.tangent
    for c in range(m):
        impulse[c] = lam[c, 0]
        for kk in range(4):
            tangent[c, kk] = lam[c, 1] * basis[c, 1, kk] + lam[c, 2] * basis[c, 2, kk] + lam[c, 3] * basis[c, 3, kk]


@njit(**cache)
def integrate(bodies: Bodies, motion: Motion, vel: Velocities, contacts: Contacts, gravity, dt) -> Motion:
    """The new state (a stage): momentum the old plus the impulses' moments; a body no contact pushed follows
    its parabola exactly, one held moves with its new velocity (symplectic Euler, which keeps resting
    contact still); every body turns by its free rotation flow (`rotate_free`)."""
    n = len(motion.x)
    x = motion.x.copy()
    r = motion.r.copy()
    L = motion.L + vel.dL
    held = np.zeros(n, dtype=np.bool_)
    for c in range(len(contacts.a)):
        if contacts.impulse[c] > 0.0:
            held[contacts.a[c]] = True
            held[contacts.b[c]] = True
    for i in range(n):
        if bodies.inv_mass[i] == 0.0:
            continue
        for k in range(4):
            x[i, k] += dt * vel.v[i, k]
            if not held[i]:
                x[i, k] -= 0.5 * dt * dt * bodies.gravity_scale[i] * gravity[k]
        r[i] = rotate_free(r[i], bodies.axes[i], L[i], bodies.iso_inv[i], bodies.excess[i], dt)
    return Motion(x, vel.v, r, L)


@njit(**cache)
def split_impulse(contacts: Contacts, rows: Rows, inv_mass, motion: Motion, options: Options) -> Motion:
    """Pseudo-velocities that push penetrating bodies apart, moving positions only (a stage): each pass
    aims every point deeper than the slop at baumgarte * excess depth / dt; no velocity, no energy."""
    n = len(motion.x)
    m = len(contacts.a)
    if options.position_iterations == 0 or m == 0:
        return motion
    dt = options.dt
    x, r = motion.x, motion.r
    pv = np.zeros((n, 4))
    pw = np.zeros((n, 6))
    pdl = np.zeros((n, 6))
    plam = np.zeros(m)
    depth, body_a, body_b = contacts.depth, contacts.a, contacts.b
    basis, ang, inv_ang, k_row = rows.basis, rows.ang, rows.inv_ang, rows.mass
    slop, baumgarte = options.slop, options.baumgarte
    for it in range(options.position_iterations):
        for c in range(m):
            excess_depth = depth[c] - slop
            if excess_depth <= 0.0:
                continue
            a, b = body_a[c], body_b[c]
            vn = _row_velocity(c, 0, a, b, basis, ang, pv, pw)
            old = plam[c]
            new = max(old + k_row[c, 0] * (baumgarte * excess_depth / dt - vn), 0.0)
            plam[c] = new
            if new != old:
                _apply_row(c, 0, new - old, a, b, basis, ang, inv_ang, inv_mass, pv, pw, pdl)
    turn_by = np.empty((4, 4))
    for i in range(n):
        if inv_mass[i] > 0.0 and (pv[i].any() or pw[i].any()):
            x[i] += dt * pv[i]
            exp_into(pw[i] * dt, turn_by)
            r[i] = renormalize(turn_by @ r[i])
    return Motion(x, motion.v, r, motion.L)


@njit(**cache)
def step(bodies, parts, motion, gravity, options, impulses, previous):
    """One step: the state in, the new state and this step's contacts out, stage by stage (module doc).

    bodies, parts, motion, options, previous: `Bodies`, `Parts`, `Motion`, `Options`, `Contacts`, or plain
    tuples of their fields (Python calls with plain tuples: numba dispatches those several times faster).
    impulses: (K, 9) rows [body, point (4, world), impulse (4)] applied at the start (the hand's push).
    previous: the contacts of the step before (warm start: a point found again starts from its impulses,
    so a stack's solution carries over from step to step instead of being found anew).
    Returns the new (x, v, r, L) and the contacts' fields, as plain tuples (`Motion`, `Contacts` order).
    """
    bodies, parts, motion, options, previous = (Bodies(*bodies), Parts(*parts), Motion(*motion), Options(*options),
                                                Contacts(*previous))
    dt = options.dt
    vel = velocities(bodies, motion, impulses, gravity, dt)
    placed = place_parts(parts, motion.x, motion.r)
    contacts = collide(parts, placed, bodies.inv_mass > 0.0, motion.x, motion.r, options.margin)
    solver = rows(contacts, previous, bodies, vel, motion.x, options)
    solve(contacts, solver, bodies.inv_mass, vel, options.iterations)
    moved = split_impulse(contacts, solver, bodies.inv_mass, integrate(bodies, motion, vel, contacts, gravity, dt),
                          options)
    c = contacts
    return ((moved.x, moved.v, moved.r, moved.L),
            (c.a, c.b, c.point, c.normal, c.depth, c.impulse, c.tangent, c.speed, c.key, c.local))


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

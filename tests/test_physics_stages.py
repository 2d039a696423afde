"""Each stage of the physics step on its own, against closed forms: velocities, part transforms, collide,
rows, solve, integrate, split impulse (touch4d.physics.kernels, touch4d.physics.collide)."""
import numpy as np
import pytest

from touch4d.geometry.rotation import plane_rotation
from touch4d.physics import kernels
from touch4d.physics.arrays import Contacts, Motion, no_contacts
from touch4d.physics.bivector import wedge
from touch4d.physics.collide import collide, place_parts
from touch4d.physics.world import from_data

pytestmark = pytest.mark.timeout(600)     # the first test may compile the stages (numba; cached afterwards)

A = 0.2                                   # the boxes' edge
MASS = A ** 4                             # density 1
I0 = MASS * A * A / 6                     # a tesseract's plane inertia (isotropic)


def two_boxes(gap: float, g=(0, 0, 0, 0), restitution=0.0, static_a=False):
    """Two tesseracts of edge A on the x axis, faces `gap` apart (negative: overlapping)."""
    a = {"name": "a", "shape": "tesseract", "size": A, "position": [-(A + gap) / 2, 0, 0, 1],
         "physics": {"restitution": restitution, "static": static_a}}
    b = {"name": "b", "shape": "tesseract", "size": A, "position": [(A + gap) / 2, 0, 0, 1],
         "physics": {"restitution": restitution}}
    return from_data({"physics": {"gravity": list(g)}, "objects": [a, b]})


def motion(state, v=None):
    return Motion(state.x, state.v if v is None else np.asarray(v, dtype=float), state.r, state.L)


def test_velocities_apply_an_impulse_and_gravity():
    world, state = two_boxes(1.0, g=(0, -9.81, 0, 0))
    r = np.array([0.05, 0.02, -0.03, 0.04])
    p = np.array([0.0, 0.001, 0.002, -0.0005])
    impulses = np.r_[1.0, state.x[1] + r, p][None]
    vel = kernels.velocities(world.bodies, motion(state), impulses, world.gravity, world.dt)
    np.testing.assert_allclose(vel.v[1], p / MASS + world.gravity * world.dt, rtol=1e-12)
    np.testing.assert_allclose(vel.dL[1], wedge(r, p), rtol=1e-12)
    np.testing.assert_allclose(vel.w[1], wedge(r, p) / I0, rtol=1e-9)          # isotropic: w = L / I0
    np.testing.assert_allclose(vel.v[0], world.gravity * world.dt, rtol=1e-12)
    assert vel.isotropic.all()


def test_place_parts_turns_and_moves_every_part():
    world, state = two_boxes(1.0)
    r = plane_rotation("xw", 0.4) @ plane_rotation("yz", -0.2)
    x = np.array([[0.1, 0.2, 0.3, 0.4], [-1.0, 0.5, 0.0, 2.0]])
    placed = place_parts(world.parts, x, np.stack([r, np.eye(4)]))
    p = world.parts
    first = slice(p.v_start[0], p.v_start[0] + p.v_count[0])
    np.testing.assert_allclose(placed.verts[first], p.verts[first] @ r.T + x[0], atol=1e-15)
    cells = slice(p.c_start[0], p.c_start[0] + p.c_count[0])
    np.testing.assert_allclose(placed.normals[cells], p.normals[cells] @ r.T, atol=1e-15)
    np.testing.assert_allclose(placed.offsets[cells], p.offsets[cells] + placed.normals[cells] @ x[0], atol=1e-15)
    # every placed vertex lies on or inside every placed cell of its part
    assert (placed.verts[first] @ placed.normals[cells].T <= placed.offsets[cells] + 1e-12).all()


def test_collide_two_boxes_face_to_face():
    world, state = two_boxes(-0.01)                             # overlapping by 0.01 along x
    placed = place_parts(world.parts, state.x, state.r)
    c = collide(world.parts, placed, world.inv_mass > 0, state.x, state.r, world.options.margin)
    assert len(c.a) >= 4 and c.a.dtype == np.int64 and set(c.a) == {0} and set(c.b) == {1}
    np.testing.assert_allclose(c.normal, np.tile([1.0, 0, 0, 0], (len(c.a), 1)), atol=1e-12)
    np.testing.assert_allclose(c.depth, 0.01, atol=1e-12)
    assert np.all(np.abs(c.point[:, 1:] - [0, 0, 1]) <= A / 2 + 1e-12)          # on the touching faces
    assert np.all(np.abs(c.point[:, 0]) <= 0.005 + 1e-12)
    # apart by more than the margin: nothing
    world, state = two_boxes(2 * world.options.margin)
    placed = place_parts(world.parts, state.x, state.r)
    assert len(collide(world.parts, placed, world.inv_mass > 0, state.x, state.r, world.options.margin).a) == 0


def one_point(gap: float, speed: float, **kwargs):
    """A single contact point through both centres (no lever arm), b approaching a along x at `speed`."""
    world, state = two_boxes(gap, **kwargs)
    c = no_contacts(1)
    c.a[0], c.b[0] = 0, 1
    c.normal[0] = [1, 0, 0, 0]
    c.depth[0] = -gap
    c.point[0] = [state.x[0, 0] + A / 2, 0, 0, 1]
    v = np.zeros((2, 4))
    v[1, 0] = -speed
    vel = kernels.velocities(world.bodies, motion(state, v), np.zeros((0, 9)), world.gravity, world.dt)
    return world, state, c, vel


def test_rows_target_the_gap_or_the_bounce():
    world, state, c, vel = one_point(0.01, 1.0)                 # 0.01 apart at 1/s: not this step (dt 1 ms)
    rows = kernels.rows(c, no_contacts(), world.bodies, vel, state.x, world.options)
    assert c.speed[0] == pytest.approx(-1.0) and rows.target[0] == pytest.approx(-0.01 / world.dt)
    assert rows.mass[0, 0] == pytest.approx(MASS / 2)           # 1 / (1/m + 1/m): no lever arm
    world, state, c, vel = one_point(0.0005, 1.0, restitution=0.5)    # closes within this step: bounces
    rows = kernels.rows(c, no_contacts(), world.bodies, vel, state.x, world.options)
    assert rows.target[0] == pytest.approx(0.5)


def test_solve_reaches_the_target_and_keeps_momentum():
    world, state, c, vel = one_point(0.0005, 1.0, restitution=1.0)
    rows = kernels.rows(c, no_contacts(), world.bodies, vel, state.x, world.options)
    kernels.solve(c, rows, world.inv_mass, vel, world.options.iterations)
    np.testing.assert_allclose(vel.v[:, 0], [-1.0, 0.0], atol=1e-12)          # equal masses exchange
    assert c.impulse[0] == pytest.approx(MASS) and np.abs(c.tangent).max() < 1e-18


def test_integrate_free_parabola_and_held_body():
    world, state = two_boxes(1.0, g=(0, -9.81, 0, 0))
    v0 = np.array([[0.3, 0.0, 0.1, 0.0], [0.0, 0.2, 0.0, -0.1]])
    vel = kernels.velocities(world.bodies, motion(state, v0), np.zeros((0, 9)), world.gravity, world.dt)
    dt, g = world.dt, world.gravity
    c = no_contacts(1)
    c.a[0], c.b[0], c.impulse[0] = 1, 1, 1.0                   # body 1 held by a contact, body 0 free
    moved = kernels.integrate(world.bodies, motion(state, v0), vel, c, g, dt)
    np.testing.assert_allclose(moved.x[0], state.x[0] + v0[0] * dt + 0.5 * g * dt * dt, atol=1e-15)
    np.testing.assert_allclose(moved.x[1], state.x[1] + (v0[1] + g * dt) * dt, atol=1e-15)
    np.testing.assert_allclose(moved.r, state.r, atol=1e-15)                    # no spin: no turn


def test_split_impulse_moves_positions_only():
    world, state = two_boxes(-0.002, static_a=True)
    placed = place_parts(world.parts, state.x, state.r)
    c = collide(world.parts, placed, world.inv_mass > 0, state.x, state.r, world.options.margin)
    vel = kernels.velocities(world.bodies, motion(state), np.zeros((0, 9)), world.gravity, world.dt)
    rows = kernels.rows(c, no_contacts(), world.bodies, vel, state.x, world.options)
    before = Motion(state.x.copy(), state.v.copy(), state.r.copy(), state.L.copy())
    o = world.options._replace(position_iterations=60)       # passes enough to converge over the face's points
    after = kernels.split_impulse(c, rows, world.inv_mass, before, o)
    push = after.x[1] - state.x[1]
    # a box on a face pushed out along the normal by baumgarte * (depth - slop), its own passes converged
    np.testing.assert_allclose(push, [o.baumgarte * (0.002 - o.slop), 0, 0, 0], rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(after.x[0], state.x[0])                       # static
    np.testing.assert_array_equal(after.v, state.v)
    np.testing.assert_allclose(after.r[1], state.r[1], atol=1e-9)


def test_the_stages_make_the_step():
    world, state = two_boxes(-0.001, g=(0, -9.81, 0, 0), restitution=0.3)
    state = state.__class__(0.0, 0, state.x, np.array([[0.5, 0, 0, 0], [-0.5, 0, 0, 0]]), state.r, state.L)
    m, contacts = kernels.step(world.bodies, world.parts, motion(state), world.gravity, world.options,
                               np.zeros((0, 9)), no_contacts())
    m, contacts = Motion(*m), Contacts(*contacts)
    assert len(contacts.a) > 0 and contacts.a.dtype == np.int64
    # the bodies swap momentum symmetrically: total momentum kept (gravity aside), no spin
    np.testing.assert_allclose(MASS * (m.v.sum(axis=0) - 2 * world.gravity * world.dt), 0, atol=1e-15)
    assert m.v[0, 0] < 0 < m.v[1, 0]


def contacts_at(local, key=7, speed=0.0, impulse=0.0, tangent=(0.0, 0.0, 0.0, 0.0), normal=(1.0, 0.0, 0.0, 0.0)):
    """Contacts of one pair of parts (key), one per row of `local` (in b's frame), all alike but there."""
    c = no_contacts(len(local))
    c.local[:] = local
    c.key[:] = key
    c.speed[:] = speed
    c.impulse[:] = impulse
    c.tangent[:] = tangent
    c.normal[:] = normal
    return c


def test_warm_match_carries_the_nearest_previous_point_within_reach_and_never_an_impacts_impulse():
    world, _ = two_boxes(0.0)
    o = world.options._replace(warm_distance=0.01, bounce_speed=0.5)
    now = contacts_at([[0.0, 0.0, 0.0, 0.0]])
    near, nearer, far = [0.008, 0, 0, 0], [0, 0.004, 0, 0], [0.02, 0, 0, 0]
    before = contacts_at([far, near, nearer], impulse=0.0, tangent=(0.3, 0.1, -0.2, 0.0))
    before.impulse[:] = [1.0, 2.0, 3.0]
    lam, tangent = np.zeros((1, 4)), np.zeros((1, 4))
    kernels._warm_match(0, 1, 0, now, before, o, lam, tangent)
    assert lam[0, 0] == 3.0                                     # the nearest of those within reach
    np.testing.assert_array_equal(tangent[0], [0.0, 0.1, -0.2, 0.0])     # along the normal removed
    struck = contacts_at([nearer], impulse=3.0, speed=-0.6)     # it approached faster than bounce_speed
    lam[:] = 0.0
    kernels._warm_match(0, 1, 0, now, struck, o, lam, tangent * 0)
    assert lam[0, 0] == 0.0
    other_pair = contacts_at([nearer], key=8, impulse=3.0)
    kernels._warm_match(0, 1, 0, now, other_pair, o, lam, tangent * 0)
    assert lam[0, 0] == 0.0


def test_restitution_bounces_every_fast_point_of_a_pair_once_one_strikes():
    world, _ = two_boxes(0.0)
    o = world.options._replace(bounce_speed=0.5, margin=0.01)
    c = contacts_at(np.zeros((3, 4)))
    c.speed[:] = [-2.0, -1.0, -0.2]              # the last approaches slower than bounce_speed
    c.depth[:] = [0.0, -0.005, -0.001]
    target = np.array([-0.1, -10.0, -10.0])      # only the first closes its gap within the step
    kernels._restitution(0, 3, 0.5, c, o, target)
    np.testing.assert_array_equal(target, [1.0, 0.5, -10.0])
    target = np.array([-10.0, -10.0, -10.0])     # none strikes: the speculative targets stay
    kernels._restitution(0, 3, 0.5, c, o, target)
    np.testing.assert_array_equal(target, [-10.0, -10.0, -10.0])


def test_reduce_keeps_the_deepest_then_the_farthest_across_the_normal():
    from touch4d.physics.collide import MAX_POINTS, _reduce

    n = np.array([0.0, 1.0, 0.0, 0.0])
    count = MAX_POINTS + 8
    cand = np.zeros((count, 4))
    cand[:, 0] = np.arange(count) * 0.1                  # along x, across the normal
    cand[:, 1] = 5.0 * np.arange(count)                  # along the normal: no distance across it
    depth = np.full(count, 0.01)
    depth[6] = 0.05
    keep = np.ones(count, dtype=np.bool_)
    keep[3] = False
    out_pts, out_depth = np.empty((MAX_POINTS, 4)), np.empty(MAX_POINTS)
    got = _reduce(cand, depth, keep, count, count - 1, n, out_pts, out_depth)
    assert got == MAX_POINTS and out_depth[0] == 0.05 and out_pts[0, 0] == pytest.approx(0.6)
    assert out_pts[1, 0] == pytest.approx((count - 1) * 0.1)     # the farthest from the deepest, across n
    assert out_pts[2, 0] == 0.0                                  # then the farthest from both
    assert 0.3 not in np.round(out_pts[:, 0], 9)                 # a point not kept is never chosen
    few = np.zeros(count, dtype=np.bool_)
    few[[2, 5]] = True
    assert _reduce(cand, depth, few, count, 2, n, out_pts, out_depth) == 2
    np.testing.assert_allclose(out_pts[:2, 0], [0.2, 0.5])

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

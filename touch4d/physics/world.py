"""A fixed-step 4D rigid-body world: constants (`World`), state (`State`), and `step(world, state)`.

`step` is a pure function: the same world, state and impulses give bit-identical new states (no clock,
no randomness, contacts and solver visited in a fixed order). A body's state is its centre of mass
`x`, velocity `v`, orientation `r` (the scene object's orientation: world = r (size local) + position)
and world angular momentum `L` (a bivector: what a free body keeps exactly; its angular velocity is
`angular_velocity(world, state)`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from touch4d.geometry import tolerance
from touch4d.geometry.scene import Scene

from . import arrays, bivector, kernels
from .config import ObjectPhysics, PhysicsConfig, ScenePhysics
from .inertia import mass_properties


@dataclass(frozen=True)
class Contacts:
    """The contact points of one step (one entry each): bodies a, b; point (4,); normal (4,) from a to b;
    depth (> 0 penetrating); normal impulse; tangential impulse (4,); approach speed before the step
    (normal relative velocity, < 0 closing)."""

    entries: arrays.Contacts

    def __len__(self) -> int:
        return len(self.entries.a)

    a = property(lambda self: self.entries.a)
    b = property(lambda self: self.entries.b)
    points = property(lambda self: self.entries.point)
    normals = property(lambda self: self.entries.normal)
    depth = property(lambda self: self.entries.depth)
    impulse = property(lambda self: self.entries.impulse)
    tangent_impulse = property(lambda self: self.entries.tangent)
    speed = property(lambda self: self.entries.speed)


# The solver's constants, in screen units (one unit is 250 mm with the default glove and calibration) and s.
BAUMGARTE = 0.2            # fraction of the penetration beyond the slop removed per step (split impulse)
BOUNCE_SPEED = 0.05        # units/s (12.5 mm/s): slower approaches do not bounce; at least 4 |g| dt, so a body
                           # resting under gravity does not
STICK_SPEED = 0.002        # units/s (0.5 mm/s): a point sliding slower sticks (static friction); at least 2 |g| dt
WARM_DISTANCE = 0.005      # units (1.25 mm): a contact point moved less than this in its body's frame is the same


@dataclass(frozen=True, eq=False)
class World:
    """Everything a step needs that does not change: bodies' mass properties, shapes, materials, options."""

    names: tuple[str, ...]
    sizes: np.ndarray            # (N,) object sizes
    centers: np.ndarray          # (N, 4) centre of mass in the object's scaled local frame
    mass: np.ndarray             # (N,) inf for static bodies
    inv_mass: np.ndarray         # (N,) 0 for static bodies
    axes: np.ndarray             # (N, 4, 4) principal axes (columns, local frame)
    plane_inertia: np.ndarray    # (N, 6) principal plane inertias (0 for static bodies)
    inv_plane: np.ndarray        # (N, 6)
    iso_inv: np.ndarray          # (N,) 1 / I0 (mean plane inertia)
    excess: np.ndarray           # (N, 6) 1 / I_ab - 1 / I0, exactly 0 where the inertia is isotropic
    gravity_scale: np.ndarray    # (N,)
    friction_static: np.ndarray
    friction_kinetic: np.ndarray
    restitution: np.ndarray
    parts: arrays.Parts          # every body's convex parts, flat
    gravity: np.ndarray          # (4,)
    dt: float
    options: arrays.Options

    @cached_property
    def step_constants(self) -> tuple[tuple, tuple, tuple]:
        """bodies, parts, options as plain tuples, as `kernels.step` is called (numba dispatches those fast)."""
        return tuple(self.bodies), tuple(self.parts), tuple(self.options)

    @cached_property
    def bodies(self) -> arrays.Bodies:
        """The bodies' constants as the step's stages take them."""
        return arrays.Bodies(self.inv_mass, self.axes, self.inv_plane, self.iso_inv, self.excess, self.gravity_scale,
                             self.friction_static, self.friction_kinetic, self.restitution)

    @property
    def static(self) -> np.ndarray:
        return self.inv_mass == 0.0

    def index(self, name: str) -> int:
        return self.names.index(name)


@dataclass(frozen=True, eq=False)
class State:
    """Time, step count, every body's x (N, 4), v (N, 4), r (N, 4, 4), L (N, 6), and the last step's contacts
    (their impulses start the next step's solver)."""

    time: float
    steps: int
    x: np.ndarray
    v: np.ndarray
    r: np.ndarray
    L: np.ndarray
    contacts: arrays.Contacts = field(default_factory=arrays.no_contacts)

    def digest(self) -> bytes:
        """The state's exact bytes (for determinism checks and replays)."""
        return b"".join(np.ascontiguousarray(a).tobytes() for a in (self.x, self.v, self.r, self.L, *self.contacts))


def from_data(data: dict, **kwargs) -> tuple[World, State]:
    """The world of a scene given as the mapping a scene file holds (for scripts and tests)."""
    from touch4d.geometry.scene import parse_scene

    from .config import parse_physics

    return build_world(parse_scene(data), parse_physics(data), **kwargs)


def build_world(scene: Scene, physics: PhysicsConfig | None = None, *, rate: float | None = None,
                iterations: int | None = None) -> tuple[World, State]:
    """The world and initial state of a scene (objects in order) with its physics (defaults when None)."""
    physics = physics or PhysicsConfig(ScenePhysics(), [])
    settings = physics.scene
    n = len(scene.objects)
    specs = [physics.objects[i] if i < len(physics.objects) else ObjectPhysics() for i in range(n)]
    names, sizes, centers, masses, axes, planes = [], np.zeros(n), np.zeros((n, 4)), np.zeros(n), [], np.zeros((n, 6))
    part_rows = []
    x, v, r, L = np.zeros((n, 4)), np.zeros((n, 4)), np.zeros((n, 4, 4)), np.zeros((n, 6))
    for i, (obj, spec) in enumerate(zip(scene.objects, specs)):
        names.append(obj.name)
        sizes[i] = obj.size
        local = [p.transformed(None, None, obj.size) for p in obj.local_parts()]
        props = mass_properties(local, mass=spec.mass, density=spec.density)
        centers[i] = props.center
        r[i] = obj.orientation
        x[i] = obj.position + obj.orientation @ props.center
        if spec.static:
            masses[i] = np.inf
            axes.append(np.eye(4))
        else:
            masses[i] = props.mass
            axes.append(props.axes)
            planes[i] = props.plane_inertia
            v[i] = spec.velocity
            w = np.radians(bivector.from_planes(spec.angular_velocity))
            c = bivector.compound(obj.orientation @ props.axes)
            L[i] = c @ (planes[i] * (c.T @ w))
        for poly in local:
            dirs, spans = edge_face_directions(poly)
            part_rows.append((i, poly.vertices - props.center, poly.normals, poly.offsets - poly.normals @ props.center,
                              poly.edges, dirs, spans, tolerance.size(poly.vertices)))
    dynamic = np.isfinite(masses)
    inv_mass = np.where(dynamic, 1.0 / np.where(dynamic, masses, 1.0), 0.0)
    inv_plane = np.where(planes > 0, 1.0 / np.where(planes > 0, planes, 1.0), 0.0)
    mean = planes.mean(axis=1)
    iso_inv = np.where(mean > 0, 1.0 / np.where(mean > 0, mean, 1.0), 0.0)
    excess = inv_plane - iso_inv[:, None]
    excess[np.abs(planes - mean[:, None]) <= 1e-9 * mean[:, None]] = 0.0     # isotropic: turns exactly
    excess[~dynamic] = 0.0
    friction = np.array([s.friction_pair for s in specs]).reshape(n, 2)
    dt = 1.0 / (rate or settings.rate)
    g = float(np.linalg.norm(settings.gravity))
    options = arrays.Options(dt=dt, iterations=int(iterations or settings.iterations),
                             position_iterations=int(settings.position_iterations), margin=float(settings.margin),
                             slop=float(settings.slop), baumgarte=BAUMGARTE, bounce_speed=max(BOUNCE_SPEED, 4.0 * g * dt),
                             stick_speed=max(STICK_SPEED, 2.0 * g * dt), warm_distance=WARM_DISTANCE)
    world = World(
        names=tuple(names), sizes=sizes, centers=centers, mass=masses, inv_mass=inv_mass,
        axes=np.array(axes).reshape(n, 4, 4), plane_inertia=planes, inv_plane=inv_plane, iso_inv=iso_inv,
        excess=excess, gravity_scale=np.ones(n), friction_static=friction[:, 0].copy(),
        friction_kinetic=friction[:, 1].copy(), restitution=np.array([s.restitution for s in specs], dtype=float),
        parts=_flatten(part_rows), gravity=np.array(settings.gravity, dtype=float), dt=dt, options=options,
    )
    return world, State(0.0, 0, x, v, r, L)


def _flatten(rows) -> arrays.Parts:
    """The parts as flat arrays (edges by global vertex index)."""
    body = np.array([row[0] for row in rows], dtype=np.int64)
    vc = np.array([len(row[1]) for row in rows], dtype=np.int64)
    cc = np.array([len(row[2]) for row in rows], dtype=np.int64)
    ec = np.array([len(row[4]) for row in rows], dtype=np.int64)
    starts = lambda counts: np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64)   # noqa: E731
    vs, cs, es = starts(vc), starts(cc), starts(ec)
    verts = np.ascontiguousarray(np.concatenate([row[1] for row in rows]))
    normals = np.ascontiguousarray(np.concatenate([row[2] for row in rows]))
    offsets = np.ascontiguousarray(np.concatenate([row[3] for row in rows]))
    edges = np.ascontiguousarray(np.concatenate([np.asarray(row[4], dtype=np.int64) + s for row, s in zip(rows, vs)]))
    dc = np.array([len(row[5]) for row in rows], dtype=np.int64)
    fc = np.array([len(row[6]) for row in rows], dtype=np.int64)
    dirs = np.ascontiguousarray(np.concatenate([row[5] for row in rows]).reshape(-1, 4))
    spans = np.ascontiguousarray(np.concatenate([row[6] for row in rows]).reshape(-1, 2, 4))
    size = np.array([row[7] for row in rows], dtype=np.float64)
    return arrays.Parts(body, vs, vc, cs, cc, es, ec, verts, normals, offsets, edges, starts(dc), dc, dirs, starts(fc), fc,
                        spans, size)


MAX_EDGE_DIRECTIONS = 32      # parts with more distinct edge directions (or 2-face planes, below) are
MAX_FACE_PLANES = 64          # separated by their cells only: the edge x face axes would cost too much


def edge_face_directions(poly) -> tuple[np.ndarray, np.ndarray]:
    """A convex part's distinct edge directions (D, 4) and 2-face planes (F, 2, 4) (the polytope's), for the
    edge x 2-face separating axes; empty when there are too many."""
    dirs, spans = poly.edge_directions, poly.face_planes
    if len(dirs) > MAX_EDGE_DIRECTIONS or len(spans) > MAX_FACE_PLANES:
        return np.zeros((0, 4)), np.zeros((0, 2, 4))
    return dirs, spans


NO_IMPULSES = np.zeros((0, 9))


def step(world: World, state: State, impulses: np.ndarray | None = None) -> tuple[State, Contacts]:
    """The state one fixed step (world.dt) later, and that step's contacts.

    impulses: optional (K, 9) rows [body, point (4, world), impulse (4)] applied at the step's start
    (the hand's push)."""
    imp = NO_IMPULSES if impulses is None or len(impulses) == 0 else np.ascontiguousarray(impulses, dtype=np.float64)
    motion, contacts = kernels.step(*world.step_constants[:2], (state.x, state.v, state.r, state.L), world.gravity,
                                    world.step_constants[2], imp, tuple(state.contacts))
    contacts = arrays.Contacts(*contacts)
    return State((state.steps + 1) * world.dt, state.steps + 1, *motion, contacts), Contacts(contacts)


def run(world: World, state: State, steps: int) -> State:
    """`steps` steps with no external input."""
    for _ in range(steps):
        state, _ = step(world, state)
    return state


# ---- what the state means -------------------------------------------------------------------------


def angular_velocity(world: World, state: State) -> np.ndarray:
    """(N, 6) world angular velocities (radians per second, by plane)."""
    return kernels.angular_velocities(state.r, state.L, world.axes, world.inv_plane)


def object_positions(world: World, state: State) -> np.ndarray:
    """(N, 4) scene-object positions (world = r (size local) + position)."""
    return state.x - np.einsum("nij,nj->ni", state.r, world.centers)


def energy(world: World, state: State) -> float:
    """Kinetic plus gravitational potential energy of the dynamic bodies."""
    dyn = ~world.static
    m = world.mass[dyn]
    kinetic = 0.5 * np.sum(m * np.sum(state.v[dyn] ** 2, axis=1))
    rotational = 0.5 * np.sum(angular_velocity(world, state)[dyn] * state.L[dyn])
    potential = -np.sum(m * (state.x[dyn] @ world.gravity))
    return float(kinetic + rotational + potential)


def angular_momentum(world: World, state: State) -> np.ndarray:
    """(6,) total angular momentum about the origin: spin plus m x ^ v of every dynamic body."""
    dyn = ~world.static
    orbital = world.mass[dyn, None] * bivector.wedge(state.x[dyn], state.v[dyn])
    return state.L[dyn].sum(axis=0) + orbital.sum(axis=0)


def with_pose(world: World, state: State, index: int, position=None, orientation=None, velocity=None,
              angular_velocity_world=None) -> State:
    """The state with one body placed (object position / orientation) or set moving; others untouched."""
    x, v, r, L = state.x.copy(), state.v.copy(), state.r.copy(), state.L.copy()
    if orientation is not None:
        r[index] = orientation
    if position is not None or orientation is not None:
        pos = object_positions(world, state)[index] if position is None else np.asarray(position, dtype=float)
        x[index] = pos + r[index] @ world.centers[index]
    if velocity is not None:
        v[index] = velocity
    if angular_velocity_world is not None and not world.static[index]:
        c = bivector.compound(r[index] @ world.axes[index])
        L[index] = c @ (world.plane_inertia[index] * (c.T @ np.asarray(angular_velocity_world, dtype=float)))
    moved = position is not None or orientation is not None      # a moved body's contacts are found anew
    return replace(state, x=x, v=v, r=r, L=L, contacts=arrays.no_contacts() if moved else state.contacts)

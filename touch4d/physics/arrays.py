"""The physics step's data, as named tuples of arrays (numba compiles them as it does plain arrays): what a
stage takes and gives is named, not a position in a long argument list.

Units: screen units (the screen spans [-1, 1]^3; with the default glove and calibration, `screen_edge_m`
0.5 m over 2 units, one screen unit is 250 mm), seconds, kilograms per unit 4-volume as the scene's density.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Bodies(NamedTuple):
    """What does not change of every body (N of them)."""

    inv_mass: np.ndarray          # (N,) 0 for a static body
    axes: np.ndarray              # (N, 4, 4) principal axes (columns, body frame)
    inv_plane: np.ndarray         # (N, 6) 1 / principal plane inertia (0 for a static body)
    iso_inv: np.ndarray           # (N,) 1 / I0, the mean plane inertia
    excess: np.ndarray            # (N, 6) 1 / I_ab - 1 / I0, exactly 0 where the inertia is isotropic
    gravity_scale: np.ndarray     # (N,)
    friction_static: np.ndarray   # (N,)
    friction_kinetic: np.ndarray  # (N,)
    restitution: np.ndarray       # (N,)


class Parts(NamedTuple):
    """Every body's convex parts (P of them) in the body's frame (centre of mass at 0), flat: part p's
    vertices are verts[v_start[p]:v_start[p] + v_count[p]], and so on."""

    body: np.ndarray              # (P,) int64, the body of each part
    v_start: np.ndarray           # (P,) int64 vertices
    v_count: np.ndarray
    c_start: np.ndarray           # (P,) int64 cells (normals, offsets)
    c_count: np.ndarray
    e_start: np.ndarray           # (P,) int64 edges
    e_count: np.ndarray
    verts: np.ndarray             # (V, 4)
    normals: np.ndarray           # (C, 4) unit, outward
    offsets: np.ndarray           # (C,) n.x <= offset
    edges: np.ndarray             # (E, 2) int64, indices into verts
    d_start: np.ndarray           # (P,) int64 edge directions
    d_count: np.ndarray
    dirs: np.ndarray              # (D, 4)
    f_start: np.ndarray           # (P,) int64 2-face planes
    f_count: np.ndarray
    spans: np.ndarray             # (F, 2, 4) two orthonormal vectors spanning each plane
    size: np.ndarray              # (P,) the part's size (`geometry.tolerance.size`), which scales the tolerances


class Placed(NamedTuple):
    """The parts' geometry in the world, this step (the moving arrays of `Parts`)."""

    verts: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    dirs: np.ndarray
    spans: np.ndarray


class Motion(NamedTuple):
    """Every body's state: centre of mass x (N, 4), velocity v (N, 4), orientation r (N, 4, 4) and world
    angular momentum L (N, 6)."""

    x: np.ndarray
    v: np.ndarray
    r: np.ndarray
    L: np.ndarray


class Options(NamedTuple):
    """The solver's settings (`world.build_world` sets them from the scene and the constants there)."""

    dt: float                     # s
    iterations: int               # velocity passes
    position_iterations: int      # split-impulse passes
    margin: float                 # screen units: contacts are made this far apart (speculative)
    slop: float                   # screen units: penetration left alone
    baumgarte: float              # fraction of the penetration beyond the slop removed per step
    bounce_speed: float           # screen units/s: slower approaches do not bounce
    stick_speed: float            # screen units/s: slower sliding sticks (static friction)
    warm_distance: float          # screen units: a point moved less than this (body frame) is found again


class Contacts(NamedTuple):
    """The contact points of one step, one entry each; `key` (the pair of parts) and `local` (the point in
    body b's frame) find a point again in the next step, whose impulses then start from this step's."""

    a: np.ndarray                 # (K,) int64 bodies
    b: np.ndarray
    point: np.ndarray             # (K, 4) world
    normal: np.ndarray            # (K, 4) unit, from a to b
    depth: np.ndarray             # (K,) > 0 penetrating
    impulse: np.ndarray           # (K,) normal impulse
    tangent: np.ndarray           # (K, 4) tangential impulse
    speed: np.ndarray             # (K,) normal relative velocity before the step (< 0 closing)
    key: np.ndarray               # (K,) int64 pair of parts: part_a * P + part_b
    local: np.ndarray             # (K, 4) the point in body b's frame


def no_contacts(count: int = 0) -> Contacts:
    """`count` contact entries, all zero (none: the state before the first step)."""
    return Contacts(np.zeros(count, np.int64), np.zeros(count, np.int64), np.zeros((count, 4)), np.zeros((count, 4)),
                    np.zeros(count), np.zeros(count), np.zeros((count, 4)), np.zeros(count),
                    np.zeros(count, np.int64), np.zeros((count, 4)))


class Velocities(NamedTuple):
    """The bodies' velocities while the step solves: linear v (N, 4), angular w (N, 6), the world inverse
    inertia (N, 6, 6), the momentum the impulses have added dL (N, 6), and which bodies are isotropic."""

    v: np.ndarray
    w: np.ndarray
    inv_inertia: np.ndarray
    dL: np.ndarray
    isotropic: np.ndarray


class Rows(NamedTuple):
    """The solver's rows, one set of four (normal, three tangents) per contact point: Jacobians with the
    inverse inertia applied, computed once a step, and what each row aims at."""

    ra: np.ndarray                # (K, 4) the point from a's and b's centre of mass
    rb: np.ndarray
    basis: np.ndarray             # (K, 4, 4) n, t1, t2, t3
    ang: np.ndarray               # (K, 4, 2, 6) r_a ^ d, r_b ^ d
    inv_ang: np.ndarray           # (K, 4, 2, 6) I^-1 (r ^ d) per body
    mass: np.ndarray              # (K, 4) effective mass of each row
    lam: np.ndarray               # (K, 4) accumulated impulses along the rows
    target: np.ndarray            # (K,) the normal relative velocity aimed at
    mu: np.ndarray                # (K,) friction coefficient (static or kinetic)

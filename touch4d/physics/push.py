"""The hand pushes what it feels: impulses from the tactile stimulus, so touch and motion agree.

The hand lives in the screen (the hyperplane w = 0) and feels, at each sample c_i, the object its ray
along +w enters first, at distance l_i, with the stimulus h_i of paper eq. 1-2. It pushes with the same
rays: when the hand moves at u (in the screen's x, y, z), each touched sample presses the point it feels,
q_i = (c_i, l_i), along u, by the share h_i / sum_j h_j of that object's stimulus. Per step the object's
velocity at those points along u is brought toward u at `rate` (1 / s): a push (never a pull) that moves
the object as fast as the hand advances into it, spread over the hand exactly as the glove renders it.
So where the hand feels more it pushes more, where it feels nothing it pushes nothing, and a hand held
still holds nothing back and adds nothing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import bivector
from .world import State, World


@dataclass(frozen=True)
class Touch:
    """What the hand touches at one pose: points q_i (K, 4), the object of each (K,), their weights
    (K,; h_i / sum of h over that object's points) and the hand's velocity (3,) in screen units / s."""

    points: np.ndarray
    objects: np.ndarray
    weights: np.ndarray
    velocity: np.ndarray

    @classmethod
    def none(cls) -> "Touch":
        return cls(np.zeros((0, 4)), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(3))


def touch_from_stimulus(positions3, l, hit, h, velocity3, perspective_eye: float | None = None) -> Touch:
    """The touch of a stimulus: touched samples (h > 0) and where their rays meet the objects."""
    positions3, l, hit, h = (np.asarray(a) for a in (positions3, l, hit, h))
    keep = (h > 0) & np.isfinite(l) & (hit >= 0)
    c = positions3[keep]
    dist = l[keep]
    if perspective_eye is None:
        points = np.column_stack([c, dist])                                  # along +w
    else:                                                                   # from the eye at w = -d through c
        eye = np.array([0.0, 0.0, 0.0, -perspective_eye])
        direction = np.column_stack([c, np.zeros(len(c))]) - eye
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        points = np.column_stack([c, np.zeros(len(c))]) + dist[:, None] * direction
    objects = hit[keep].astype(np.int64)
    weights = h[keep].astype(float)
    for j in np.unique(objects):
        weights[objects == j] /= weights[objects == j].sum()
    return Touch(points, objects, weights, np.asarray(velocity3, dtype=float).reshape(3))


def push_impulses(world: World, state: State, touch: Touch, rate: float) -> np.ndarray:
    """(K, 9) impulse rows [body, point (4), impulse (4)] of one step for `touch` (see module doc)."""
    speed = float(np.linalg.norm(touch.velocity))
    if len(touch.points) == 0 or speed == 0.0 or rate <= 0:
        return np.zeros((0, 9))
    direction = np.r_[touch.velocity / speed, 0.0]
    bodies = touch.objects
    dynamic = ~world.static[bodies]
    if not dynamic.any():
        return np.zeros((0, 9))
    bodies, points, weights = bodies[dynamic], touch.points[dynamic], touch.weights[dynamic]
    from .world import angular_velocity

    w = angular_velocity(world, state)[bodies]
    r = points - state.x[bodies]
    point_velocity = state.v[bodies] + np.einsum("kij,kj->ki", bivector.hat(w), r)
    shortfall = speed - point_velocity @ direction                          # how much slower than the hand
    # bring the point's speed along u to the hand's over 1 / rate, each point's share by its stimulus
    amount = np.clip(rate * world.dt, 0.0, 1.0) * np.maximum(shortfall, 0.0) * world.mass[bodies] * weights
    rows = np.column_stack([bodies.astype(float), points, amount[:, None] * direction])
    return rows[amount > 0]

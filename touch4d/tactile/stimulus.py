"""The stimulus model of the paper (§5): from the distances l_i to the motor intensities V_i.

Pure, vectorised functions: eq. 1 (`relative_strength`), eq. 2 (`adjusted_strength`), eq. 3
(`intensity`), and `compute_stimulus`, which places the glove's samples with a hand pose, casts
them along +w through a scene (eq. 4-7, by `touch4d.geometry.raycast.RayCaster`) and applies 1-3.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .glove import Glove
from .pose import place


@dataclass(frozen=True)
class Stimulus:
    """Everything computed for one pose; arrays per sample (N) and per motor (M)."""

    positions: np.ndarray   # (N, 3) samples c_i in screen coordinates
    inside: np.ndarray      # (N,) bool: inside the screen cube [-1, 1]^3
    l: np.ndarray           # (N,) eq. 7 distance, NaN unless inside and hit
    hit: np.ndarray         # (N,) index of the object hit, -1 where l is NaN
    s: np.ndarray           # (N,) eq. 1
    h: np.ndarray           # (N,) eq. 2
    motor_h: np.ndarray     # (M,) h as each motor feels it (its sample's, or its weighted samples')
    V: np.ndarray           # (M,) eq. 3, the motor intensities
    alpha: float
    beta: float
    gamma: float

    @property
    def touched(self) -> np.ndarray:
        """The set L of the paper: samples inside the screen whose ray meets an object."""
        return np.isfinite(self.l)


def relative_strength(l: np.ndarray, alpha: float) -> np.ndarray:
    """Eq. 1: s_i = max(alpha (l_min - l_i) + 1, 0), l_min over the touched samples; 0 where l is NaN."""
    depth = np.where(np.isnan(l), np.inf, l)
    l_min = depth.min(initial=np.inf)
    if not math.isfinite(l_min):
        return np.zeros(np.shape(l))
    return np.maximum(alpha * (l_min - depth) + 1.0, 0.0)


def adjusted_strength(s: np.ndarray, beta: float) -> np.ndarray:
    """Eq. 2: h_i = (1 - beta sum_k s_k / N) s_i, N the number of samples with s > 0 (0 if none)."""
    active = np.count_nonzero(s > 0)
    if active == 0:
        return np.zeros(np.shape(s))
    # No clip needed: with s <= 1 and beta <= 1, beta * sum(s) <= active holds after every rounding too
    # (rounding to nearest never passes a representable bound), so the factor is never negative.
    return (1.0 - beta * float(s.sum()) / active) * s


def intensity(h: np.ndarray, gamma: float) -> np.ndarray:
    """Eq. 3: V_i = gamma h_i."""
    return gamma * h


def motor_strength(glove: Glove, h: np.ndarray) -> np.ndarray:
    """h as each motor feels it: its own sample's, or the weighted mean over the samples it covers."""
    return h[glove.motor_sample] if glove.motor_weights is None else glove.motor_weights @ h


def inside_screen(points: np.ndarray) -> np.ndarray:
    """Which screen points (N, 3) lie in the screen cube [-1, 1]^3 (boundary included)."""
    a = np.abs(points)
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2]) <= 1.0   # 3x faster than .max(axis=1)


def compute_stimulus(glove: Glove, caster, position, orientation, alpha: float | None = None,
                     beta: float | None = None) -> Stimulus:
    """The stimulus for a hand pose (screen position (3,), unit quaternion x,y,z,w) against a scene.

    `caster` is the scene's RayCaster (orthographic or perspective, as it was built); alpha and
    beta default to the glove's. Raises `PoseError` for a bad pose.
    """
    return stimulus_at(glove, caster, place(glove.samples, glove.units_per_metre, position, orientation), alpha, beta)


def compute_joint_stimulus(glove: Glove, caster, names, positions, orientations, handedness: str,
                           alpha: float | None = None, beta: float | None = None) -> Stimulus:
    """The stimulus for a tracked hand's joints (WebXR's 25, screen units): every sample placed by
    its bone (touch4d.tactile.skeleton), then eq. 1-7 as for a pose. Raises `JointsError` for
    joints that cannot place the hand."""
    skeleton = glove.skeleton
    m = skeleton.transforms(names, positions, orientations, handedness, glove.units_per_metre)
    return stimulus_at(glove, caster, skeleton.place("samples", m), alpha, beta)


def stimulus_at(glove: Glove, caster, positions: np.ndarray, alpha: float | None = None,
                beta: float | None = None) -> Stimulus:
    """Eq. 1-7 for the glove's samples already placed in the screen (N, 3), however they were placed."""
    alpha = glove.alpha if alpha is None else alpha
    beta = glove.beta if beta is None else beta
    inside = inside_screen(positions)
    if inside.any():
        l, hit = caster.cast(positions)       # NaN and -1 on a miss
        if not inside.all():
            l = np.where(inside, l, np.nan)
            hit = np.where(inside, hit, -1)
    else:
        l, hit = np.full(len(positions), np.nan), np.full(len(positions), -1)
    return _from_distances(glove, positions, inside, l, hit, alpha, beta)


def stimulus_of_distances(glove: Glove, positions: np.ndarray, inside: np.ndarray, l: np.ndarray, hit: np.ndarray,
                          alpha: float | None = None, beta: float | None = None) -> Stimulus:
    """Eq. 1-3 for distances already found (l NaN and hit -1 where a sample touches nothing), however
    they were found: the GPU's tactile pass (touch4d.render.tactile) gives them from the renderer's ray."""
    return _from_distances(glove, positions, np.asarray(inside, bool), np.asarray(l, float), np.asarray(hit),
                           glove.alpha if alpha is None else alpha, glove.beta if beta is None else beta)


def no_stimulus(glove: Glove, positions: np.ndarray | None = None, alpha: float | None = None,
                beta: float | None = None) -> Stimulus:
    """All zeros: the hand is absent (tracking lost) or there is nothing to touch."""
    n = len(glove.samples)
    if positions is None:
        positions = np.full((n, 3), np.nan)
    return _from_distances(glove, positions, np.zeros(n, bool), np.full(n, np.nan), np.full(n, -1),
                           glove.alpha if alpha is None else alpha, glove.beta if beta is None else beta)


def _from_distances(glove, positions, inside, l, hit, alpha, beta) -> Stimulus:
    s = relative_strength(l, alpha)
    h = adjusted_strength(s, beta)
    motor_h = motor_strength(glove, h)
    return Stimulus(positions=positions, inside=inside, l=l, hit=hit, s=s, h=h, motor_h=motor_h,
                    V=intensity(motor_h, glove.gamma), alpha=float(alpha), beta=float(beta),
                    gamma=float(glove.gamma))

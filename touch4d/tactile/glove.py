"""The glove model: sample points on a parametric hand, motors bound to samples, stimulus constants.

`load_glove(path)` reads a glove file once (declared in touch4d.glovefile, so the tactile and motor
nodes accept exactly the same files); every mistake, an unknown key (a typo) included, raises
`ConfigError` naming the file, the key and what was expected. This module builds the hand, its
samples and the motor bindings from the file's tactile part.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from touch4d import glovefile, schema
from touch4d.configfile import CONFIG_DIR
from touch4d.glovefile import DEFAULT_TOUCH_THRESHOLD, Beta, CanSection, GloveFile
from touch4d.schema import Positive

from .hand import FINGER_NAMES, Hand

DEFAULT_GLOVE = CONFIG_DIR / "glove.yaml"
TACTILE_KEYS = ("screen_edge_m", "grid", "hand", "alpha", "beta", "gamma")


@dataclass(frozen=True)
class Glove:
    """Samples and motors in the hand frame (metres), and the constants of eq. 1-3."""

    path: str
    screen_edge_m: float
    hand: Hand
    samples: np.ndarray          # (N, 3) metres, hand frame
    motor_names: list[str]
    motor_positions: np.ndarray  # (M, 3) metres, hand frame
    motor_sample: np.ndarray     # (M,) index into samples
    motor_board: np.ndarray      # (M,) CAN node id
    motor_channel: np.ndarray    # (M,) channel on that board
    alpha: float
    beta: float
    gamma: float
    touch_threshold: float = DEFAULT_TOUCH_THRESHOLD   # a motor driven above this counts as touched
    can: CanSection = field(default_factory=CanSection)   # the boards' part, as the file gave it
    bones: glovefile.Bones = field(default_factory=glovefile.Bones)   # where the finger joints lie
    # (M, N) weights of each motor over the samples (rows sum to 1), or None: each motor feels its
    # own sample (motor_sample) alone. Eq. 3 per motor: V_m = gamma sum_i w_mi h_i.
    motor_weights: np.ndarray | None = None

    @cached_property
    def skeleton(self):
        """The samples and motors bound to the hand's bones (touch4d.tactile.skeleton), built once."""
        from .skeleton import Skeleton
        return Skeleton.of(self)

    @cached_property
    def weight_matrix(self) -> np.ndarray:
        """(M, N) every motor's weights over the samples, dense: `motor_weights`, or 1 on its own
        sample (what a page given the glove mixes with: motor_strength = weight_matrix @ h)."""
        if self.motor_weights is not None:
            return self.motor_weights
        weights = np.zeros((len(self.motor_names), len(self.samples)))
        weights[np.arange(len(self.motor_names)), self.motor_sample] = 1.0
        return weights

    @property
    def units_per_metre(self) -> float:
        """Screen units per metre: the screen is 2 units and `screen_edge_m` metres wide."""
        return 2.0 / self.screen_edge_m

    def with_constants(self, alpha: float | None = None, beta: float | None = None,
                       gamma: float | None = None) -> "Glove":
        """The same glove with some of alpha, beta, gamma replaced (checked like the file's)."""
        alpha = self.alpha if alpha is None else check_alpha(alpha, self.path, "alpha")
        beta = self.beta if beta is None else check_beta(beta, self.path, "beta")
        gamma = self.gamma if gamma is None else check_gamma(gamma, self.path, "gamma")
        return replace(self, alpha=alpha, beta=beta, gamma=gamma)


def load_glove(path: str | Path | None = None) -> Glove:
    """Read a glove file (default: config/glove.yaml) and build its samples and motor bindings."""
    data, path = glovefile.load(path)
    return glove_from_file(data, path)


def glove_from_dict(data, path="<input>") -> Glove:
    """Build a `Glove` from the parsed contents of a glove file."""
    return glove_from_file(glovefile.convert(data, path), path)


def glove_from_file(data: GloveFile, path="<input>") -> Glove:
    """The tactile part of a checked glove file: the hand, its samples and where each motor binds."""
    for key in TACTILE_KEYS:
        if getattr(data, key) is None:
            schema.fail(path, key, "a value (the tactile model needs screen_edge_m, grid, hand, alpha, beta, gamma)")
    for i, finger in enumerate(data.hand.fingers):
        if finger.name not in FINGER_NAMES:
            schema.fail(path, f"hand.fingers[{i}].name", f"one of {', '.join(FINGER_NAMES)}", got=finger.name,
                        choices=FINGER_NAMES)
    palm = schema.to_builtins(data.hand.palm)
    hand = Hand.from_sizes(palm, [{**schema.to_builtins(f), "base": list(f.base)} for f in data.hand.fingers])
    counts = data.grid.counts
    samples = hand.grid_samples(counts)
    if len(samples) == 0:
        schema.fail(path, "grid.n", "a grid that leaves sample points inside the hand", got=data.grid.n)
    names = [m.name for m in data.motors]
    positions = np.array([m.position for m in data.motors], dtype=float)

    distance = np.linalg.norm(positions[:, None, :] - samples[None, :, :], axis=2)
    motor_sample = np.argmin(distance, axis=1)
    low, high = hand.bounds()
    reach = float(np.linalg.norm((high - low) / (np.asarray(counts) - 1)))
    far = np.flatnonzero(distance[np.arange(len(names)), motor_sample] > reach)
    if len(far):
        k = int(far[0])
        schema.fail(path, f"motors[{k}].position", f"a point on the hand, within {reach:.4f} m of a sample point",
                    got=positions[k].tolist())
    return Glove(
        motor_weights=_cover_weights(data.motors, samples, motor_sample, path),
        path=str(path), screen_edge_m=data.screen_edge_m, hand=hand, samples=samples,
        motor_names=names, motor_positions=positions, motor_sample=motor_sample,
        motor_board=np.array([m.board for m in data.motors], dtype=int),
        motor_channel=np.array([m.channel for m in data.motors], dtype=int),
        alpha=data.alpha, beta=data.beta, gamma=data.gamma, touch_threshold=data.touch_threshold, can=data.can,
        bones=data.bones,
    )


def _cover_weights(motors, samples: np.ndarray, motor_sample: np.ndarray, path) -> np.ndarray | None:
    """Each motor's weights over the samples: 1/K on each of the K samples within its `covers`
    radius, or 1 on its own sample; None when no motor covers more than its own sample."""
    if all(m.covers is None for m in motors):
        return None
    weights = np.zeros((len(motors), len(samples)))
    for k, m in enumerate(motors):
        if m.covers is None:
            weights[k, motor_sample[k]] = 1.0
            continue
        near = np.linalg.norm(samples - np.asarray(m.position), axis=1) <= m.covers.radius
        if not near.any():
            schema.fail(path, f"motors[{k}].covers.radius", "a radius that reaches a sample point",
                        got=m.covers.radius)
        weights[k, near] = 1.0 / np.count_nonzero(near)
    return weights


def check_alpha(value, path, key) -> float:
    """A value for alpha (eq. 1), checked as the glove file's."""
    return schema.convert(value, Positive, path, key)


def check_beta(value, path, key) -> float:
    """A value for beta (eq. 2), checked as the glove file's."""
    return schema.convert(value, Beta, path, key)


def check_gamma(value, path, key) -> float:
    """A value for gamma (eq. 3), checked as the glove file's."""
    return schema.convert(value, Positive, path, key)

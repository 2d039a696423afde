"""The glove model: sample points on a parametric hand, motors bound to samples, stimulus constants.

`load_glove(path)` reads and checks a glove file (config/glove.yaml); every mistake, an unknown
key (a typo) included, raises `ConfigError` naming the file, the key and what was expected. The
`can:` section and the motors' names, boards and channels are checked by `touch4d.boards.config`,
so the tactile and motor nodes accept exactly the same glove files.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from touch4d.configfile import read_yaml, resolve_path
from touch4d.errors import ConfigError
from touch4d.boards.config import DEFAULT_GLOVE, glove_can_from_mapping

from .bones import BonesSection, read_bones
from .hand import FINGER_NAMES, Hand

TOP_KEYS = ("screen_edge_m", "grid", "hand", "alpha", "beta", "gamma", "motors", "can", "bones")


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
    can: dict = field(default_factory=dict)
    bones: BonesSection = field(default_factory=BonesSection)   # where the finger joints lie (bones.py)

    @cached_property
    def skeleton(self):
        """The samples and motors bound to the hand's bones (touch4d.tactile.skeleton), built once."""
        from .skeleton import Skeleton
        return Skeleton.of(self)

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
    path = resolve_path(path if path is not None else "config/glove.yaml", what="glove file")
    return glove_from_dict(read_yaml(path, "glove file"), path)


def glove_from_dict(data, path="<input>") -> Glove:
    """Build a `Glove` from the parsed contents of a glove file."""
    r = _Reader(path)
    root = r.mapping(data, "(top level)", TOP_KEYS)
    screen_edge_m = r.number(root, "screen_edge_m", positive=True)
    counts = _grid_counts(r, r.mapping(r.get(root, "grid"), "grid", ("n",)))
    hand = _hand(r, r.mapping(r.get(root, "hand"), "hand", ("palm", "fingers")))
    alpha = check_alpha(r.get(root, "alpha"), path, "alpha")
    beta = check_beta(r.get(root, "beta"), path, "beta")
    gamma = check_gamma(r.get(root, "gamma"), path, "gamma")
    # Names, boards and channels are the boards package's: one set of rules for both readers.
    can_cfg = glove_can_from_mapping(root, path)

    samples = hand.grid_samples(counts)
    if len(samples) == 0:
        raise ConfigError(path, "grid.n", "a grid that leaves sample points inside the hand", got=counts)
    names = list(can_cfg.motor_names)
    positions = _motor_positions(r, root["motors"])

    distance = np.linalg.norm(positions[:, None, :] - samples[None, :, :], axis=2)
    motor_sample = np.argmin(distance, axis=1)
    low, high = hand.bounds()
    reach = float(np.linalg.norm((high - low) / (np.asarray(counts) - 1)))
    far = np.flatnonzero(distance[np.arange(len(names)), motor_sample] > reach)
    if len(far):
        k = int(far[0])
        raise ConfigError(path, f"motors[{k}].position",
                          f"a point on the hand, within {reach:.4f} m of a sample point",
                          got=positions[k].tolist())
    return Glove(
        path=str(path), screen_edge_m=screen_edge_m, hand=hand, samples=samples,
        motor_names=names, motor_positions=positions, motor_sample=motor_sample,
        motor_board=np.array(can_cfg.motor_board, dtype=int), motor_channel=np.array(can_cfg.motor_channel, dtype=int),
        alpha=alpha, beta=beta, gamma=gamma, can=dict(root.get("can") or {}),
        bones=read_bones(root.get("bones"), path),
    )


def check_alpha(value, path, key) -> float:
    return _Reader(path).scalar(value, key, positive=True)


def check_beta(value, path, key) -> float:
    beta = _Reader(path).scalar(value, key)
    if not 0.0 <= beta <= 1.0:
        raise ConfigError(path, key, "a number in 0..1 (paper eq. 2)", got=value)
    return beta


def check_gamma(value, path, key) -> float:
    return _Reader(path).scalar(value, key, positive=True)


def _grid_counts(r: "_Reader", grid: dict) -> tuple[int, int, int]:
    n = r.get(grid, "n", "grid.n")
    values = n if isinstance(n, list) else [n, n, n]
    if len(values) != 3 or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 2 for v in values):
        raise ConfigError(r.path, "grid.n", "an integer >= 2, or a list of 3 of them", got=n)
    return tuple(values)


def _hand(r: "_Reader", hand: dict) -> Hand:
    palm = r.mapping(r.get(hand, "palm", "hand.palm"), "hand.palm", ("width", "length", "thickness"))
    palm_sizes = {k: r.number(palm, k, positive=True, where="hand.palm") for k in ("width", "length", "thickness")}
    if palm_sizes["thickness"] > palm_sizes["width"]:  # the rounded sides need width >= thickness (hand.py)
        raise ConfigError(r.path, "hand.palm.thickness", f"a number <= hand.palm.width ({palm_sizes['width']:g})",
                          got=palm_sizes["thickness"])
    fingers = r.get(hand, "fingers", "hand.fingers")
    if not isinstance(fingers, list) or not fingers:
        raise ConfigError(r.path, "hand.fingers", "a list of fingers (thumb .. little)", got=fingers)
    made = []
    for i, f in enumerate(fingers):
        where = f"hand.fingers[{i}]"
        f = r.mapping(f, where, ("name", "base", "angle_deg", "length", "radius"))
        name = r.get(f, "name", f"{where}.name")
        if name not in FINGER_NAMES:
            raise ConfigError(r.path, f"{where}.name", f"one of {', '.join(FINGER_NAMES)}", got=name)
        made.append({
            "name": name,
            "base": r.vector(r.get(f, "base", f"{where}.base"), f"{where}.base", 2),
            "angle_deg": r.number(f, "angle_deg", where=where),
            "length": r.number(f, "length", positive=True, where=where),
            "radius": r.number(f, "radius", positive=True, where=where),
        })
    names = [f["name"] for f in made]
    if len(set(names)) != len(names):
        raise ConfigError(r.path, "hand.fingers", "each finger named once", got=names)
    return Hand.from_sizes(palm_sizes, made)


def _motor_positions(r: "_Reader", motors: list) -> np.ndarray:
    """Each motor's position on the hand (metres); the list itself was checked by glove_can_from_mapping."""
    positions = []
    for i, m in enumerate(motors):
        where = f"motors[{i}]"
        r.mapping(m, where, ("name", "position", "board", "channel"))
        positions.append(r.vector(r.get(m, "position", f"{where}.position"), f"{where}.position", 3))
    return np.array(positions, dtype=float)


class _Reader:
    """Typed reads from parsed YAML that raise ConfigError naming the file and key."""

    def __init__(self, path):
        self.path = path

    def get(self, mapping: dict, key: str, where: str | None = None):
        if key not in mapping:
            raise ConfigError(self.path, where or key, "this key to be present")
        return mapping[key]

    def mapping(self, value, where: str, keys: tuple[str, ...] | None = None) -> dict:
        """`value` as a mapping; with `keys`, any other key (a typo) is named."""
        if not isinstance(value, dict):
            raise ConfigError(self.path, where, "a mapping", got=value)
        unknown = [k for k in value if k not in keys] if keys is not None else []
        if unknown:
            prefix = "" if where.startswith("(") else f"{where}."
            raise ConfigError(self.path, f"{prefix}{unknown[0]}", f"one of {', '.join(keys)}", got=unknown[0])
        return value

    def scalar(self, value, key: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(self.path, key, "a finite number", got=value)
        if positive and not value > 0:
            raise ConfigError(self.path, key, "a number > 0", got=value)
        return float(value)

    def number(self, mapping: dict, key: str, positive: bool = False, where: str | None = None) -> float:
        full = f"{where}.{key}" if where else key
        return self.scalar(self.get(mapping, key, full), full, positive)

    def integer(self, mapping: dict, key: str, where: str, low: int | None = None) -> int:
        full = f"{where}.{key}"
        value = self.get(mapping, key, full)
        if isinstance(value, bool) or not isinstance(value, int) or (low is not None and value < low):
            raise ConfigError(self.path, full, "an integer" + (f" >= {low}" if low is not None else ""), got=value)
        return value

    def vector(self, value, where: str, size: int) -> list[float]:
        if not isinstance(value, list) or len(value) != size:
            raise ConfigError(self.path, where, f"a list of {size} numbers", got=value)
        return [self.scalar(v, where) for v in value]

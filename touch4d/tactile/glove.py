"""The glove model: sample points on a parametric hand, motors bound to samples, stimulus constants.

`load_glove(path)` reads and checks a glove file (config/glove.yaml); every mistake raises
`ConfigError` naming the file, the key and what was expected.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from touch4d.errors import ConfigError

from .hand import FINGER_NAMES, Hand

DEFAULT_GLOVE = Path(__file__).resolve().parents[2] / "config" / "glove.yaml"


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
    path = Path(path) if path is not None else DEFAULT_GLOVE
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(path, "<file>", "a readable glove file", got=exc.strerror) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(path, "<file>", "valid YAML", got=str(exc).splitlines()[0]) from None
    return glove_from_dict(data, path)


def glove_from_dict(data, path="<input>") -> Glove:
    """Build a `Glove` from the parsed contents of a glove file."""
    r = _Reader(path)
    root = r.mapping(data, "<top level>")
    screen_edge_m = r.number(root, "screen_edge_m", positive=True)
    counts = _grid_counts(r, r.mapping(r.get(root, "grid"), "grid"))
    hand = _hand(r, r.mapping(r.get(root, "hand"), "hand"))
    alpha = check_alpha(r.get(root, "alpha"), path, "alpha")
    beta = check_beta(r.get(root, "beta"), path, "beta")
    gamma = check_gamma(r.get(root, "gamma"), path, "gamma")
    can = r.mapping(r.get(root, "can"), "can")
    board_channels = _boards(r, can)

    samples = hand.grid_samples(counts)
    if len(samples) == 0:
        raise ConfigError(path, "grid.n", "a grid that leaves sample points inside the hand", got=counts)
    names, positions, boards, channels = _motors(r, r.get(root, "motors"), board_channels)

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
        motor_board=boards, motor_channel=channels, alpha=alpha, beta=beta, gamma=gamma, can=can,
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
    palm = r.mapping(r.get(hand, "palm", "hand.palm"), "hand.palm")
    palm_sizes = {k: r.number(palm, k, positive=True, where="hand.palm") for k in ("width", "length", "thickness")}
    fingers = r.get(hand, "fingers", "hand.fingers")
    if not isinstance(fingers, list) or not fingers:
        raise ConfigError(r.path, "hand.fingers", "a list of fingers (thumb .. little)", got=fingers)
    made = []
    for i, f in enumerate(fingers):
        where = f"hand.fingers[{i}]"
        f = r.mapping(f, where)
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


def _boards(r: "_Reader", can: dict) -> dict[int, int]:
    boards = r.get(can, "boards", "can.boards")
    if not isinstance(boards, list) or not boards:
        raise ConfigError(r.path, "can.boards", "a list of {id, channels}", got=boards)
    found: dict[int, int] = {}
    for i, b in enumerate(boards):
        where = f"can.boards[{i}]"
        b = r.mapping(b, where)
        board_id = r.integer(b, "id", where, low=1)
        if board_id in found:
            raise ConfigError(r.path, f"{where}.id", "a board id used once", got=board_id)
        found[board_id] = r.integer(b, "channels", where, low=1)
    return found


def _motors(r: "_Reader", motors, board_channels: dict[int, int]):
    if not isinstance(motors, list) or not motors:
        raise ConfigError(r.path, "motors", "a list of {name, position, board, channel}", got=motors)
    names, positions, boards, channels = [], [], [], []
    used: dict[tuple[int, int], str] = {}
    for i, m in enumerate(motors):
        where = f"motors[{i}]"
        m = r.mapping(m, where)
        name = r.get(m, "name", f"{where}.name")
        if not isinstance(name, str) or not name:
            raise ConfigError(r.path, f"{where}.name", "a non-empty string", got=name)
        if name in names:
            raise ConfigError(r.path, f"{where}.name", "a motor name used once", got=name)
        position = r.vector(r.get(m, "position", f"{where}.position"), f"{where}.position", 3)
        board = r.integer(m, "board", where)
        if board not in board_channels:
            raise ConfigError(r.path, f"{where}.board", f"a board id listed in can.boards {sorted(board_channels)}",
                              got=board)
        channel = r.integer(m, "channel", where, low=0)
        if channel >= board_channels[board]:
            raise ConfigError(r.path, f"{where}.channel", f"0..{board_channels[board] - 1} (board {board})",
                              got=channel)
        if (board, channel) in used:
            raise ConfigError(r.path, f"{where}.channel",
                              f"a channel not already driving motor '{used[board, channel]}'", got=[board, channel])
        used[board, channel] = name
        names.append(name)
        positions.append(position)
        boards.append(board)
        channels.append(channel)
    return (names, np.array(positions, dtype=float), np.array(boards, dtype=int), np.array(channels, dtype=int))


class _Reader:
    """Typed reads from parsed YAML that raise ConfigError naming the file and key."""

    def __init__(self, path):
        self.path = path

    def get(self, mapping: dict, key: str, where: str | None = None):
        if key not in mapping:
            raise ConfigError(self.path, where or key, "this key to be present")
        return mapping[key]

    def mapping(self, value, where: str) -> dict:
        if not isinstance(value, dict):
            raise ConfigError(self.path, where, "a mapping", got=value)
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

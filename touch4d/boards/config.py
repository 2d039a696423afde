"""The glove's CAN configuration: the `can:` section and the motor -> board/channel map of glove.yaml.

This is the one place the boards package reads the glove file; every default of the `can:` section
lives in `DEFAULTS` below, so a glove file may give only the keys it changes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from touch4d.configfile import CONFIG_DIR, read_yaml, resolve_path
from touch4d.errors import ConfigError

DEFAULT_GLOVE = CONFIG_DIR / "glove.yaml"

MAX_CHANNELS = 8  # one duty frame per board: 8 x 7-bit duty + 8-bit counter = 64 bits (see dbc.py)

DEFAULTS = {
    "interface": "virtual",
    "channel": "touch4d-glove",
    "bitrate": 500000,
    "refresh_hz": 200.0,
    "idle_refresh_hz": None,    # None: 25 Hz, or faster when the board watchdog needs it (_idle_refresh)
    "watchdog_s": 0.1,
    "board_watchdog_s": 0.1,
    "status_hz": 20.0,
    "heartbeat_hz": 2.0,
    "board_timeout_s": 0.3,
    "stop_hold_s": 1.0,
    "command_max_age_s": None,  # None: watchdog_s
    "send_timeout_s": 0.002,
    "ids": {"stop": 0x000, "status": 0x180, "duty": 0x200, "heartbeat": 0x700},
    "duty": {"exponent": 1.0, "start": 0.3, "max": 0.8, "deadband": 0.02, "full_scale": 1.0},
    "thermal": {"max_on_s": 10.0, "cool_s": 3.0},
}


@dataclass(frozen=True)
class Board:
    """One motor board: its CAN node id and how many PWM channels it drives."""

    id: int
    channels: int


@dataclass(frozen=True)
class DutyConfig:
    """Intensity -> PWM duty: duty = start + (max - start) * (V / full_scale) ** exponent, 0 below deadband.

    `exponent` shapes the duty curve; it is not the paper's gamma (eq. 3's gain, in the tactile model)."""

    exponent: float
    start: float
    max: float
    deadband: float
    full_scale: float


@dataclass(frozen=True)
class ThermalConfig:
    """A motor on for `max_on_s` without a break is forced off for `cool_s`."""

    max_on_s: float
    cool_s: float


@dataclass(frozen=True)
class CanIds:
    """Frame id bases; per-board frames add the board's node id (CANopen style)."""

    stop: int
    status: int
    duty: int
    heartbeat: int


@dataclass(frozen=True)
class GloveCan:
    """Everything the boards package needs from a glove file."""

    file: str
    interface: str
    channel: str
    bitrate: int
    refresh_hz: float
    idle_refresh_hz: float
    watchdog_s: float
    board_watchdog_s: float
    status_hz: float
    heartbeat_hz: float
    board_timeout_s: float
    stop_hold_s: float
    command_max_age_s: float
    send_timeout_s: float
    ids: CanIds
    duty: DutyConfig
    thermal: ThermalConfig
    boards: tuple[Board, ...]
    motor_names: tuple[str, ...]
    motor_board: tuple[int, ...]
    motor_channel: tuple[int, ...]

    def board(self, board_id: int) -> Board:
        for b in self.boards:
            if b.id == board_id:
                return b
        raise KeyError(board_id)

    def motors_of(self, board_id: int) -> list[tuple[int, int]]:
        """(motor index, channel) of every motor on one board."""
        return [(k, c) for k, (b, c) in enumerate(zip(self.motor_board, self.motor_channel)) if b == board_id]


def load_glove_can(path: str | Path | None = None) -> GloveCan:
    """Read the `can:` section and the motors of a glove file (default config/glove.yaml)."""
    path = resolve_path(path if path is not None else "config/glove.yaml", what="glove file")
    return glove_can_from_mapping(read_yaml(path, "glove file"), path)


def glove_can_from_mapping(data, file="<input>") -> GloveCan:
    """Build and check a `GloveCan` from the parsed glove file (a mapping with `motors` and `can`)."""
    if not isinstance(data, dict):
        raise ConfigError(file, "(top level)", "a mapping with 'motors' and 'can'", got=type(data).__name__)
    can = data.get("can", {})
    if not isinstance(can, dict):
        raise ConfigError(file, "can", "a mapping", got=can)
    unknown = set(can) - set(DEFAULTS) - {"boards"}
    if unknown:
        raise ConfigError(file, f"can.{sorted(unknown)[0]}", f"one of {sorted(set(DEFAULTS) | {'boards'})}")

    def get(key, kind, check=None, what=""):
        value = can.get(key, DEFAULTS[key])
        return _typed(file, f"can.{key}", value, kind, check, what)

    def section(key, kinds, checks):
        value = can.get(key, {})
        if not isinstance(value, dict):
            raise ConfigError(file, f"can.{key}", "a mapping", got=value)
        extra = set(value) - set(DEFAULTS[key])
        if key == "duty" and "gamma" in extra:
            # The duty curve's exponent was once called gamma, like eq. 3's gain: name the new key.
            raise ConfigError(file, "can.duty.gamma", "can.duty.exponent (the duty curve's exponent; "
                              "'gamma' is eq. 3's gain at the top level of the glove file)")
        if extra:
            raise ConfigError(file, f"can.{key}.{sorted(extra)[0]}", f"one of {sorted(DEFAULTS[key])}")
        merged = {**DEFAULTS[key], **value}
        return {k: _typed(file, f"can.{key}.{k}", merged[k], kinds[k], *checks[k]) for k in DEFAULTS[key]}

    positive = (lambda v: 0 < v < math.inf, "> 0 and finite")
    fraction = (lambda v: 0 <= v <= 1, "in 0..1")
    frame_id = (lambda v: 0 <= v <= 0x7FF, "an 11-bit CAN id 0..0x7FF")

    duty = section("duty", {k: float for k in DEFAULTS["duty"]},
                   {"exponent": positive, "start": fraction, "max": fraction, "deadband": fraction,
                    "full_scale": positive})
    if duty["start"] > duty["max"]:
        raise ConfigError(file, "can.duty.start", f"<= can.duty.max ({duty['max']})", got=duty["start"])
    thermal = section("thermal", {k: float for k in DEFAULTS["thermal"]},
                      {"max_on_s": positive, "cool_s": (lambda v: v >= 0, ">= 0")})
    ids = section("ids", {k: int for k in DEFAULTS["ids"]}, {k: frame_id for k in DEFAULTS["ids"]})

    watchdog_s = get("watchdog_s", float, *positive)
    boards = _boards(file, can.get("boards"))
    motors = _motors(file, data.get("motors"), boards)
    cfg = GloveCan(
        file=str(file),
        interface=get("interface", str, lambda v: v != "", "a python-can interface name"),
        channel=str(_typed(file, "can.channel", can.get("channel", DEFAULTS["channel"]), (str, int))),
        bitrate=get("bitrate", int, lambda v: 10_000 <= v <= 1_000_000, "a classic CAN bitrate 10000..1000000"),
        refresh_hz=get("refresh_hz", float, *positive),
        idle_refresh_hz=_idle_refresh(file, can, get),
        watchdog_s=watchdog_s,
        board_watchdog_s=get("board_watchdog_s", float, *positive),
        status_hz=get("status_hz", float, *positive),
        heartbeat_hz=get("heartbeat_hz", float, *positive),
        board_timeout_s=get("board_timeout_s", float, *positive),
        stop_hold_s=get("stop_hold_s", float, lambda v: v >= 0, ">= 0 (.inf: a stop latches until restart)"),
        command_max_age_s=(watchdog_s if can.get("command_max_age_s") is None else
                           get("command_max_age_s", float, lambda v: v >= 0, ">= 0 (0: no age check)")),
        send_timeout_s=get("send_timeout_s", float, lambda v: 0 <= v < math.inf, ">= 0 and finite"),
        ids=CanIds(**ids),
        duty=DutyConfig(**duty),
        thermal=ThermalConfig(**thermal),
        boards=boards,
        motor_names=tuple(m[0] for m in motors),
        motor_board=tuple(m[1] for m in motors),
        motor_channel=tuple(m[2] for m in motors),
    )
    _check_ids(cfg)
    _check_idle_refresh(cfg)
    return cfg


IDLE_REFRESH_HZ = 25.0


def _idle_refresh(file, can: dict, get) -> float:
    """`can.idle_refresh_hz`, or its default: 25 Hz, at least two frames per board watchdog, at
    most refresh_hz."""
    if can.get("idle_refresh_hz") is not None:
        return get("idle_refresh_hz", float, lambda v: 0 < v < math.inf, "> 0 and finite")
    positive = (lambda v: 0 < v < math.inf, "> 0 and finite")
    fastest, watchdog = get("refresh_hz", float, *positive), get("board_watchdog_s", float, *positive)
    return min(max(IDLE_REFRESH_HZ, 2.0 / watchdog), fastest)


def _check_idle_refresh(cfg: GloveCan) -> None:
    """All-off boards are refreshed at `idle_refresh_hz`: no faster than `refresh_hz`, and at least
    twice per board watchdog, so that one lost frame trips no board."""
    if cfg.idle_refresh_hz > cfg.refresh_hz:
        raise ConfigError(cfg.file, "can.idle_refresh_hz", f"<= can.refresh_hz ({cfg.refresh_hz:g})",
                          got=cfg.idle_refresh_hz)
    if 2.0 / cfg.idle_refresh_hz > cfg.board_watchdog_s + 1e-12:
        raise ConfigError(cfg.file, "can.idle_refresh_hz",
                          f">= {2.0 / cfg.board_watchdog_s:g} (two frames per can.board_watchdog_s)",
                          got=cfg.idle_refresh_hz)


def _typed(file, key, value, kind, check=None, what=""):
    """Check one value's type (ints are accepted for floats, bools never count as numbers)."""
    kinds = kind if isinstance(kind, tuple) else (kind,)
    ok = isinstance(value, kinds) and not isinstance(value, bool)
    if not ok and float in kinds and isinstance(value, int) and not isinstance(value, bool):
        value, ok = float(value), True
    names = " or ".join(k.__name__ for k in kinds)
    if not ok:
        raise ConfigError(file, key, f"a {names}" + (f" {what}" if what else ""), got=value)
    if check is not None and not check(value):
        raise ConfigError(file, key, f"a {names} {what}".rstrip(), got=value)
    return value


def _boards(file, raw) -> tuple[Board, ...]:
    if raw is None:
        raw = [{"id": i, "channels": MAX_CHANNELS} for i in range(1, 5)]
    if not isinstance(raw, list) or not raw:
        raise ConfigError(file, "can.boards", "a non-empty list of {id, channels}", got=raw)
    boards, seen = [], set()
    for i, b in enumerate(raw):
        key = f"can.boards[{i}]"
        if not isinstance(b, dict) or set(b) != {"id", "channels"}:
            raise ConfigError(file, key, "a mapping with exactly 'id' and 'channels'", got=b)
        bid = _typed(file, f"{key}.id", b["id"], int, lambda v: 1 <= v <= 127, "CAN node id 1..127")
        ch = _typed(file, f"{key}.channels", b["channels"], int, lambda v: 1 <= v <= MAX_CHANNELS,
                    f"1..{MAX_CHANNELS} (one duty frame per board)")
        if bid in seen:
            raise ConfigError(file, f"{key}.id", "a board id used once", got=bid)
        seen.add(bid)
        boards.append(Board(bid, ch))
    return tuple(boards)


def _motors(file, raw, boards) -> list[tuple[str, int, int]]:
    if not isinstance(raw, list) or not raw:
        raise ConfigError(file, "motors", "a non-empty list of {name, position, board, channel}", got=raw)
    channels = {b.id: b.channels for b in boards}
    out, names, slots = [], set(), {}
    for i, m in enumerate(raw):
        key = f"motors[{i}]"
        if not isinstance(m, dict):
            raise ConfigError(file, key, "a mapping with name, position, board, channel", got=m)
        for k in ("name", "board", "channel"):
            if k not in m:
                raise ConfigError(file, f"{key}.{k}", "present")
        name = _typed(file, f"{key}.name", m["name"], str, lambda v: v != "", "non-empty")
        board = _typed(file, f"{key}.board", m["board"], int, lambda v: v in channels,
                       f"one of the can.boards ids {sorted(channels)}")
        channel = _typed(file, f"{key}.channel", m["channel"], int, lambda v: 0 <= v < channels[board],
                         f"0..{channels[board] - 1} (board {board} has {channels[board]} channels)")
        if name in names:
            raise ConfigError(file, f"{key}.name", "a motor name used once", got=name)
        if (board, channel) in slots:
            raise ConfigError(file, f"{key}.channel",
                              f"a channel of board {board} not already driving motor '{slots[board, channel]}'",
                              got=channel)
        names.add(name)
        slots[board, channel] = name
        out.append((name, board, channel))
    return out


def _check_ids(cfg: GloveCan) -> None:
    """Every frame id must fit in 11 bits and no two frames may share one."""
    used = {cfg.ids.stop: "stop"}
    for b in cfg.boards:
        for kind in ("status", "duty", "heartbeat"):
            fid = getattr(cfg.ids, kind) + b.id
            if fid > 0x7FF:
                raise ConfigError(cfg.file, f"can.ids.{kind}", f"a base leaving room for node id {b.id} in 11 bits",
                                  got=hex(getattr(cfg.ids, kind)))
            if fid in used:
                raise ConfigError(cfg.file, f"can.ids.{kind}",
                                  f"a base whose id {hex(fid)} (board {b.id}) does not clash with {used[fid]}")
            used[fid] = f"{kind} of board {b.id}"

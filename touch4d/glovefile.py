"""The glove file (config/glove.yaml), declared once and read once.

Two packages use one file: the tactile model (touch4d.tactile.glove) reads the hand, its sample
grid, the stimulus constants and where each motor sits; the motor boards (touch4d.boards.config)
read the `can:` section and which board and channel drive each motor. Both build their part from
the one `GloveFile` this module reads, so they accept exactly the same files, and neither package
imports the other. Every default lives in the Structs below; the packaged glove file shows them
as comments (a test keeps the two in step).
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated

import msgspec

from touch4d import schema
from touch4d.configfile import resolve_path
from touch4d.schema import Finite, Fraction, NonNegative, Positive

DEFAULT_PATH = "config/glove.yaml"
DEFAULT_TOUCH_THRESHOLD = 0.05   # see GloveFile.touch_threshold
MAX_CHANNELS = 8   # one duty frame per board: 8 x 7-bit duty + 8-bit counter = 64 bits (see boards/dbc.py)

Point2 = tuple[Finite, Finite]
Point3 = tuple[Finite, Finite, Finite]
Beta = Annotated[float, msgspec.Meta(ge=0, le=1, description="a number in 0..1 (paper eq. 2)")]
FrameId = Annotated[int, msgspec.Meta(ge=0, le=0x7FF, description="an 11-bit CAN id 0..0x7FF")]


# ---- the tactile model's part ------------------------------------------------------------------------


class Palm(msgspec.Struct, forbid_unknown_fields=True):
    """A slab whose thumb and little-finger sides are rounded (radius thickness / 2), metres."""

    width: Positive
    length: Positive
    thickness: Positive

    def __post_init__(self):
        if self.thickness > self.width:   # the rounded sides need width >= thickness (tactile/hand.py)
            raise schema.Invalid(f"a number <= hand.palm.width ({self.width:g})", self.thickness, "thickness")


class Finger(msgspec.Struct, forbid_unknown_fields=True):
    """A capsule from `base` [x, y] (z = 0), turned `angle_deg` from +y toward +x, metres."""

    name: str
    base: Point2
    angle_deg: Finite
    length: Positive
    radius: Positive


class HandSpec(msgspec.Struct, forbid_unknown_fields=True):
    palm: Palm
    fingers: Annotated[list[Finger], msgspec.Meta(min_length=1, description="a list of fingers (thumb .. little)")]

    def __post_init__(self):
        names = [f.name for f in self.fingers]
        if len(set(names)) != len(names):
            raise schema.Invalid("each finger named once", names, "fingers")


class Grid(msgspec.Struct, forbid_unknown_fields=True):
    """An n x n x n grid (or [nx, ny, nz]) over the hand's bounding box; the points inside it are samples."""

    # (a constrained int inside a union crashes msgspec 0.22's collector: the bound is checked below)
    n: Annotated[int | tuple[int, int, int], msgspec.Meta(description="an integer >= 2, or a list of 3 of them")]

    def __post_init__(self):
        if min(self.counts) < 2:
            raise schema.Invalid("an integer >= 2, or a list of 3 of them", list(self.n) if isinstance(self.n, tuple)
                                 else self.n, "n")

    @property
    def counts(self) -> tuple[int, int, int]:
        return tuple(self.n) if isinstance(self.n, tuple) else (self.n, self.n, self.n)


class Covers(msgspec.Struct, forbid_unknown_fields=True):
    """The samples one actuator feels: every sample within `radius` metres of it, weighted equally
    (a held controller's one actuator stands for the whole hand around it; touch4d.tactile.glove)."""

    radius: Positive


class Motor(msgspec.Struct, forbid_unknown_fields=True):
    """One motor: its name, where it sits on the hand (metres) and the board channel that drives it;
    `covers`: the samples it feels (default: its nearest sample only, a glove's coin motor)."""

    name: Annotated[str, msgspec.Meta(min_length=1)]
    position: Point3
    board: int
    channel: int
    covers: Covers | None = None


BoneFraction = Annotated[float, msgspec.Meta(gt=0, lt=1, description="a fraction of the finger, 0..1")]
BoneFractions = Annotated[tuple[BoneFraction, BoneFraction, BoneFraction],
                          msgspec.Meta(description="three fractions of the finger's length, base to tip")]


class Bones(msgspec.Struct, forbid_unknown_fields=True):
    """Where the finger joints lie (the articulated hand, touch4d.tactile.skeleton): per finger its
    three bones' lengths as fractions of its capsule, base to tip (adding up to 1); `wrist` [x, y]
    metres. Each key optional: a finger not named gets touch4d.tactile.bones' human proportions."""

    wrist: Point2 | None = None
    thumb: BoneFractions | None = None
    index: BoneFractions | None = None
    middle: BoneFractions | None = None
    ring: BoneFractions | None = None
    little: BoneFractions | None = None

    def __post_init__(self):
        for finger in ("thumb", "index", "middle", "ring", "little"):
            given = getattr(self, finger)
            if given is not None and abs(sum(given) - 1.0) > 1e-6:
                raise schema.Invalid("three fractions of the finger's length adding up to 1", list(given), finger)


# ---- the motor boards' part ----------------------------------------------------------------------


class Board(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """One motor board: its CAN node id and how many PWM channels it drives."""

    id: Annotated[int, msgspec.Meta(ge=1, le=127, description="a CAN node id 1..127")]
    channels: Annotated[int, msgspec.Meta(ge=1, le=MAX_CHANNELS,
                                          description=f"1..{MAX_CHANNELS} channels (one duty frame per board)")]


class DutyConfig(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """Intensity -> PWM duty: duty = start + (max - start) * (V / full_scale) ** exponent, 0 below deadband.

    `exponent` shapes the duty curve; it is not the paper's gamma (eq. 3's gain, in the tactile model)."""

    exponent: Positive = 1.0
    start: Fraction = 0.3        # coin motors do not spin below this duty
    max: Fraction = 0.8          # keeps the motors within their rated voltage
    deadband: Fraction = 0.02
    full_scale: Positive = 1.0

    def __post_init__(self):
        if self.start > self.max:
            raise schema.Invalid(f"<= can.duty.max ({self.max:g})", self.start, "start")


class ThermalConfig(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """A motor on for `max_on_s` without a break is forced off for `cool_s` (coil heating)."""

    max_on_s: Positive = 10.0
    cool_s: NonNegative = 3.0


class CanIds(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """Frame id bases; per-board frames add the board's node id (CANopen style)."""

    stop: FrameId = 0x000
    status: FrameId = 0x180
    duty: FrameId = 0x200
    heartbeat: FrameId = 0x700


def _default_boards() -> list[Board]:
    return [Board(i, MAX_CHANNELS) for i in range(1, 5)]


class CanSection(msgspec.Struct, forbid_unknown_fields=True):
    """The glove's CAN bus (read by the motor node, touch4d/boards/config.py)."""

    interface: Annotated[str, msgspec.Meta(min_length=1, description="a python-can interface name")] = "virtual"
    channel: str | int = "touch4d-glove"
    bitrate: Annotated[int, msgspec.Meta(ge=10_000, le=1_000_000,
                                         description="a classic CAN bitrate 10000..1000000")] = 500_000
    refresh_hz: Positive = 200.0                 # every board's duty frame is resent at this rate
    idle_refresh_hz: Positive | None = None      # None: 25 Hz, or faster when the board watchdog needs it
    watchdog_s: Positive = 0.1                   # node: tactile/motors silent this long -> every motor off
    board_watchdog_s: Positive = 0.1             # board: no duty frame this long -> every channel off
    status_hz: Positive = 20.0
    heartbeat_hz: Positive = 2.0
    board_timeout_s: Positive = 0.3
    stop_hold_s: Annotated[float, msgspec.Meta(ge=0, description=">= 0 (.inf: a stop latches until restart)")] = 1.0
    command_max_age_s: NonNegative | None = None  # None: watchdog_s; 0: no age check
    send_timeout_s: NonNegative = 0.002
    ids: CanIds = msgspec.field(default_factory=CanIds)
    duty: DutyConfig = msgspec.field(default_factory=DutyConfig)
    thermal: ThermalConfig = msgspec.field(default_factory=ThermalConfig)
    boards: Annotated[list[Board], msgspec.Meta(min_length=1, description="a non-empty list of {id, channels}")] = \
        msgspec.field(default_factory=_default_boards)

    def __post_init__(self):
        if isinstance(self.channel, bool):
            raise schema.Invalid("a string or an integer", self.channel, "channel")
        seen = set()
        for i, b in enumerate(self.boards):
            if b.id in seen:
                raise schema.Invalid("a board id used once", b.id, f"boards[{i}].id")
            seen.add(b.id)
        used = {self.ids.stop: "stop"}
        for b in self.boards:
            for kind in ("status", "duty", "heartbeat"):
                base = getattr(self.ids, kind)
                if base + b.id > 0x7FF:
                    raise schema.Invalid(f"a base leaving room for node id {b.id} in 11 bits", hex(base), f"ids.{kind}")
                if base + b.id in used:
                    raise schema.Invalid(f"a base whose id {hex(base + b.id)} (board {b.id}) does not clash with "
                                         f"{used[base + b.id]}", hex(base), f"ids.{kind}")
                used[base + b.id] = f"{kind} of board {b.id}"
        # All-off boards are refreshed at idle_refresh_hz: no faster than refresh_hz, and at least
        # twice per board watchdog, so that one lost frame trips no board.
        if self.idle_refresh_hz is not None:
            if self.idle_refresh_hz > self.refresh_hz:
                raise schema.Invalid(f"<= can.refresh_hz ({self.refresh_hz:g})", self.idle_refresh_hz, "idle_refresh_hz")
            if 2.0 / self.idle_refresh_hz > self.board_watchdog_s + 1e-12:
                raise schema.Invalid(f">= {2.0 / self.board_watchdog_s:g} (two frames per can.board_watchdog_s)",
                                     self.idle_refresh_hz, "idle_refresh_hz")


# ---- the file ------------------------------------------------------------------------------------


class GloveFile(msgspec.Struct, forbid_unknown_fields=True):
    """A glove file as written. The tactile model needs screen_edge_m, grid, hand and alpha, beta,
    gamma (a file for the motor boards alone may leave them out)."""

    motors: Annotated[list[Motor], msgspec.Meta(min_length=1,
                                                description="a non-empty list of {name, position, board, channel}")]
    screen_edge_m: Positive | None = None
    grid: Grid | None = None
    hand: HandSpec | None = None
    alpha: Positive | None = None                # paper eq. 1, per screen unit
    beta: Beta | None = None
    gamma: Positive | None = None                # paper eq. 3
    # A motor counts as touched (status line, HUD, WebXR page) when its intensity is above this.
    touch_threshold: Annotated[float, msgspec.Meta(ge=0, lt=1, description="an intensity in 0..1")] = \
        DEFAULT_TOUCH_THRESHOLD
    can: CanSection = msgspec.field(default_factory=CanSection)
    bones: Bones = msgspec.field(default_factory=Bones)

    def __post_init__(self):
        """Every motor on a board and channel that exist, each channel and name used once."""
        channels = {b.id: b.channels for b in self.can.boards}
        names, slots = set(), {}
        for i, m in enumerate(self.motors):
            if m.board not in channels:
                raise schema.Invalid(f"one of the can.boards ids {sorted(channels)}", m.board, f"motors[{i}].board")
            if not 0 <= m.channel < channels[m.board]:
                raise schema.Invalid(f"0..{channels[m.board] - 1} (board {m.board} has {channels[m.board]} channels)",
                                     m.channel, f"motors[{i}].channel")
            if m.name in names:
                raise schema.Invalid("a motor name used once", m.name, f"motors[{i}].name")
            if (m.board, m.channel) in slots:
                raise schema.Invalid(f"a channel of board {m.board} not already driving motor "
                                     f"'{slots[m.board, m.channel]}'", m.channel, f"motors[{i}].channel")
            names.add(m.name)
            slots[m.board, m.channel] = m.name


def load(path=None) -> tuple[GloveFile, Path]:
    """The glove file at `path` (found by resolve_path; default config/glove.yaml), checked, and its path."""
    path = resolve_path(path if path is not None else DEFAULT_PATH, what="glove file")
    return convert(schema.read_yaml(path, "glove file"), path), path


def convert(data, file=None) -> GloveFile:
    """A parsed glove file checked against `GloveFile` (ConfigError naming file, key, expected, got)."""
    duty = data.get("can", {}).get("duty") if isinstance(data, dict) and isinstance(data.get("can"), dict) else None
    if isinstance(duty, dict) and "gamma" in duty:
        # The duty curve's exponent was once called gamma, like eq. 3's gain: name the new key.
        schema.fail(file, "can.duty.gamma", "can.duty.exponent (the duty curve's exponent; 'gamma' is eq. 3's "
                    "gain at the top level of the glove file)")
    return schema.convert(data, GloveFile, file)

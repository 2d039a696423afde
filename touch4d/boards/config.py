"""The glove's CAN configuration: the `can:` section and the motor -> board/channel map of a glove file.

The file is declared and checked in touch4d.glovefile (every default of the `can:` section lives in
its `CanSection`, so a glove file gives only the keys it changes); this module turns its boards'
part into a `GloveCan` with the defaults that depend on other keys filled in.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from touch4d import glovefile
from touch4d.configfile import CONFIG_DIR
from touch4d.glovefile import MAX_CHANNELS, Board, CanIds, DutyConfig, ThermalConfig  # noqa: F401 (the boards' types)

DEFAULT_GLOVE = CONFIG_DIR / "glove.yaml"
IDLE_REFRESH_HZ = 25.0   # all-off boards' refresh by default (raised to two frames per board watchdog)

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
    data, path = glovefile.load(path)
    return glove_can(data, path)


def glove_can_from_mapping(data, file="<input>") -> GloveCan:
    """A `GloveCan` from the parsed contents of a glove file (a mapping with `motors` and `can`)."""
    return glove_can(glovefile.convert(data, file), file)


def glove_can(glove: glovefile.GloveFile, file="<input>") -> GloveCan:
    """The boards' part of a checked glove file, with the defaults that follow other keys."""
    can = glove.can
    return GloveCan(
        file=str(file), interface=can.interface, channel=str(can.channel), bitrate=can.bitrate,
        refresh_hz=can.refresh_hz,
        # 25 Hz, at least two frames per board watchdog, at most refresh_hz
        idle_refresh_hz=(can.idle_refresh_hz if can.idle_refresh_hz is not None else
                         min(max(IDLE_REFRESH_HZ, 2.0 / can.board_watchdog_s), can.refresh_hz)),
        watchdog_s=can.watchdog_s, board_watchdog_s=can.board_watchdog_s, status_hz=can.status_hz,
        heartbeat_hz=can.heartbeat_hz, board_timeout_s=can.board_timeout_s, stop_hold_s=can.stop_hold_s,
        command_max_age_s=can.watchdog_s if can.command_max_age_s is None else can.command_max_age_s,
        send_timeout_s=can.send_timeout_s, ids=can.ids, duty=can.duty, thermal=can.thermal,
        boards=tuple(can.boards),
        motor_names=tuple(m.name for m in glove.motors),
        motor_board=tuple(m.board for m in glove.motors),
        motor_channel=tuple(m.channel for m in glove.motors),
    )

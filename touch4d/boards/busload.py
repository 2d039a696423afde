"""The CAN bus load of a glove configuration, worst case, against its bitrate.

A classic CAN data frame with an 11-bit id and n data bytes has 47 + 8n bits: SOF 1, id 11,
RTR 1, IDE 1, r0 1, DLC 4, data 8n, CRC 15, CRC delimiter 1, ACK 2, EOF 7, intermission 3.
Bit stuffing (a complement bit after 5 equal bits) covers SOF..CRC, 34 + 8n bits, and adds at
worst floor((34 + 8n - 1) / 4) bits (Davis et al., "CAN schedulability analysis", 2007): an
8-byte frame is 111 bits nominal, 135 worst case.

Frame rates per board: duty frames at most `driver.FRAMES_PER_PERIOD` (2) x refresh_hz, the
long-run worst case of changes sent at once plus the periodic refresh (see driver.py); status at
status_hz, heartbeat at heartbeat_hz. NMT frames are sent only at start, on a stop and to restart
a board, and are left out.
"""
from __future__ import annotations

from dataclasses import dataclass

from touch4d.errors import ConfigError
from touch4d.boards.config import GloveCan
from touch4d.boards.dbc import build_database
from touch4d.boards.driver import FRAMES_PER_PERIOD

MAX_LOAD = 0.70


def frame_bits(dlc: int, stuffing: bool = True) -> int:
    """Bits on the wire of one standard-id data frame with `dlc` bytes, worst-case stuffing if asked."""
    if not 0 <= dlc <= 8:
        raise ValueError(f"classic CAN carries 0..8 data bytes, got {dlc}")
    bits = 47 + 8 * dlc
    return bits + ((34 + 8 * dlc - 1) // 4 if stuffing else 0)


@dataclass(frozen=True)
class BusLoad:
    """Load of a configuration: total bits/s, fraction of the bitrate, and (frame, frames/s, bits) rows."""

    bits_per_s: float
    fraction: float
    rows: tuple

    def describe(self) -> str:
        lines = [f"{name:>14}: {rate:7.1f} frames/s x {bits} bits" for name, rate, bits in self.rows]
        lines.append(f"{'total':>14}: {self.bits_per_s:9.0f} bit/s = {100 * self.fraction:.1f} % (worst case)")
        return "\n".join(lines)


def bus_load(cfg: GloveCan) -> BusLoad:
    """Worst-case bus load of the configuration (frame lengths from the generated DBC)."""
    db = build_database(cfg)
    rows = []
    for b in cfg.boards:
        for name, rate in ((f"Duty_B{b.id}", FRAMES_PER_PERIOD * cfg.refresh_hz), (f"Status_B{b.id}", cfg.status_hz),
                           (f"Heartbeat_B{b.id}", cfg.heartbeat_hz)):
            rows.append((name, rate, frame_bits(db.get_message_by_name(name).length)))
    bits = sum(rate * n for _, rate, n in rows)
    return BusLoad(bits_per_s=bits, fraction=bits / cfg.bitrate, rows=tuple(rows))


def check_bus_load(cfg: GloveCan, limit: float = MAX_LOAD) -> BusLoad:
    """The bus load, or ConfigError when it exceeds `limit` of the bitrate."""
    load = bus_load(cfg)
    if load.fraction > limit:
        raise ConfigError(
            cfg.file, "can",
            f"a worst-case bus load <= {100 * limit:.0f} % of can.bitrate {cfg.bitrate} bit/s "
            f"(lower refresh_hz, status_hz or heartbeat_hz, or raise bitrate)",
            got=f"{100 * load.fraction:.1f} % ({load.bits_per_s:.0f} bit/s)",
        )
    return load

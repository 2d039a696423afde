"""Intensity -> PWM duty for coin vibration motors, and the per-motor thermal limit (pure functions)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from touch4d.boards.config import DutyConfig, ThermalConfig
from touch4d.boards.dbc import DUTY_LEVELS


def intensity_to_duty(intensity, cfg: DutyConfig) -> np.ndarray:
    """PWM duty 0..1 per motor from the intensity V_i (paper eq. 3).

    x = clip(V / full_scale, 0, 1); below `deadband` the motor is off; above it the duty is
    `start + (max - start) * x ** exponent`, so the weakest felt stimulus still gets the duty at
    which a coin motor starts to spin, and no stimulus exceeds `max`. NaN or inf count as off.
    """
    x = np.asarray(intensity, dtype=np.float64) / cfg.full_scale
    x = np.clip(np.where(np.isfinite(x), x, 0.0), 0.0, 1.0)
    on = (x > 0) & (x >= cfg.deadband)
    return np.where(on, cfg.start + (cfg.max - cfg.start) * x ** cfg.exponent, 0.0)


def duty_to_levels(duty) -> np.ndarray:
    """Duty 0..1 -> the 7-bit raw levels of the duty frame (0..127), rounded to nearest."""
    return np.rint(np.clip(np.asarray(duty, dtype=np.float64), 0.0, 1.0) * DUTY_LEVELS).astype(np.int64)


def levels_to_duty(levels) -> np.ndarray:
    """Raw levels 0..127 -> duty 0..1."""
    return np.asarray(levels, dtype=np.float64) / DUTY_LEVELS


@dataclass(frozen=True)
class ThermalState:
    """Per motor: start of the current on-streak, start of the current off time, end of a forced cool-down."""

    on_since: np.ndarray
    off_since: np.ndarray
    cool_until: np.ndarray

    @classmethod
    def initial(cls, n: int) -> "ThermalState":
        nan = np.full(n, np.nan)
        return cls(on_since=nan, off_since=nan.copy(), cool_until=np.full(n, -np.inf))


def thermal_limit(duty, state: ThermalState, now: float, cfg: ThermalConfig) -> tuple[np.ndarray, ThermalState]:
    """Apply the continuous on-time limit: returns (limited duty, new state).

    A motor on for `max_on_s` is forced off for `cool_s`. An on-streak only ends after the motor
    has been off for `cool_s` too, so flicking a motor off for a moment does not reset its streak.
    """
    duty = np.asarray(duty, dtype=np.float64)
    cooling = now < state.cool_until
    wants = (duty > 0) & ~cooling
    on_since = np.where(wants & np.isnan(state.on_since), now, state.on_since)
    off_since = np.where(wants, np.nan, np.where(np.isnan(state.off_since), now, state.off_since))
    rested = ~wants & (now - off_since >= cfg.cool_s)
    on_since = np.where(rested, np.nan, on_since)
    over = wants & (now - on_since >= cfg.max_on_s)
    cool_until = np.where(over, now + cfg.cool_s, state.cool_until)
    on_since = np.where(over, np.nan, on_since)
    off_since = np.where(over, now, off_since)
    limited = np.where(wants & ~over, duty, 0.0)
    return limited, ThermalState(on_since=on_since, off_since=off_since, cool_until=cool_until)


def thermal_deadline(duty, state: ThermalState, now: float, cfg: ThermalConfig) -> float:
    """The earliest time after `now` at which `thermal_limit` with the same duty and the `state` it
    returned at `now` can give another result or state (a streak reaching `max_on_s`, a cool-down or
    a rest ending); inf if never. Until then the limit need not be computed again."""
    duty = np.asarray(duty, dtype=np.float64)
    cooling = now < state.cool_until
    wants = (duty > 0) & ~cooling
    streak = ~np.isnan(state.on_since)
    if (wants & ~streak).any():
        return now                                            # its streak starts at the next call
    times = np.concatenate([
        state.cool_until[cooling],                            # cooling ends: the motor may start
        state.on_since[wants & streak] + cfg.max_on_s,        # a streak reaches the limit
        state.off_since[~wants & streak] + cfg.cool_s,        # a rest ends the streak
    ])
    return float(times.min()) if len(times) else np.inf

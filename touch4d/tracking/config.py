"""Reading the tracking config files (calibration, paths) and checking node parameters, with errors
that name the file (or node) and the key."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from touch4d import configfile
from touch4d.errors import ConfigError

CONFIG_DIR = configfile.CONFIG_DIR
MAX_TRACKER_RATE = 1000.0   # Hz: the tracker role publishes at up to 1 kHz


def read_yaml(path) -> dict:
    """The top-level map of a YAML file; a missing file or bad YAML is a ConfigError naming the file."""
    data = configfile.read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(path, "(top level)", "a map", got=type(data).__name__)
    return data


def get_map(data: dict, key: str, file, where: str = "", default: Any = None) -> dict:
    value = data.get(key, default)
    if not isinstance(value, dict):
        raise ConfigError(file, where + key, "a map", got=value)
    return value


def get_number(data: dict, key: str, file, where: str = "", default: Any = None, positive: bool = False) -> float:
    value = finite_parameter(data.get(key, default), file, where + key)
    if positive and not value > 0:
        raise ConfigError(file, where + key, "a number > 0", got=value)
    return value


def finite_parameter(value, source, key: str) -> float:
    """A node parameter that must be a finite number; else a ConfigError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(source, key, "a finite number", got=value)
    return float(value)


def positive_parameter(value, source, key: str, maximum: float = np.inf, unit: str = "") -> float:
    """A node parameter that must be a finite number in (0, maximum]; else a ConfigError naming it."""
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value)
            or not 0 < value <= maximum):
        bound = f"a number in (0, {maximum:g}]" if np.isfinite(maximum) else "a finite number > 0"
        raise ConfigError(source, key, bound + (f" {unit}" if unit else ""), got=value)
    return float(value)


def get_vector(data: dict, key: str, file, n: int, where: str = "", default: Any = None) -> np.ndarray:
    value = data.get(key, default)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (n,) or not np.isfinite(arr).all():
        raise ConfigError(file, where + key, f"a list of {n} finite numbers", got=value)
    return arr

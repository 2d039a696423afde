"""Reading the tracking config files (calibration, paths) with errors that name file and key."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from touch4d.errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"


def read_yaml(path) -> dict:
    """The top-level map of a YAML file; a missing file or bad YAML is a ConfigError naming the file."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(path, "(file)", "an existing YAML file", got="no such file") from None
    except yaml.YAMLError as exc:
        raise ConfigError(path, "(file)", "valid YAML", got=str(exc).splitlines()[0]) from None
    if not isinstance(data, dict):
        raise ConfigError(path, "(top level)", "a map", got=type(data).__name__)
    return data


def get_map(data: dict, key: str, file, where: str = "", default: Any = None) -> dict:
    value = data.get(key, default)
    if not isinstance(value, dict):
        raise ConfigError(file, where + key, "a map", got=value)
    return value


def get_number(data: dict, key: str, file, where: str = "", default: Any = None, positive: bool = False) -> float:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(file, where + key, "a finite number", got=value)
    if positive and not value > 0:
        raise ConfigError(file, where + key, "a number > 0", got=value)
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


def resolve(path: str | Path) -> Path:
    """A config path as given, or, when relative and not found from here, from the repository root."""
    path = Path(path)
    if path.is_absolute() or path.exists():
        return path
    return CONFIG_DIR.parent / path

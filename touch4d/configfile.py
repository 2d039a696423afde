"""Reading a YAML config file, with the ConfigError every part reports for a missing or broken one."""
from __future__ import annotations

from pathlib import Path

import yaml

from touch4d.errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def read_yaml(path, what: str = "config file"):
    """The parsed contents of a YAML file; an unreadable file or bad YAML names the file (key '(file)')."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(path, "(file)", f"a readable {what}", got=exc.strerror or str(exc)) from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(path, "(file)", "valid YAML", got=" ".join(str(exc).split())) from None


def resolve(path) -> Path:
    """A config path as given, or, when relative and not found from the working directory, from the
    repository root (so `config/gloves/dense.yaml` works from anywhere)."""
    path = Path(path)
    if path.is_absolute() or path.exists():
        return path
    from_repo = CONFIG_DIR.parent / path
    return from_repo if from_repo.exists() else path

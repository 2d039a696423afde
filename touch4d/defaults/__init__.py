"""The defaults that ship with touch4d: `config/` (glove, gloves, scenes, studies, bus, paths,
calibration, the DBC) and `launch/` (launch files), found with importlib.resources.

In the repository `config` and `launch` here are links to the top-level folders of the same names,
so the files exist once; a wheel holds copies. `touch4d config copy DIR` copies them out for
editing; `touch4d.configfile.resolve_path` falls back to them for `config/...` and `launch/...`.
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path

# A wheel installs as plain files (never zipped), so the package folder is a real path, which
# node processes and file readers need.
ROOT = Path(str(files(__name__)))
FOLDERS = ("config", "launch")

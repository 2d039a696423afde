"""Finding and reading the files a user names: one resolver for every path, and YAML with the
ConfigError every part reports for a missing or broken file.

Every path a user gives — a command-line flag (`--scene`, `--glove`, `--bus`, a launch file), an
`include:` of a launch file, a node parameter, a key file of a bus config — is found by
`resolve_path`, in this order (the first that exists wins):

1. the path itself, when it is absolute (`~` is expanded);
2. relative to the current directory;
3. relative to the folder of the file that names it (the launch file, the including file, the
   bus config), when there is one;
4. the defaults packaged with touch4d (`touch4d.defaults`), for paths that start with `config/`
   or `launch/`: `config/scenes/hypercube.yaml` works from any directory, and a copy made with
   `touch4d config copy .` shadows the packaged file from that directory on.

A path found nowhere is a `PathNotFound` (a ConfigError) that names every place it looked.
"""
from __future__ import annotations

import difflib
import os
from pathlib import Path

from touch4d import schema
from touch4d.defaults import FOLDERS, ROOT as DEFAULTS
from touch4d.errors import ConfigError

CONFIG_DIR = (DEFAULTS / "config").resolve()   # the packaged config/ (the repository's, in a checkout)
COMMAND_LINE = "command line"


class PathNotFound(ConfigError):
    """A path that is in none of the places `resolve_path` looks; `places` lists them in order (each
    once), `near` the names of existing files in those folders that are close to the one given."""

    def __init__(self, source, key: str, what: str, path, places: list[Path]):
        self.near = _near_names(path, places)
        hint = f"did you mean {' or '.join(repr(n) for n in self.near)}?" if self.near else None
        super().__init__(source, key, f"an existing {what}", got=str(path),
                         detail="looked in " + ", ".join(str(p) for p in places), hint=hint)
        self.places = places


def _near_names(path, places: list[Path]) -> list[str]:
    """`path` with its last part replaced by close names found beside any place looked (a typo)."""
    given = Path(path)
    names: set[str] = set()
    for place in places:
        try:
            names.update(p.name for p in place.parent.iterdir())
        except OSError:
            continue
    close = difflib.get_close_matches(given.name, sorted(names - {given.name}), n=1, cutoff=0.75)
    return [str(given.with_name(name)) for name in close]


def resolve_path(path, named_in=None, *, key: str = "(file)", what: str = "file") -> Path:
    """The absolute path of the file or folder `path` that a user gave, found in the order of this
    module's docstring. `named_in`: the file that names it (its folder is searched third), or a
    label such as "command line" for the error; `key`: where in it (e.g. `--scene`,
    `include[0]`, `nodes.scene.params.scene`). Not found: PathNotFound naming every place."""
    if isinstance(path, str) and not path.strip():
        raise ConfigError(named_in if named_in is not None else COMMAND_LINE, key, f"a {what} path", got=path)
    if not isinstance(path, (str, os.PathLike)):
        raise ConfigError(named_in if named_in is not None else COMMAND_LINE, key, f"a {what} path", got=path)
    given = Path(path).expanduser()
    places: list[Path] = []
    if given.is_absolute():
        places.append(given)
    else:
        places.append(Path.cwd() / given)
        base = _folder_of(named_in)
        if base is not None and base / given not in places:
            places.append(base / given)
        if given.parts and given.parts[0] in FOLDERS and ".." not in given.parts:
            places.append((DEFAULTS / given).resolve())
    places = _once(places)
    for place in places:
        if place.exists():
            return place
    raise PathNotFound(named_in if named_in is not None else path, key, what, path, places)


def _once(places: list[Path]) -> list[Path]:
    """The places without repeats: in a checkout the packaged defaults are the current directory's
    own config/ and launch/ (links), looked in once."""
    seen, out = set(), []
    for place in places:
        real = place.resolve()
        if real not in seen:
            seen.add(real)
            out.append(place)
    return out


def _folder_of(named_in) -> Path | None:
    """The absolute folder of the file `named_in` (a Path, or a string naming an existing file), or
    None when it is a label such as "command line"."""
    if isinstance(named_in, os.PathLike) or (isinstance(named_in, str) and Path(named_in).expanduser().is_file()):
        return Path(named_in).expanduser().absolute().parent
    return None


def read_yaml(path, what: str = "config file"):
    """The parsed contents of a YAML file; an unreadable file or bad YAML names the file (a syntax
    error whole, with its line and column: see touch4d.schema)."""
    return schema.read_yaml(path, what)

"""`touch4d config list | where | copy`: the packaged defaults, where a path resolves, copies to edit."""
from __future__ import annotations

import shutil
from pathlib import Path

from touch4d.configfile import COMMAND_LINE, PathNotFound, resolve_path
from touch4d.defaults import FOLDERS, ROOT
from touch4d.errors import ConfigError

# What a default is: the kinds of file the wheel packages (never keys/, which holds secrets).
KINDS = ("*.yaml", "*.dbc")


def register(subparsers) -> None:
    config = subparsers.add_parser("config", help="the packaged defaults: list, where a path resolves, copy to edit",
                                   description="The launch files, scenes, gloves, studies and bus files that ship with touch4d.")
    sub = config.add_subparsers(dest="config_command", metavar="ACTION")
    config.set_defaults(func=lambda args: config.print_help() or 2)
    p = sub.add_parser("list", help="every packaged default, and which of them a file of yours shadows here")
    p.set_defaults(func=_list)
    p = sub.add_parser("where", help="the file a path names, and the order in which paths are resolved")
    p.add_argument("paths", nargs="*", metavar="PATH", help="e.g. config/glove.yaml or launch/demo.yaml")
    p.set_defaults(func=_where)
    p = sub.add_parser("copy", help="copy the defaults (or some) into DIR to edit them",
                       description="Copy the packaged config/ and launch/ (or the NAMEs, files or folders such as "
                                   "config/glove.yaml or config/scenes) into DIR. From DIR on, config/... and "
                                   "launch/... name your copies first.")
    p.add_argument("dir", metavar="DIR", help="destination folder (config/ and launch/ go inside it)")
    p.add_argument("names", nargs="*", metavar="NAME", help="only these defaults (default: all)")
    p.add_argument("--force", action="store_true", help="overwrite files that already exist in DIR")
    p.set_defaults(func=_copy)


def default_files(root: Path = ROOT) -> list[str]:
    """The relative names (config/..., launch/...) of every packaged default under `root`."""
    names = set()
    for folder in FOLDERS:
        for kind in KINDS:
            for file in (root / folder).rglob(kind):
                rel = file.relative_to(root)
                if "keys" not in rel.parts and file.is_file():
                    names.add(rel.as_posix())
    return sorted(names)


def copy_defaults(dest: Path, names: list[str] = (), force: bool = False,
                  root: Path = ROOT) -> tuple[list[str], list[str]]:
    """Copy the defaults (those under the `names`, else all) into `dest`; returns (copied, kept):
    files already in `dest` are kept unless `force`."""
    available = default_files(root)
    chosen = available
    if names:
        wanted = [n.strip("/") for n in names]
        for name in wanted:
            if not any(a == name or a.startswith(name + "/") for a in available):
                raise ConfigError(COMMAND_LINE, "NAME", "a packaged default (touch4d config list), e.g. "
                                  "config/glove.yaml, config/scenes or launch", got=name)
        chosen = [a for a in available if any(a == n or a.startswith(n + "/") for n in wanted)]
    copied, kept = [], []
    for name in chosen:
        target = dest / name
        if target.exists() and not force:
            kept.append(name)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(root / name, target)
        copied.append(name)
    return copied, kept


def home() -> Path:
    """The folder that holds the packaged config/ and launch/ (the repository, in a checkout)."""
    return (ROOT / "config").resolve().parent


def _list(args) -> int:
    print(f"packaged defaults: {home()}")
    for name in default_files():
        found = resolve_path(name)
        mine = Path.cwd() / name
        print(f"  {name}" + (f"   (yours here: {mine})" if found == mine else ""))
    return 0


ORDER = """\
A path is looked for, the first that exists winning:
  1. as given, when absolute;
  2. in the current directory;
  3. beside the file that names it (a launch file, an including launch file, a bus config);
  4. for config/... and launch/..., in the packaged defaults: {root}"""


def _where(args) -> int:
    if not args.paths:
        print(ORDER.format(root=home()))
        return 0
    code = 0
    for path in args.paths:
        try:
            print(resolve_path(path, COMMAND_LINE, key="PATH"))
        except PathNotFound as exc:
            print(f"{path}: not found; looked in: " + ", ".join(str(p) for p in exc.places))
            code = 1
    return code


def _copy(args) -> int:
    dest = Path(args.dir).expanduser()
    if dest.exists() and not dest.is_dir():
        raise ConfigError(COMMAND_LINE, "DIR", "a folder", got=str(dest))
    copied, kept = copy_defaults(dest, args.names, args.force)
    print(f"copied {len(copied)} file(s) into {dest.absolute()}"
          + (f"; kept {len(kept)} that already exist(s) there (--force overwrites): {', '.join(kept)}" if kept else ""))
    print(f"from {dest.absolute()}, config/... and launch/... now name these copies first "
          "(touch4d config where PATH shows which file a path names)")
    return 0

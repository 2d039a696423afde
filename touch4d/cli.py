"""The `touch4d` command: each part of touch4d registers its own sub-commands."""
from __future__ import annotations

import argparse
import importlib
import sys

from touch4d.errors import Touch4dError
from touch4d.stdio import EXIT_PIPE_CLOSED, silence_stdout  # the reader of our output went away: stop quietly

# Each module has `register(subparsers)`; sub-commands set `func(args) -> int` on their parser.
# The commands each registers are listed so that a command imports only its own part (the
# launcher need not load the renderer and scipy before it starts the nodes).
PARTS = {
    "touch4d.commands.bus": ("launch", "topic", "node", "bus"),
    "touch4d.commands.geometry": ("shape", "scene"),
    "touch4d.commands.tactile": ("tactile", "hand"),
    "touch4d.commands.render": ("render",),
    "touch4d.commands.log": ("record", "replay", "log"),
    "touch4d.commands.boards": ("glove",),
    "touch4d.commands.defaults": ("config",),
    "touch4d.commands.study": ("study",),
    "touch4d.commands.physics": ("physics",),
    "touch4d.commands.lesson": ("lesson",),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with every part's commands, or only the part that owns `command`."""
    parser = argparse.ArgumentParser(prog="touch4d", description="Touch 4D objects with a vibrotactile glove.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    owners = [name for name, commands in PARTS.items() if command in commands]
    for name in owners or PARTS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        module.register(sub)
    return parser


# Commands that run until Ctrl+C: for them Ctrl+C is the normal way to stop, so it exits 0.
RUN_UNTIL_STOPPED = {"launch", "record", "replay", "topic", "node", "bus", "glove"}


def main(argv: list[str] | None = None) -> int:
    try:
        try:
            code = _main(argv)
        finally:
            sys.stdout.flush()      # argparse's --help exits with its text still buffered
        return code
    except BrokenPipeError:
        silence_stdout()
        return EXIT_PIPE_CLOSED


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        parser = build_parser(argv[0] if argv else None)
        args, extra = parser.parse_known_args(argv)
        # `touch4d launch FILE --duration 5 ROLE:=X`: positionals after an option come back unknown.
        if extra and isinstance(getattr(args, "items", None), list) and not any(e.startswith("-") for e in extra):
            args.items.extend(extra)
        elif extra:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        return int(args.func(args) or 0)
    except Touch4dError as exc:
        print(f"touch4d {argv[0] if argv else ''}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Also while still importing, before a command could install its own handler.
        command = next((a for a in argv if not a.startswith("-")), "")
        return 0 if command in RUN_UNTIL_STOPPED else 130


if __name__ == "__main__":
    sys.exit(main())

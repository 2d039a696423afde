"""The `touch4d` command: each part of touch4d registers its own sub-commands."""
from __future__ import annotations

import argparse
import importlib
import sys

from touch4d.errors import Touch4dError

# Each module has `register(subparsers)`; sub-commands set `func(args) -> int` on their parser.
PARTS = (
    "touch4d.bus.cli",        # launch, topic, node
    "touch4d.geometry.cli",   # shape
    "touch4d.tactile.cli",    # tactile
    "touch4d.render.cli",     # render
    "touch4d.log.cli",        # record, replay, log
    "touch4d.glove.cli",      # glove
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="touch4d", description="Touch 4D objects with a vibrotactile glove.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in PARTS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except Touch4dError as exc:
        print(f"touch4d {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

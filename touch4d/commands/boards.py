"""`touch4d glove ...`: write the glove's DBC, show its bus load, run the board emulator, design a layout."""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError
from touch4d.boards.busload import bus_load
from touch4d.boards.config import load_glove_can
from touch4d.boards.dbc import dbc_text


def register(subparsers) -> None:
    parser = subparsers.add_parser("glove", help="the glove's CAN protocol and board emulator")
    sub = parser.add_subparsers(dest="glove_command", metavar="ACTION", required=True)

    p = sub.add_parser("dbc", help="write the DBC file of the glove's CAN protocol")
    p.add_argument("--glove", help="glove file (default config/glove.yaml)")
    p.add_argument("-o", "--output", help="output file (default: standard output)")
    p.set_defaults(func=cmd_dbc)

    p = sub.add_parser("busload", help="print the worst-case CAN bus load of the glove's configuration")
    p.add_argument("--glove", help="glove file (default config/glove.yaml)")
    p.set_defaults(func=cmd_busload)

    p = sub.add_parser("emulate", help="run the motor-board emulator on a python-can channel")
    p.add_argument("--glove", help="glove file (default config/glove.yaml)")
    p.add_argument("--interface", help="python-can interface (default: the glove's can.interface)")
    p.add_argument("--channel", help="python-can channel (default: the glove's can.channel)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--firmware", action="store_true",
                   help="run the boards' firmware core (firmware/, built for this machine) instead of the Python emulator")
    p.add_argument("--print-period", type=float, default=1.0, help="seconds between status lines")
    p.set_defaults(func=cmd_emulate)

    from touch4d.commands.study.planning import register_glove_design   # a layout chosen by what it tells

    register_glove_design(sub)


def _glove(args):
    """The `--glove` file's CAN configuration (default config/glove.yaml)."""
    path = resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None
    return load_glove_can(path)


def cmd_dbc(args) -> int:
    text = dbc_text(_glove(args))
    if args.output:
        Path(args.output).write_bytes(text.encode())
    else:
        sys.stdout.write(text)
    return 0


def cmd_busload(args) -> int:
    cfg = _glove(args)
    print(f"{cfg.file}: {len(cfg.boards)} boards at {cfg.bitrate} bit/s, refresh {cfg.refresh_hz:g} Hz")
    print(bus_load(cfg).describe())
    return 0


def cmd_emulate(args) -> int:
    import can

    from touch4d.boards.emulator import make_glove_emulator

    if not (math.isfinite(args.print_period) and args.print_period > 0):
        raise ConfigError("<command line>", "--print-period", "a number of seconds > 0", got=args.print_period)
    cfg = _glove(args)
    kind = "firmware" if args.firmware else "python"
    try:
        emulator = make_glove_emulator(kind, cfg, interface=args.interface, channel=args.channel)  # may build
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise ConfigError("<command line>", "--interface/--channel", "a python-can bus that opens",
                          got=f"{args.interface or cfg.interface} {args.channel or cfg.channel}: {exc}") from None
    print(f"emulating boards {[b.id for b in cfg.boards]} ({kind}) on {args.interface or cfg.interface} "
          f"channel {args.channel or cfg.channel}", flush=True)
    end = None if args.duration is None else time.monotonic() + args.duration
    emulator.start()
    try:
        while end is None or time.monotonic() < end:
            time.sleep(args.print_period if end is None else max(0.0, min(args.print_period, end - time.monotonic())))
            for bid, board in emulator.boards.items():
                gone = " (removed)" if bid in emulator.removed else ""
                pwm = f" pwm {board.pwm}/{board.pwm_period}" if args.firmware else ""
                print(f"board {bid}: {board.nmt_state.lower()} {board.output_state().lower()} "
                      f"levels {board.levels}{pwm}{gone}", flush=True)
            print(f"frames: {dict(emulator.counters)}", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    return 0

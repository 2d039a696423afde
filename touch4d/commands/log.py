"""`touch4d record`, `touch4d replay` and `touch4d log info|export|recover`."""
from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

from touch4d.errors import Touch4dError


def register(subparsers) -> None:
    p = subparsers.add_parser("record", help="record bus topics into an MCAP log",
                              description="Record topics (all by default) into an MCAP log until Ctrl+C "
                                          "or --duration; reports per-topic seq gaps at the end.")
    p.add_argument("topics", nargs="*", metavar="TOPIC", help="topics to record (exact names; default: all)")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="the .mcap file to write")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--bus", metavar="FILE", help="bus config file (default: $TOUCH4D_BUS or config/bus.yaml)")
    p.add_argument("--namespace", "--ns", default="", metavar="NS",
                   help="record the stack launched with --namespace NS (topics written relative to NS)")
    p.add_argument("--no-realtime", dest="realtime", action="store_false",
                   help="do not try real-time priority for the receiving thread (it keeps stamps accurate)")
    p.set_defaults(func=cmd_record)

    p = subparsers.add_parser("replay", help="republish a log with its recorded timing",
                              description="Republish a log's messages with the recorded timing scaled by "
                                          "--rate, stamped now (the recorded stamp kept in each message's "
                                          "recorded_stamp) unless --original-stamps.")
    p.add_argument("file", metavar="FILE")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (2 = twice as fast)")
    p.add_argument("--loop", action="store_true", help="start over at the end, until Ctrl+C")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds of the log")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="replay only these topics")
    p.add_argument("--remap", action="append", metavar="FROM:=TO", help="publish topic FROM as TO (repeatable)")
    stamps = p.add_mutually_exclusive_group()
    stamps.add_argument("--restamp", dest="restamp", action="store_true", default=True,
                        help="the default: stamp and source_stamp moved to now (their difference kept), a fresh "
                             "seq, the recorded stamp in recorded_stamp; live nodes treat it as live")
    stamps.add_argument("--original-stamps", dest="restamp", action="store_false",
                        help="send the recorded bytes unchanged (stamps as recorded: a live motor node "
                             "drops such commands as stale)")
    p.add_argument("--recover", action="store_true",
                   help="replay an unfinished log (no footer: its recorder was killed) up to where it ends; "
                        "damaged chunks are skipped with a warning in any case")
    p.add_argument("--bus", metavar="FILE", help="bus config file")
    p.add_argument("--namespace", "--ns", default="", metavar="NS", help="publish every topic under NS/")
    p.add_argument("--no-realtime", dest="realtime", action="store_false",
                   help="do not try real-time priority for the sending thread (it keeps timing exact)")
    p.set_defaults(func=cmd_replay)

    p = subparsers.add_parser("log", help="inspect, export and recover logs")
    sub = p.add_subparsers(dest="log_command", metavar="ACTION", required=True)
    q = sub.add_parser("info", help="topics, types, counts, rates, duration, time range, seq gaps")
    q.add_argument("file", metavar="FILE")
    q.add_argument("--json", action="store_true", help="print the summary as JSON")
    q.add_argument("--recover", action="store_true",
                   help="summarize an unfinished log up to where it ends (damaged chunks are skipped anyway)")
    q.set_defaults(func=cmd_info)
    q = sub.add_parser("export", help="one topic as CSV / JSON Lines, or a JSON MCAP copy for Foxglove")
    q.add_argument("file", metavar="FILE")
    q.add_argument("--format", choices=("csv", "json", "foxglove"), required=True)
    q.add_argument("--topic", action="append", metavar="TOPIC",
                   help="the topic to export (csv/json: exactly one; foxglove: repeatable, default all)")
    q.add_argument("-o", "--output", metavar="OUT", help="output file (csv/json default: standard output)")
    q.add_argument("--recover", action="store_true",
                   help="export an unfinished log up to where it ends (damaged chunks are skipped anyway)")
    q.set_defaults(func=cmd_export)
    q = sub.add_parser("recover", help="copy everything readable of a damaged log into a complete one")
    q.add_argument("file", metavar="FILE")
    q.add_argument("-o", "--output", required=True, metavar="OUT")
    q.set_defaults(func=cmd_recover)


@contextmanager
def _stop_on_signals(stop):
    """SIGINT and SIGTERM call `stop()` instead of raising, so the command can finish cleanly."""
    previous = {s: signal.signal(s, lambda *_: stop()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _namespace(text: str) -> str:
    """--namespace checked (a ConfigError naming it)."""
    from touch4d.bus.names import EXPECTED, check_namespace
    from touch4d.configfile import COMMAND_LINE
    from touch4d.errors import ConfigError

    try:
        return check_namespace(text)
    except ValueError:
        raise ConfigError(COMMAND_LINE, "--namespace", EXPECTED, got=text) from None


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _warn_damage(path: str, problems: list[str], chunks: int, messages: int, prefix: str = "") -> None:
    """What was skipped or could not be read, as warnings: the command went on with the rest."""
    for problem in problems:
        _err(f"{prefix}warning: {path}: {problem}")
    if chunks:
        _err(f"{prefix}warning: {path}: {chunks} damaged chunk{'s' if chunks != 1 else ''} skipped, "
             f"{messages} message(s) lost")


def cmd_record(args) -> int:
    from touch4d.bus.config import resolve_bus_config

    from touch4d.log.recorder import Recorder

    if args.duration is not None and not 0 < args.duration < float("inf"):
        raise Touch4dError(f"record: --duration must be a finite number of seconds > 0, got {args.duration}")
    sys.setswitchinterval(0.0005)  # the receiving thread must not wait 5 ms for the GIL
    recorder = Recorder(resolve_bus_config(args.bus), args.output, args.topics, realtime=args.realtime,
                        namespace=_namespace(args.namespace))
    done = threading.Event()
    with _stop_on_signals(done.set):
        recorder.start()
        _err(f"recording {', '.join(args.topics) if args.topics else 'all topics'} to {args.output}"
             + (f" for {args.duration:g} s" if args.duration else " (Ctrl+C to stop)"))
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while not done.is_set() and not recorder.wait(0):
            left = 0.2 if deadline is None else deadline - time.monotonic()
            if left <= 0:
                break
            done.wait(min(0.2, left))
        report = recorder.stop()
    print("\n".join(report.lines()), flush=True)
    return 1 if report.error else 0


def cmd_replay(args) -> int:
    from touch4d.bus.config import resolve_bus_config

    from touch4d.log.reader import LogReader
    from touch4d.log.replay import BusSender, Plan, Replayer, ReplayOptions, parse_remap

    try:
        remap = parse_remap(args.remap)
    except ValueError as exc:
        raise Touch4dError(str(exc)) from None
    options = ReplayOptions(args.rate, args.loop, args.start, args.topics, remap, args.restamp, args.realtime)
    reader = LogReader(args.file, recover=args.recover)
    plan = Plan(reader, options)
    for warning in plan.warnings():
        _err(f"replay: {warning}")
    sys.setswitchinterval(0.0005)
    sender = BusSender(resolve_bus_config(args.bus), realtime=args.realtime, namespace=_namespace(args.namespace))
    replayer = Replayer(reader, plan, options, sender)
    try:
        with _stop_on_signals(replayer.stop), _progress(plan, options) as progress:
            stats = replayer.run(progress)
    finally:
        sender.close()
    how = "stopped" if stats.stopped else "done"
    _err(f"replay {how}: {stats.sent} messages sent, {stats.passes} full pass(es), "
         f"worst lateness {stats.late_max * 1e3:.1f} ms"
         + (f", {stats.restamp_failed} sent as recorded (not a stamped message map)" if stats.restamp_failed else ""))
    _warn_damage(args.file, reader.problems, reader.skipped_chunks, reader.skipped_messages, "replay: ")
    return 0


@contextmanager
def _progress(plan, options):
    """A rich progress bar on a terminal; a plain line every few seconds otherwise."""
    total = plan.duration
    if sys.stderr.isatty():
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        columns = (TextColumn("replay"), BarColumn(), TextColumn("{task.completed:.1f}/{task.total:.1f} s"),
                   TextColumn("{task.fields[sent]} msgs"), TimeElapsedColumn())
        with Progress(*columns, console=Console(stderr=True), refresh_per_second=5) as bar:
            task = bar.add_task("replay", total=max(total, 1e-9), sent=0)
            yield lambda r: bar.update(task, completed=r.position, sent=r.stats.sent)
        return
    state = {"next": 0.0}

    def plain(r) -> None:
        if r.clock() >= state["next"]:
            state["next"] = r.clock() + 5.0
            _err(f"replay: {r.position:.1f}/{total:.1f} s{' (looping)' if options.loop else ''}, "
                 f"{r.stats.sent} messages")

    yield plain


def cmd_info(args) -> int:
    from touch4d.log.summary import format_summary, summarize

    summary = summarize(args.file, recover=args.recover)
    print(json.dumps(summary.to_dict(), indent=2) if args.json else format_summary(summary), flush=True)
    _warn_damage(args.file, summary.problems, summary.skipped_chunks, summary.skipped_messages)
    return 0


def cmd_export(args) -> int:
    from touch4d.log.export import export_csv, export_foxglove, export_json
    from touch4d.log.reader import LogReader

    reader = LogReader(args.file, recover=args.recover)
    if args.format == "foxglove":
        out = args.output or args.file.rsplit(".", 1)[0] + ".foxglove.mcap"
        result = export_foxglove(reader, out, args.topic)
    else:
        if not args.topic or len(args.topic) != 1:
            raise Touch4dError(f"log export --format {args.format}: expected exactly one --topic "
                               f"(columns differ between topics)")
        fn = export_csv if args.format == "csv" else export_json
        if args.output:
            with open(args.output, "w", newline="") as f:
                result = fn(reader, args.topic[0], f)
        else:
            try:
                result = fn(reader, args.topic[0], sys.stdout)
                sys.stdout.flush()
            except BrokenPipeError:  # e.g. piped into `head`: the reader has what it wanted
                sys.stdout = open(os.devnull, "w")
                return 0
        out = args.output or "standard output"
    _err(f"exported {result.written} messages to {out}")
    for topic, n in result.skipped.items():
        _err(f"skipped {n} message(s) on {topic} that are not decodable messages")
    _warn_damage(args.file, reader.problems, reader.skipped_chunks, reader.skipped_messages)
    return 0


def cmd_recover(args) -> int:
    from touch4d.log.recover import recover_log

    result = recover_log(args.file, args.output)
    _warn_damage(args.file, result.problems, result.skipped_chunks, result.skipped_messages)
    print(f"recovered {result.messages} messages from {args.file} into {args.output}")
    return 0

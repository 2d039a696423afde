"""Sub-commands of the bus: `launch`, `topic list|echo|hz|pub`, `node list|run`, `bus broker|keygen`."""
from __future__ import annotations

import argparse
import json
import signal
from pathlib import Path

from touch4d.bus.config import resolve_bus_config, user_bus_config
from touch4d.configfile import COMMAND_LINE, PathNotFound, resolve_path
from touch4d.errors import ConfigError

DEFAULT_LAUNCH = "launch/demo.yaml"   # yours (a copy in the current directory), else the packaged one
BUS_HELP = "bus config file (default: $TOUCH4D_BUS, else config/bus.yaml)"


def register(subparsers) -> None:
    p = subparsers.add_parser("launch", help="start the broker and the nodes of a launch file",
                              description="Start the broker and every node of a launch file. Overrides: "
                              "ROLE:=NODE swaps a node, +ROLE:=NODE adds one, ROLE:=none drops one, "
                              "ROLE.PARAM:=VALUE sets a parameter.")
    p.add_argument("items", nargs="*", metavar="FILE|OVERRIDE",
                   help=f"launch file (default {DEFAULT_LAUNCH}) and overrides")
    p.add_argument("--duration", type=float, help="stop after S seconds")
    p.add_argument("--bus", help=BUS_HELP)
    p.add_argument("--no-broker", action="store_true", help="use a broker that already runs (e.g. on another machine)")
    p.add_argument("--ready-file", help="write the bus endpoints (JSON) here once every node is started")
    p.add_argument("--namespace", metavar="NS", help="every topic of this launch under NS/ (replaces the file's ns)")
    p.set_defaults(func=_launch)

    topic = _group(subparsers, "topic", "inspect topics")
    p = topic.add_parser("list", help="topics with their type, rate and publishers")
    p.add_argument("--duration", type=float, default=2.0, help="listen for S seconds (default 2)")
    p.set_defaults(func=_topic_list)
    p = topic.add_parser("echo", help="print the messages of a topic")
    p.add_argument("topic")
    p.add_argument("-n", "--count", type=int, help="stop after N messages")
    p.add_argument("--duration", type=float, help="stop after S seconds")
    p.add_argument("--type", help="message type (default: the topic's standard type)")
    p.add_argument("--full", action="store_true", help="print long arrays whole")
    p.set_defaults(func=_topic_echo)
    p = topic.add_parser("hz", help="the rate of a topic")
    p.add_argument("topic")
    p.add_argument("--duration", type=float, help="stop after S seconds")
    p.add_argument("--window", type=float, default=1.0, help="print every S seconds (default 1)")
    p.set_defaults(func=_topic_hz)
    p = topic.add_parser("pub", help="publish a message given as YAML, e.g. \"{reason: test, origin: me}\"")
    p.add_argument("topic")
    p.add_argument("yaml", help="the message's fields as a YAML mapping (header fields are filled in)")
    p.add_argument("--type", help="message type (default: the topic's standard type)")
    p.add_argument("-r", "--rate", type=float, help="publish repeatedly at HZ")
    p.add_argument("-n", "--count", type=int, help="publish N times")
    p.set_defaults(func=_topic_pub)
    for parser in topic.choices.values():
        parser.add_argument("--bus", help=BUS_HELP)
        parser.add_argument("--namespace", "--ns", default="", metavar="NS",
                            help="the topics of the stack launched with --namespace NS (TOPIC means NS/TOPIC)")

    node = _group(subparsers, "node", "inspect or run nodes")
    p = node.add_parser("list", help="the nodes that can be launched and where each comes from (--live: the "
                                     "running ones, from their heartbeats)")
    p.add_argument("--live", action="store_true", help="list the nodes running on the bus instead")
    p.add_argument("--duration", type=float, default=2.5, help="with --live: listen for S seconds (default 2.5)")
    p.add_argument("--bus", help="with --live: " + BUS_HELP)
    p.add_argument("--namespace", "--ns", default=None, metavar="NS", help="with --live: only the nodes of NS")
    p.set_defaults(func=_node_list)
    p = node.add_parser("info", help="a node's parameters: type, default, what is valid")
    p.add_argument("node", help="a node name (see `touch4d node list`) or a module path")
    p.set_defaults(func=_node_info)
    p = node.add_parser("run", help="run one node in this process: NODE [--name N] [--params JSON]")
    p.add_argument("module", metavar="node", help="a node name (see `touch4d node list`) or a module path")
    p.add_argument("args", nargs=argparse.REMAINDER, help="--name N --params JSON --bus FILE --namespace NS --log-level L")
    p.set_defaults(func=_node_run)

    bus = _group(subparsers, "bus", "the broker and its keys")
    p = bus.add_parser("broker", help="run the broker alone (the launcher normally runs it)")
    p.add_argument("--bus", help=BUS_HELP)
    p.set_defaults(func=_broker)
    p = bus.add_parser("keygen", help="make a CurveZMQ key pair for a machine or the broker")
    p.add_argument("name", help="key name, e.g. broker, pc, pi")
    p.add_argument("--dir", default="config/keys", help="folder for the key files (default config/keys)")
    p.set_defaults(func=_keygen)


def _group(subparsers, name: str, help: str):
    """A command with actions; without one it prints its own help."""
    parser = subparsers.add_parser(name, help=help, description=help)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)
    return parser.add_subparsers(dest=f"{name}_command", metavar="ACTION")


def launch_file_path(name: str):
    """The launch file a user named: a path, or a bare name such as `pi` for `launch/pi.yaml` (a path
    wins when it exists; the name is then found like any path, yours first, else the packaged one)."""
    given = Path(name)
    if len(given.parts) == 1 and not given.suffix and not given.exists():
        try:
            return resolve_path(f"launch/{name}.yaml", COMMAND_LINE, key="launch file", what="launch file")
        except PathNotFound as exc:
            near = [Path(n).stem for n in exc.near]   # `dmeo`: did you mean 'demo'?
            raise ConfigError(COMMAND_LINE, "launch file", "a launch file: a path, or the name of one in launch/ "
                              f"({', '.join(_launch_names()) or 'none found'})", got=name, detail=exc.detail,
                              hint=f"did you mean {' or '.join(repr(n) for n in near)}?" if near else None) from None
    return resolve_path(name, COMMAND_LINE, key="launch file", what="launch file")


def _launch_names() -> list[str]:
    """The bare names `touch4d launch NAME` takes: launch/*.yaml here and packaged."""
    from touch4d.defaults import ROOT

    return sorted({p.stem for folder in (Path("launch"), ROOT / "launch") if folder.is_dir()
                   for p in folder.glob("*.yaml")})


def _launch(args) -> int:
    from touch4d.bus.launcher import Launcher
    from touch4d.bus.preflight import load_checked
    from touch4d.bus.startup import PARENT_PID_ENV, die_with_parent

    die_with_parent(PARENT_PID_ENV)   # started by `touch4d study run`: its stack ends with it, even killed outright
    # Ctrl+C from here on is remembered, not raised: a KeyboardInterrupt raised where Python swallows it
    # (a fork's handlers while a library starts a process) would lose the stop; the launcher takes it up.
    early: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: early.append(signum))
    files = [i for i in args.items if ":=" not in i]
    overrides = [i for i in args.items if ":=" in i]
    if len(files) > 1:
        raise ConfigError("command line", "FILE", "one launch file", got=files)
    path = launch_file_path(files[0] if files else DEFAULT_LAUNCH)
    # every node's parameters valid, every file found and every port free before any node starts
    nodes = load_checked(path, overrides, namespace=args.namespace)
    bus = user_bus_config(args.bus)
    return Launcher(nodes, bus, start_broker=not args.no_broker, duration=args.duration,
                    ready_file=args.ready_file, launch_file=str(path), bus_file=bus.source, signals=early).run()


def _topic_list(args) -> int:
    from touch4d.bus.introspect import topic_list

    topic_list(resolve_bus_config(args.bus), args.duration, namespace=args.namespace)
    return 0


def _topic_echo(args) -> int:
    from touch4d.bus.introspect import topic_echo

    topic_echo(args.topic, resolve_bus_config(args.bus), args.count, args.duration, args.type, args.full,
               namespace=args.namespace)
    return 0


def _topic_hz(args) -> int:
    from touch4d.bus.introspect import topic_hz

    topic_hz(args.topic, resolve_bus_config(args.bus), args.duration, args.window, namespace=args.namespace)
    return 0


def _topic_pub(args) -> int:
    from touch4d.bus.introspect import topic_pub

    topic_pub(args.topic, args.yaml, resolve_bus_config(args.bus), args.type, args.rate, args.count,
              namespace=args.namespace)
    return 0


def _node_list(args) -> int:
    if args.live:
        from touch4d.bus.introspect import node_list

        node_list(resolve_bus_config(args.bus), args.duration, namespace=args.namespace)
        return 0
    from touch4d.bus.registry import aliases, available, shadowed

    kinds = available()
    names = aliases(kinds)
    rows = []
    for name, others in sorted(names.items()):
        kind = kinds[name]
        origin = "touch4d" if kind.origin == "touch4d" else f"{kind.origin} ({kind.target})"
        try:
            doc = (kind.load().__doc__ or "").strip().splitlines()[:1]
        except Exception as exc:  # noqa: BLE001 - another package's node may fail to import: say so, go on
            doc = [f"cannot be imported: {type(exc).__name__}: {exc}"]
        label = name + (f" (alias {', '.join(others)})" if others else "")
        rows.append((label, origin, doc[0] if doc else ""))
    width = max(len(r[0]) for r in rows)
    owidth = max(len(r[1]) for r in rows)
    print(f"{'node'.ljust(width)}  {'from'.ljust(owidth)}  what")
    for label, origin, doc in rows:
        print(f"{label.ljust(width)}  {origin.ljust(owidth)}  {doc}")
    for kind in shadowed():
        print(f"(not listed: '{kind.name}' of the {kind.origin} ({kind.target}): a built-in node has that name; "
              f"launch it as node: {kind.target})")
    print("Any importable module holding a Node class also launches by its path, e.g. node: mylab.nodes.my_tracker.")
    return 0


def _node_info(args) -> int:
    from touch4d.bus.registry import NodeNotFound, available, find

    try:
        kind = find(args.node)
        node_class = kind.load()
    except NodeNotFound as exc:
        raise ConfigError("command line", "node", exc.expected, got=exc.got) from None
    doc = (node_class.__doc__ or "").strip().splitlines()
    others = [n for n, k in available().items() if k.target == kind.target and k.origin == kind.origin and n != kind.name]
    print(f"{kind.name}: {node_class.__module__}.{node_class.__qualname__} ({kind.origin})"
          + (f"; also named {', '.join(sorted(others))}" if others else ""))
    if doc:
        print(f"  {doc[0]}")
    if not node_class.PARAMS:
        print("  no parameters")
    for name, param in node_class.PARAMS.items():
        default = json.dumps(param.default)
        print(f"  {name}: {param.describe()}; default {default}" + (f" - {param.doc}" if param.doc else ""))
    return 0


def _node_run(args) -> int:
    from touch4d.bus.process import main

    return main([args.module, *args.args])


def _broker(args) -> int:
    from touch4d.bus.broker import Broker

    Broker(user_bus_config(args.bus)).run()
    return 0


def _keygen(args) -> int:
    from touch4d.bus.keys import HOWTO, keygen

    public, secret = keygen(args.dir, args.name)
    print(HOWTO.format(public=public, secret=secret))
    return 0

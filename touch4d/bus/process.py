"""One node process: `run_node` builds a node from its command line and spins it until a signal.

The launcher starts each node as `python -u -m touch4d.bus NODE --name ROLE --params JSON`, NODE
as its launch file names it (touch4d.bus.registry finds the class). Once the node is built the
process freezes its start-up heap (touch4d.bus.heap) and tells the launcher it is ready (a byte on
the pipe `$TOUCH4D_READY_FD`); one that exits before that failed to start. A launch file's
`group` runs several nodes in one process (`python -m touch4d.bus --group NAME --nodes JSON`) on one
executor, ready once all are built. SIGINT/SIGTERM make
`spin` return, then `on_shutdown` runs before the sockets close and the process exits 0; a bad
parameter or config exits 2.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys

import zmq

from touch4d.bus.config import resolve_bus_config
from touch4d.bus.executor import Executor
from touch4d.bus.heap import freeze_startup_heap
from touch4d.bus.startup import GroupError, configure, group_members, tell_ready
from touch4d.errors import Touch4dError, Unavailable


def parse_node_args(argv: list[str] | None, default_name: str | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog=default_name or "node", description="Run one touch4d node.")
    parser.add_argument("--name", help="node name (its role in the launch file)")
    parser.add_argument("--kind", help="the node's name in launch files, for heartbeats")
    parser.add_argument("--params", default="{}", help="parameters as a JSON object")
    parser.add_argument("--params-source", help="where the parameters came from (for error messages)")
    parser.add_argument("--bus", help="bus config file (default: $TOUCH4D_BUS, else config/bus.yaml)")
    parser.add_argument("--namespace", default="", metavar="NS", help="put every topic of the node under NS/")
    parser.add_argument("--log-level", default=os.environ.get("TOUCH4D_LOG_LEVEL", "INFO"))
    parser.add_argument("--realtime", action="store_true",
                        help="run with real-time (SCHED_FIFO) priority when permitted (root or CAP_SYS_NICE)")
    return parser.parse_args(argv)


def run_node(node_class, argv: list[str] | None = None) -> int:
    """Build `node_class` from the command line, spin it until SIGINT/SIGTERM, shut it down; returns
    the exit code (0 after a clean stop, 2 when the node's parameters or config are wrong, 1 when
    something it needs is unavailable)."""
    args = parse_node_args(sys.argv[1:] if argv is None else argv, getattr(node_class, "__name__", None))
    name = args.name or node_class.__name__
    configure(args, name)
    params = _params_object(args.params, f"node {args.name}: --params")
    if params is None:
        return 2
    kwargs = {"params": params, "kind": args.kind, "params_source": args.params_source, "namespace": args.namespace}
    if args.name:
        kwargs["role"] = args.name
    return _run([(name, node_class, kwargs)], args.bus, shared=False)


def run_group(argv: list[str]) -> int:
    """`python -m touch4d.bus --group NAME --nodes JSON`: several nodes in one process, on one
    executor (one thread: node code still needs no locks). JSON: a list of {"node": NODE, "name":
    ROLE, "params": {...}, "params_source": FILE}, built in order. The exit codes are `run_node`'s;
    the process stops (and its launcher restarts it whole) when any of its nodes asks to."""
    parser = argparse.ArgumentParser(prog="touch4d.bus --group", description="Run several touch4d nodes in one process.")
    parser.add_argument("--group", required=True, help="the group's name (its launch file's `group`)")
    parser.add_argument("--nodes", required=True, help="the nodes, as a JSON list")
    parser.add_argument("--bus", help="bus config file (default: $TOUCH4D_BUS, else config/bus.yaml)")
    parser.add_argument("--namespace", default="", metavar="NS", help="put every topic of the nodes under NS/")
    parser.add_argument("--log-level", default=os.environ.get("TOUCH4D_LOG_LEVEL", "INFO"))
    parser.add_argument("--realtime", action="store_true", help="as for one node")
    args = parser.parse_args(argv)
    configure(args, args.group)

    entries = _params_object(args.nodes, f"group {args.group}: --nodes", list)
    if entries is None:
        return 2
    try:
        members, private = group_members(entries, args.namespace, f"group {args.group}: --nodes")
    except GroupError as exc:
        print(exc, file=sys.stderr)
        return 2
    return _run(members, args.bus, shared=True, private=private)


def _params_object(text: str, where: str, kind: type = dict):
    """`text` parsed as a JSON object (or list), or None after saying what was wrong on stderr."""
    try:
        value = json.loads(text)
        if not isinstance(value, kind):
            raise ValueError(f"not a{'n object' if kind is dict else ' list'}")
    except ValueError as exc:
        print(f"{where}: expected a JSON {'object' if kind is dict else 'list'}, got {text!r} ({exc})", file=sys.stderr)
        return None
    return value


def _run(members: list[tuple[str, type, dict]], bus_file: str | None, shared: bool, private=()) -> int:
    """Build the nodes `members` names (name, class, constructor arguments) in order, spin them until
    SIGINT/SIGTERM, shut them down in reverse order. `shared`: on one executor (a group), which keeps
    the bus topics `private` in the process (touch4d.bus.local)."""
    executor = Executor() if shared else None
    if executor is not None:
        executor.local.private = frozenset(t.encode() for t in private)
    built: list = []
    # Handlers go in before the nodes are built: a stop that arrives meanwhile is kept for later.
    holder: dict = {"stop": False}

    def stop(signum, frame):
        holder["stop"] = True
        target = executor or (built[0] if built else None)
        if target is not None:
            target.request_shutdown()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)
    name = members[0][0]
    try:
        try:
            bus = resolve_bus_config(bus_file)
            for name, node_class, kwargs in members:
                built.append(node_class(**kwargs, bus=bus, **({"executor": executor} if shared else {})))
        except Unavailable as exc:   # a package, device or service it needs is not there
            print(f"node {name}: {exc}", file=sys.stderr)
            return 1
        except Touch4dError as exc:
            print(f"node {name}: {exc}", file=sys.stderr)
            return 2
        freeze_startup_heap()   # a full collection over it would stall the loop for tens of ms
        tell_ready()
        if holder["stop"]:
            (executor or built[0]).request_shutdown()
        (executor or built[0]).spin()
    finally:
        for node in reversed(built):
            node.shutdown()
        if executor is not None:
            executor.close()
        # Wait (up to the publisher's 1 s linger) until what on_shutdown published has left.
        zmq.Context.instance().destroy(linger=1000)
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m touch4d.bus NODE [node args]`: run the node NODE names (touch4d.bus.registry);
    `python -m touch4d.bus --group NAME --nodes JSON ...`: several in one process (`run_group`);
    `python -m touch4d.bus --container NAME`: groups loaded and unloaded while it runs (touch4d.bus.container)."""
    from touch4d.bus.registry import NodeNotFound, find

    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--group":
        return run_group(argv)
    if argv and argv[0] == "--container":
        from touch4d.bus.container import run_container

        return run_container(argv)
    if not argv or argv[0].startswith("-"):
        print("usage: python -m touch4d.bus NODE [--name N] [--params JSON] ...", file=sys.stderr)
        return 2
    ref, rest = argv[0], argv[1:]
    if "--kind" not in rest:
        rest = [*rest, "--kind", ref]
    try:
        node_class = find(ref).load()
    except NodeNotFound as exc:
        print(f"node {ref!r}: {exc}", file=sys.stderr)
        return 2
    return run_node(node_class, rest)


def main_for_module(module: str) -> None:
    """`python -m touch4d.nodes.NAME [node args]`: a node module run as a script runs its node (and
    exits with its code) instead of declaring the class and exiting 0 having done nothing."""
    sys.exit(main([module, *sys.argv[1:]]))


if __name__ == "__main__":
    sys.exit(main())

"""What `touch4d launch` settles before it starts any node: every file a node parameter names is
found, once, and every port a node serves on is free.

A path parameter (`Param(..., path="scene file")`) is resolved by touch4d.configfile.resolve_path
against the file that set it (the launch file, an included file or the command line), so a path in
an included file elsewhere is found beside that file; the node process gets the absolute path. A
path found nowhere stops the launch with an error naming that file (or the override) and key, the
places looked and a close name. A port parameter (`Param(..., port=True)`) is tried on the node's
`host` parameter (loopback without one); one in use, or wanted by two nodes, stops it the same way.
"""
from __future__ import annotations

import errno
import os
import pickle
import socket
import sys

from touch4d.bus import registry
from touch4d.bus.launchfile import NodeSpec, load_launch
from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError


def where(spec: NodeSpec, name: str) -> tuple[str, str]:
    """(file or "command line", key) where parameter `name` of `spec` was set; for a default, the
    file that names the node."""
    return spec.param_sources.get(name, (spec.source, f"nodes.{spec.role}.params.{name}"))


def resolve_paths(nodes: dict[str, NodeSpec]) -> None:
    """Find every path parameter of every node (given or default) and hand it to the node as an
    absolute path; a PathNotFound (a ConfigError) otherwise."""
    for spec in nodes.values():
        declared = registry.find(spec.module).load().PARAMS
        for name, param in declared.items():
            if not param.path:
                continue
            given = name in spec.params
            value = spec.params[name] if given else param.default
            if not value:   # "" or null: no file (the node's default, if any)
                continue
            source, key = where(spec, name) if given else (spec.source, f"nodes.{spec.role}.params.{name}")
            # A default is the node's own (config/..., found in the current directory or packaged),
            # never relative to a launch file that did not write it.
            spec.params[name] = str(resolve_path(value, source if given else None, key=key, what=param.path_what))


def check_ports(nodes: dict[str, NodeSpec]) -> None:
    """Every port parameter free on its node's host, and no port wanted by two nodes."""
    wanted: dict[tuple[str, int], str] = {}
    for role, spec in nodes.items():
        declared = registry.find(spec.module).load().PARAMS
        for name, param in declared.items():
            if not param.port:
                continue
            port = spec.params.get(name, param.default)
            if not port:
                continue   # 0: any free port
            host = spec.params.get("host", declared["host"].default) if "host" in declared else "127.0.0.1"
            source, key = where(spec, name)
            other = wanted.get((host, port))
            if other is not None:
                raise ConfigError(source, key, f"a port no other node of this launch serves on", got=port,
                                  detail=f"node '{other}' serves on {host}:{port} too; give one of them another "
                                         f"port ({role}.{name}:=PORT, or 0 for any free one)")
            wanted[(host, port)] = role
            problem = port_problem(host, port)
            if problem:
                raise ConfigError(source, key, f"a TCP port free on {host}", got=port,
                                  detail=f"{problem}; choose another with {role}.{name}:=PORT (0: any free "
                                         f"one), or stop what holds it")


def port_problem(host: str, port: int) -> str | None:
    """Why `port` cannot be served on `host` (e.g. another program holds it), or None when it can."""
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            # As a server binds it (SO_REUSEADDR): a port left in TIME_WAIT by the last run is free.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            return f"port {port} on {host} is in use by another program (another touch4d launch?)"
        return f"port {port} on {host} cannot be served: {exc.strerror or exc}"
    return None


def check_launch(nodes: dict[str, NodeSpec]) -> None:
    """Everything the launcher settles before any node starts (see the module doc)."""
    resolve_paths(nodes)
    check_ports(nodes)




def load_checked(path, overrides: list[str] = (), namespace: str | None = None) -> dict[str, NodeSpec]:
    """`load_launch` and `check_launch` in a forked child, the specs back through a pipe: checking
    the parameters imports every node's module (numpy, scipy, aiohttp: ~70 MB) that the launcher
    never uses again, once per launch (a study server runs one per participant). A child that
    fails: the same checks here, so that the error is raised where it is found."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.close(r)
            with os.fdopen(w, "wb") as out:
                nodes = load_launch(path, overrides, namespace=namespace)
                check_launch(nodes)
                pickle.dump(nodes, out)
            code = 0
        except BaseException:  # noqa: BLE001 - the parent checks again and raises it
            pass
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    if os.waitstatus_to_exitcode(status) == 0:
        return pickle.loads(data)
    nodes = load_launch(path, overrides, namespace=namespace)
    check_launch(nodes)
    return nodes

"""Launch files: which nodes to run, with which parameters; includes and command-line overrides.

```yaml
include: [base.yaml]          # merged first (found by touch4d.configfile.resolve_path); may nest
ns: P07                       # every topic of this launch under P07/ (touch4d.bus.names); optional
nodes:
  tracker:                    # the role (node name)
    node: scripted_tracker    # a built-in node, an installed one (entry point), or mylab.nodes.x
    params: {rate: 90}        # merged over the included file's params for this role
    params_for:               # parameters for other modules swapped into this role
      replay: {file: session.mcap}
    respawn: false            # restart it when it dies
    respawn_delay: 0.5        # seconds before a restart
    realtime: false           # SCHED_FIFO priority for the haptic loop, when permitted (in a
                              # container: its loop thread alone, touch4d.bus.container)
    group: participant        # run in one process with the other nodes of this group; optional
    private: [hand/pose]      # topics its group keeps to itself (with `group` only); optional
```
Overrides on the command line: `ROLE:=NODE` swaps a node, `+ROLE:=NODE` adds one, `ROLE:=none`
removes one, `ROLE.PARAM:=VALUE` sets a parameter (VALUE read as YAML). A swap to another node drops
the role's `params` (they belong to the node it replaces: `rate` is Hz for a tracker but a speed
factor for replay) and takes that node's `params_for` entry instead. `ns` is the launched file's (an
included file's is not used); `touch4d launch FILE --namespace NS` replaces it.

Nodes of one `group` share a process and its one thread (touch4d.bus.process.run_group): less
memory and no copies between processes, but a node that blocks holds up the others. The group is
one process to the launcher: it respawns (whole) if any of its nodes says `respawn`, after the
longest `respawn_delay` of its nodes, and is realtime if any of them is. Without `group`, each node
is a process of its own. A group's `private` topics (the union of its nodes' lists) stay in its
process: published there, they go to its subscribers in-process and never to the broker, and its
nodes do not listen for them on the broker (touch4d.bus.local): what a served participant's haptic
loop saves, at the price of no other process hearing them (no `topic echo`, no recorder outside).

Everything is checked before any process starts: every role an override names exists, every node
exists, and every parameter is one the node declares (`PARAMS`), with a valid value.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import msgspec

from touch4d import schema
from touch4d.bus import names, registry
from touch4d.bus.params import check_params, suggest
from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError


class NodeEntry(msgspec.Struct, forbid_unknown_fields=True):
    """One role of a launch file, as written; a key left out keeps what an included file set."""

    node: Annotated[str, msgspec.Meta(description="a node name (`touch4d node list`) or a module path")] | None = None
    params: dict[str, Any] | None = None
    params_for: dict[str, dict[str, Any]] | None = None   # node module -> its parameters in this role
    respawn: bool | None = None
    respawn_delay: Annotated[float, msgspec.Meta(ge=0, le=schema.FINITE_MAX, description="seconds >= 0")] | None = None
    realtime: bool | None = None
    group: Annotated[str, msgspec.Meta(description="a group name: the nodes of one group share a process")] | None = None
    private: list[str] | None = None   # topics the node's group keeps in its process


class LaunchFile(msgspec.Struct, forbid_unknown_fields=True):
    """A launch file, as written (see the module doc)."""

    include: str | list[str] = []
    ns: str = ""
    nodes: dict[str, NodeEntry] = {}


@dataclass
class NodeSpec:
    """One node of a launch: its role, module, parameters and restart policy."""

    role: str
    module: str | None = None
    params: dict = field(default_factory=dict)
    params_for: dict = field(default_factory=dict)  # module -> params, used when swapped in
    respawn: bool = False
    respawn_delay: float = 0.5
    realtime: bool = False
    namespace: str = ""         # every topic of the node under NAMESPACE/ (touch4d.bus.names)
    group: str = ""             # the nodes of one group share a process; "": a process of its own
    group_source: str = ""      # the file that set `group`
    private: list = field(default_factory=list)   # topics its group keeps in its process (touch4d.bus.local)
    source: str = COMMAND_LINE  # the file that last set this node's module or parameters
    # parameter -> (where it was set, its key there): a file and nodes.ROLE.params.NAME, or the override
    param_sources: dict = field(default_factory=dict)


def load_launch(path: str | Path, overrides: list[str] = (), namespace: str | None = None) -> dict[str, NodeSpec]:
    """Read a launch file with its includes, apply command-line overrides and check the result:
    every node exists and gets only parameters it declares, with valid values. `path` and the
    includes are found by `resolve_path` (an include relative to its including file after the
    current directory). `namespace` (`--namespace`) replaces the file's `ns`."""
    nodes: dict[str, NodeSpec] = {}
    path = resolve_path(path, COMMAND_LINE, key="launch file", what="launch file")
    ns = _merge_file(path, nodes, stack=())
    source, key = (path, "ns") if namespace is None else (COMMAND_LINE, "--namespace")
    try:
        ns = names.check_namespace(ns if namespace is None else namespace)
    except ValueError as exc:
        raise ConfigError(source, key, names.EXPECTED, got=ns if namespace is None else namespace) from None
    apply_overrides(nodes, overrides, launch_file=str(path))
    for spec in nodes.values():
        spec.namespace = ns
    for role, spec in nodes.items():
        if spec.module is None:
            raise ConfigError(spec.source, f"nodes.{role}.node", "a node (the role is not defined by any included file)")
        node_class = _load_node(spec.source, f"nodes.{role}.node", spec.module)
        _check_params(node_class, spec, spec.params, f"node {spec.module} (role '{role}' of {path})")
    processes(nodes)   # a group that clashes with a role: refused here, before anything starts
    return nodes


def _load_node(source, key: str, ref: str):
    """The class of node `ref`, or a ConfigError at `source`/`key` saying what is available."""
    try:
        return registry.find(ref).load()
    except registry.NodeNotFound as exc:
        raise ConfigError(source, key, exc.expected, got=exc.got) from None


def _check_params(node_class, spec: NodeSpec, params: dict, owner: str) -> None:
    def error(name, expected, got):
        source, key = spec.param_sources.get(name, (spec.source, f"nodes.{spec.role}.params.{name}"))
        return ConfigError(source, key, expected, got=got)

    check_params(node_class.PARAMS, params, error, owner)


def _merge_file(path: Path, nodes: dict[str, NodeSpec], stack: tuple[Path, ...]) -> str:
    """Merge a launch file (its includes first) into `nodes`; returns its `ns`."""
    path = path.resolve()
    if path in stack:
        raise ConfigError(stack[-1], "include", "no include cycle", got=str(path))
    try:
        text = path.read_text()
    except OSError as exc:
        where = stack[-1] if stack else COMMAND_LINE
        raise ConfigError(where, "include" if stack else "launch file", "a readable launch file",
                          got=f"{path} ({exc.strerror})") from None
    data = schema.parse_yaml(text, path)
    spec = schema.convert({} if data is None else data, LaunchFile, path)
    includes = [spec.include] if isinstance(spec.include, str) else spec.include
    for i, inc in enumerate(includes):
        _merge_file(resolve_path(inc, path, key=f"include[{i}]", what="launch file"), nodes, (*stack, path))
    for role, entry in spec.nodes.items():
        _merge_node(path, role, entry, nodes)
    return spec.ns


def _merge_node(path: Path, role: str, entry: NodeEntry, nodes: dict[str, NodeSpec]) -> None:
    where = f"nodes.{role}"
    _check_role(path, where, role)
    spec = nodes.get(role) or NodeSpec(role, source=str(path))
    if entry.node is not None:
        if spec.module is not None and spec.module != entry.node:
            _swap(spec, entry.node)  # the params belong to the node this file replaces
        spec.module = entry.node
        spec.source = str(path)
    if entry.params is not None:
        spec.params = {**spec.params, **entry.params}
        spec.param_sources.update({k: (str(path), f"{where}.params.{k}") for k in entry.params})
        spec.source = str(path)
    if entry.params_for is not None:
        for module, params in entry.params_for.items():
            node_class = _load_node(path, f"{where}.params_for.{module}", module)
            check_params(node_class.PARAMS, params, lambda name, expected, got, m=module: ConfigError(
                path, f"{where}.params_for.{m}.{name}", expected, got=got), f"node {module}")
        spec.params_for = {**spec.params_for, **{k: dict(v) for k, v in entry.params_for.items()}}
    if entry.respawn is not None:
        spec.respawn = entry.respawn
    if entry.realtime is not None:
        spec.realtime = entry.realtime
    if entry.respawn_delay is not None:
        spec.respawn_delay = entry.respawn_delay
    if entry.group is not None:
        if entry.group:
            _check_role(path, f"{where}.group", entry.group, "a group name")
        spec.group, spec.group_source = entry.group, str(path)
    if entry.private is not None:
        for i, topic in enumerate(entry.private):
            # the stop and the heartbeats reach every process, always (safety, the monitor)
            if not topic or topic.startswith(("_bus/", "/")) or topic in names.GLOBAL_TOPICS | names.BROADCAST_TOPICS:
                raise ConfigError(path, f"{where}.private[{i}]", "a topic of the node's namespace (not _bus/..., "
                                  "absolute, the heartbeats or the stop)", got=topic)
        spec.private = list(entry.private)
    nodes[role] = spec


def _check_role(source, key: str, role: str, what: str = "a role name") -> None:
    if not role.replace("_", "").replace("-", "").isalnum():
        raise ConfigError(source, key, f"{what} of letters, digits, '_' or '-'", got=role)


def processes(nodes: dict[str, NodeSpec]) -> dict[str, list[NodeSpec]]:
    """The processes a launch runs, by name: each group's nodes (in launch-file order) under the
    group's name, each other node alone under its role. A group named like another node's role is
    refused (the launcher's output and `touch4d node list` name processes by it)."""
    out: dict[str, list[NodeSpec]] = {}
    for role, spec in nodes.items():
        name = spec.group or role
        if spec.private and not spec.group:
            raise ConfigError(spec.source, f"nodes.{role}.private", "a `group` for the node (private topics stay "
                              "in a group's process)", got=spec.private)
        if spec.group and spec.group in nodes and nodes[spec.group].group != spec.group:
            raise ConfigError(spec.group_source, f"nodes.{role}.group",
                              "a group name that is not the role of a node outside the group", got=spec.group)
        out.setdefault(name, []).append(spec)
    return out


def group_entries(specs: list[NodeSpec]) -> list[dict]:
    """A group's nodes as its process (or a container) is given them: `--nodes`'s JSON list
    (touch4d.bus.process.group_members reads it)."""
    return [{"node": s.module, "name": s.role, "params": s.params, "params_source": s.source,
             **({"private": s.private} if s.private else {}), **({"realtime": True} if s.realtime else {})}
            for s in specs]


def apply_overrides(nodes: dict[str, NodeSpec], overrides, launch_file: str = "the launch file") -> None:
    """Apply `ROLE:=NODE`, `+ROLE:=NODE`, `ROLE:=none` and `ROLE.PARAM:=VALUE` to `nodes`, in order."""
    removed: list[str] = []          # roles an earlier `ROLE:=none` took out: still what a typo may mean
    for arg in overrides:
        target, sep, text = arg.partition(":=")
        if not sep or not target:
            raise ConfigError(COMMAND_LINE, arg, "ROLE:=NODE, +ROLE:=NODE, ROLE:=none or ROLE.PARAM:=VALUE")
        adding = target.startswith("+")
        role, dot, param = target.removeprefix("+").partition(".")
        if adding:
            if dot or text == "none" or role in nodes:
                raise ConfigError(COMMAND_LINE, arg, f"+ROLE:=NODE with a new role (the roles of {launch_file}: "
                                                     f"{', '.join(nodes) or 'none'})", got=target)
            _check_role(COMMAND_LINE, arg, role)
            _load_node(COMMAND_LINE, arg, text)
            nodes[role] = NodeSpec(role, module=text, source=COMMAND_LINE)
            continue
        if role not in nodes:
            near = suggest(role, [*nodes, *removed])
            gone = next((r for r in removed if f"'{r}'" in near), None)
            if gone:
                near = near[:-1] + f" an earlier {gone}:=none removed it)"
            raise ConfigError(COMMAND_LINE, arg, f"a role of {launch_file} (one of: {', '.join(nodes) or 'none'})"
                              f"{near}; +ROLE:=NODE adds a node", got=role)
        spec = nodes[role]
        if dot:
            try:
                value = schema.parse_yaml(text) if text else ""
            except ConfigError as exc:   # the YAML problem whole, on one line
                raise ConfigError(COMMAND_LINE, arg, "a YAML value", got=text, detail=exc.detail) from None
            spec.params = {**spec.params, param: value}
            spec.param_sources = {**spec.param_sources, param: (COMMAND_LINE, arg)}
        elif text == "none":
            del nodes[role]
            removed.append(role)
        else:
            _load_node(COMMAND_LINE, arg, text)
            if spec.module != text:
                _swap(spec, text)
            spec.module = text


def _swap(spec: NodeSpec, node: str) -> None:
    """Another node takes the role: its own `params_for` entry replaces the role's parameters."""
    spec.params = dict(spec.params_for.get(node, {}))
    spec.param_sources = {k: (spec.source, f"nodes.{spec.role}.params_for.{node}.{k}") for k in spec.params}

"""Launch files: which nodes to run, with which parameters; includes and command-line overrides.

```yaml
include: [base.yaml]          # merged first (found by touch4d.configfile.resolve_path); may nest
nodes:
  tracker:                    # the role (node name)
    node: scripted_tracker    # a built-in node, an installed one (entry point), or mylab.nodes.x
    params: {rate: 90}        # merged over the included file's params for this role
    params_for:               # parameters for other modules swapped into this role
      replay: {file: session.mcap}
    respawn: false            # restart it when it dies
    respawn_delay: 0.5        # seconds before a restart
    realtime: false           # SCHED_FIFO priority for the haptic loop, when permitted
```
Overrides on the command line: `ROLE:=NODE` swaps a node, `+ROLE:=NODE` adds one, `ROLE:=none`
removes one, `ROLE.PARAM:=VALUE` sets a parameter (VALUE read as YAML). A swap to another node drops
the role's `params` (they belong to the node it replaces: `rate` is Hz for a tracker but a speed
factor for replay) and takes that node's `params_for` entry instead.

Everything is checked before any process starts: every role an override names exists, every node
exists, and every parameter is one the node declares (`PARAMS`), with a valid value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from touch4d.bus import registry
from touch4d.bus.params import check_params, suggest
from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError

_FILE_KEYS = {"include", "nodes"}
_NODE_KEYS = {"node", "params", "params_for", "respawn", "respawn_delay", "realtime"}


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
    source: str = COMMAND_LINE  # the file that last set this node's module or parameters
    # parameter -> (where it was set, its key there): a file and nodes.ROLE.params.NAME, or the override
    param_sources: dict = field(default_factory=dict)


def load_launch(path: str | Path, overrides: list[str] = ()) -> dict[str, NodeSpec]:
    """Read a launch file with its includes, apply command-line overrides and check the result:
    every node exists and gets only parameters it declares, with valid values. `path` and the
    includes are found by `resolve_path` (an include relative to its including file after the
    current directory)."""
    nodes: dict[str, NodeSpec] = {}
    path = resolve_path(path, COMMAND_LINE, key="launch file", what="launch file")
    _merge_file(path, nodes, stack=())
    apply_overrides(nodes, overrides, launch_file=str(path))
    for role, spec in nodes.items():
        if spec.module is None:
            raise ConfigError(spec.source, f"nodes.{role}.node", "a node (the role is not defined by any included file)")
        node_class = _load_node(spec.source, f"nodes.{role}.node", spec.module)
        _check_params(node_class, spec, spec.params, f"node {spec.module} (role '{role}' of {path})")
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


def _merge_file(path: Path, nodes: dict[str, NodeSpec], stack: tuple[Path, ...]) -> None:
    path = path.resolve()
    if path in stack:
        raise ConfigError(stack[-1], "include", "no include cycle", got=str(path))
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        where = stack[-1] if stack else COMMAND_LINE
        raise ConfigError(where, "include" if stack else "launch file", "a readable launch file", got=f"{path} ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(path, "(file)", "valid YAML", got=str(exc)) from None
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ConfigError(path, "(top level)", "a mapping with 'include' and 'nodes'", got=data)
    for key in data:
        if key not in _FILE_KEYS:
            raise ConfigError(path, str(key), f"one of {sorted(_FILE_KEYS)}", got=key)
    includes = data.get("include") or []
    if isinstance(includes, str):
        includes = [includes]
    if not isinstance(includes, list):
        raise ConfigError(path, "include", "a list of launch file paths", got=includes)
    for i, inc in enumerate(includes):
        if not isinstance(inc, str):
            raise ConfigError(path, f"include[{i}]", "a launch file path", got=inc)
        _merge_file(resolve_path(inc, path, key=f"include[{i}]", what="launch file"), nodes, (*stack, path))
    entries = data.get("nodes") or {}
    if not isinstance(entries, dict):
        raise ConfigError(path, "nodes", "a mapping of role -> node", got=entries)
    for role, entry in entries.items():
        _merge_node(path, str(role), entry, nodes)


def _merge_node(path: Path, role: str, entry, nodes: dict[str, NodeSpec]) -> None:
    where = f"nodes.{role}"
    _check_role(path, where, role)
    if not isinstance(entry, dict):
        raise ConfigError(path, where, "a mapping with 'node' and optional 'params', 'respawn', 'respawn_delay'", got=entry)
    for key in entry:
        if key not in _NODE_KEYS:
            raise ConfigError(path, f"{where}.{key}", f"one of {sorted(_NODE_KEYS)}", got=key)
    spec = nodes.get(role) or NodeSpec(role, source=str(path))
    if "node" in entry:
        if not isinstance(entry["node"], str):
            raise ConfigError(path, f"{where}.node", "a node name (`touch4d node list`) or a module path",
                              got=entry["node"])
        if spec.module is not None and spec.module != entry["node"]:
            _swap(spec, entry["node"])  # the params belong to the node this file replaces
        spec.module = entry["node"]
        spec.source = str(path)
    if "params" in entry:
        params = entry["params"] or {}
        if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
            raise ConfigError(path, f"{where}.params", "a mapping of parameter names to values", got=params)
        spec.params = {**spec.params, **params}
        spec.param_sources.update({k: (str(path), f"{where}.params.{k}") for k in params})
        spec.source = str(path)
    if "params_for" in entry:
        table = entry["params_for"] or {}
        if not isinstance(table, dict) or not all(
            isinstance(k, str) and isinstance(v, dict) for k, v in table.items()
        ):
            raise ConfigError(path, f"{where}.params_for", "a mapping of node module -> parameters", got=table)
        for module, params in table.items():
            node_class = _load_node(path, f"{where}.params_for.{module}", module)
            check_params(node_class.PARAMS, params, lambda name, expected, got, m=module: ConfigError(
                path, f"{where}.params_for.{m}.{name}", expected, got=got), f"node {module}")
        spec.params_for = {**spec.params_for, **{k: dict(v) for k, v in table.items()}}
    if "respawn" in entry:
        if not isinstance(entry["respawn"], bool):
            raise ConfigError(path, f"{where}.respawn", "true or false", got=entry["respawn"])
        spec.respawn = entry["respawn"]
    if "realtime" in entry:
        if not isinstance(entry["realtime"], bool):
            raise ConfigError(path, f"{where}.realtime", "true or false", got=entry["realtime"])
        spec.realtime = entry["realtime"]
    if "respawn_delay" in entry:
        delay = entry["respawn_delay"]
        if isinstance(delay, bool) or not isinstance(delay, (int, float)) or not 0 <= delay < math.inf:
            raise ConfigError(path, f"{where}.respawn_delay", "seconds >= 0", got=delay)
        spec.respawn_delay = float(delay)
    nodes[role] = spec


def _check_role(source, key: str, role: str) -> None:
    if not role.replace("_", "").replace("-", "").isalnum():
        raise ConfigError(source, key, "a role name of letters, digits, '_' or '-'", got=role)


def apply_overrides(nodes: dict[str, NodeSpec], overrides, launch_file: str = "the launch file") -> None:
    """Apply `ROLE:=NODE`, `+ROLE:=NODE`, `ROLE:=none` and `ROLE.PARAM:=VALUE` to `nodes`, in order."""
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
            raise ConfigError(COMMAND_LINE, arg, f"a role of {launch_file} (one of: {', '.join(nodes) or 'none'})"
                              f"{suggest(role, nodes)}; +ROLE:=NODE adds a node", got=role)
        spec = nodes[role]
        if dot:
            try:
                value = yaml.safe_load(text) if text else ""
            except yaml.YAMLError as exc:
                raise ConfigError(COMMAND_LINE, arg, "a YAML value", got=str(exc)) from None
            spec.params = {**spec.params, param: value}
            spec.param_sources = {**spec.param_sources, param: (COMMAND_LINE, arg)}
        elif text == "none":
            del nodes[role]
        else:
            _load_node(COMMAND_LINE, arg, text)
            if spec.module != text:
                _swap(spec, text)
            spec.module = text


def _swap(spec: NodeSpec, node: str) -> None:
    """Another node takes the role: its own `params_for` entry replaces the role's parameters."""
    spec.params = dict(spec.params_for.get(node, {}))
    spec.param_sources = {k: (spec.source, f"nodes.{spec.role}.params_for.{node}.{k}") for k in spec.params}

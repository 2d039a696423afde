"""Launch files: which nodes to run, with which parameters; includes and command-line overrides.

```yaml
include: [base.yaml]          # merged first (found by touch4d.configfile.resolve_path); may nest
nodes:
  tracker:                    # the role (node name)
    node: scripted_tracker    # module in touch4d.nodes
    params: {rate: 90}        # merged over the included file's params for this role
    params_for:               # parameters for other modules swapped into this role
      replay: {file: session.mcap}
    respawn: false            # restart it when it dies
    respawn_delay: 0.5        # seconds before a restart
    realtime: false           # SCHED_FIFO priority for the haptic loop, when permitted
```
Overrides on the command line: `ROLE:=MODULE` swaps (or adds) a node, `ROLE:=none` removes it,
`ROLE.PARAM:=VALUE` sets a parameter (VALUE read as YAML). A swap to another module drops the
role's `params` (they belong to the module it replaces: `rate` is Hz for a tracker but a speed
factor for replay) and takes that module's `params_for` entry instead.
"""
from __future__ import annotations

import importlib.util
import math
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path

import yaml

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


def node_modules() -> list[str]:
    """The node modules available in touch4d.nodes."""
    import touch4d.nodes

    return sorted(m.name for m in pkgutil.iter_modules(touch4d.nodes.__path__) if not m.name.startswith("_"))


def load_launch(path: str | Path, overrides: list[str] = ()) -> dict[str, NodeSpec]:
    """Read a launch file with its includes, apply command-line overrides and check the result.
    `path` and the includes are found by `resolve_path` (an include relative to its including file
    after the current directory)."""
    nodes: dict[str, NodeSpec] = {}
    _merge_file(resolve_path(path, COMMAND_LINE, key="launch file", what="launch file"), nodes, stack=())
    apply_overrides(nodes, overrides)
    for role, spec in nodes.items():
        if spec.module is None:
            raise ConfigError(spec.source, f"nodes.{role}.node", "a node module (the role is not defined by any included file)")
        _check_module(spec.source, f"nodes.{role}.node", spec.module)
    return nodes


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
    if not role.replace("_", "").replace("-", "").isalnum():
        raise ConfigError(path, where, "a role name of letters, digits, '_' or '-'", got=role)
    if not isinstance(entry, dict):
        raise ConfigError(path, where, "a mapping with 'node' and optional 'params', 'respawn', 'respawn_delay'", got=entry)
    for key in entry:
        if key not in _NODE_KEYS:
            raise ConfigError(path, f"{where}.{key}", f"one of {sorted(_NODE_KEYS)}", got=key)
    spec = nodes.get(role) or NodeSpec(role, source=str(path))
    if "node" in entry:
        if not isinstance(entry["node"], str):
            raise ConfigError(path, f"{where}.node", "a node module name in touch4d.nodes", got=entry["node"])
        spec.module = entry["node"]
        spec.source = str(path)
    if "params" in entry:
        params = entry["params"] or {}
        if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
            raise ConfigError(path, f"{where}.params", "a mapping of parameter names to values", got=params)
        spec.params = {**spec.params, **params}
        spec.source = str(path)
    if "params_for" in entry:
        table = entry["params_for"] or {}
        if not isinstance(table, dict) or not all(
            isinstance(k, str) and isinstance(v, dict) for k, v in table.items()
        ):
            raise ConfigError(path, f"{where}.params_for", "a mapping of node module -> parameters", got=table)
        for module in table:
            _check_module(path, f"{where}.params_for.{module}", module)
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


def apply_overrides(nodes: dict[str, NodeSpec], overrides) -> None:
    """Apply `ROLE:=MODULE`, `ROLE:=none` and `ROLE.PARAM:=VALUE` to `nodes`, in order."""
    for arg in overrides:
        target, sep, text = arg.partition(":=")
        if not sep or not target:
            raise ConfigError(COMMAND_LINE, arg, "ROLE:=MODULE or ROLE.PARAM:=VALUE")
        role, dot, param = target.partition(".")
        if dot:
            if role not in nodes:
                raise ConfigError(COMMAND_LINE, arg, f"a role of the launch file (one of {sorted(nodes)})", got=role)
            try:
                value = yaml.safe_load(text) if text else ""
            except yaml.YAMLError as exc:
                raise ConfigError(COMMAND_LINE, arg, "a YAML value", got=str(exc)) from None
            nodes[role].params = {**nodes[role].params, param: value}
        elif text == "none":
            nodes.pop(role, None)
        else:
            _check_module(COMMAND_LINE, arg, text)
            spec = nodes.setdefault(role, NodeSpec(role))
            if spec.module != text:
                spec.params = dict(spec.params_for.get(text, {}))
                spec.source = COMMAND_LINE
            spec.module = text


def _check_module(source, key: str, module: str) -> None:
    ok = module.replace("_", "").isalnum() and not module.startswith("_")
    if ok:
        try:
            ok = importlib.util.find_spec(f"touch4d.nodes.{module}") is not None
        except (ImportError, ValueError):
            ok = False
    if not ok:
        raise ConfigError(source, key, f"a node module in touch4d.nodes (one of: {', '.join(node_modules()) or 'none yet'})",
                          got=module)

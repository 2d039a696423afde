"""Which node a launch file's `node:` names: an entry point of the group `touch4d.nodes` (touch4d
declares its own nodes there, in its pyproject.toml, like any other package), or a module path.

    node: scripted                       # touch4d's: scripted = "touch4d.nodes.scripted_tracker"
    node: leap                           # [project.entry-points."touch4d.nodes"] leap = "mylab.nodes.leap_tracker"
    node: mylab.nodes.leap_tracker       # any importable module (or "module:Class")

A node module holds one Node subclass (or names it `NODE = Class` when it holds several or
re-exports one). touch4d's names come first, then other packages', then module paths. Two names
for one module are aliases (`scripted` and `scripted_tracker`).
"""
from __future__ import annotations

import functools
import importlib
import importlib.metadata
import importlib.util
import inspect
import sys
from dataclasses import dataclass

from touch4d.bus.params import suggest
from touch4d.errors import Touch4dError
from touch4d.targets import MissingAttribute, load_target

ENTRY_POINT_GROUP = "touch4d.nodes"
BUILT_IN = "touch4d"
NODES_PACKAGE = "touch4d.nodes"   # where touch4d's own node modules live (found by entry point, never imported here)


class NodeNotFound(Touch4dError, ValueError):
    """A node reference that names no node: `expected` says what would, `got` what was found."""

    def __init__(self, expected: str, got=None):
        self.expected = expected
        self.got = got
        super().__init__(f"expected {expected}" + (f", got {got}" if got is not None else ""))


@dataclass(frozen=True)
class NodeKind:
    """A node that can be launched: its name in launch files, what to import, where it comes from."""

    name: str
    target: str  # "package.module" or "package.module:Class"
    origin: str  # "touch4d", "entry point of DIST VERSION" or "module path"

    def load(self):
        """The node class (imports its module)."""
        from touch4d.bus.node import Node

        module_name, _, attr = self.target.partition(":")
        try:
            obj = load_target(self.target)
        except ModuleNotFoundError as exc:
            if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
                raise NodeNotFound(f"an importable module ({self.origin})", got=f"no module {module_name}") from None
            raise
        except MissingAttribute:
            raise NodeNotFound(f"a node class ({self.origin})", got=f"{module_name} has no {attr}") from None
        if inspect.ismodule(obj):
            obj = node_class_of(obj)
        if not (inspect.isclass(obj) and issubclass(obj, Node)):
            raise NodeNotFound(f"a Node subclass ({self.origin})", got=self.target)
        return obj


def node_class_of(module):
    """The node class a module holds: its `NODE`, else its one Node subclass defined there."""
    from touch4d.bus.node import Node

    explicit = getattr(module, "NODE", None)
    if explicit is not None:
        return explicit
    found = [obj for obj in vars(module).values()
             if inspect.isclass(obj) and issubclass(obj, Node) and obj.__module__ == module.__name__]
    if len(found) != 1:
        what = "no Node subclass" if not found else f"{len(found)} Node subclasses ({', '.join(c.__name__ for c in found)})"
        raise NodeNotFound("a node module holding one Node subclass (or naming it with NODE = TheClass)",
                           got=f"{module.__name__}: {what}")
    return found[0]


def _registered() -> list[NodeKind]:
    """Every entry point of the group, in install order: touch4d's own nodes and other packages'."""
    return list(_scan(tuple(sys.path)))


@functools.lru_cache(maxsize=4)
def _scan(path: tuple[str, ...]) -> tuple[NodeKind, ...]:
    """The entry points installed on `path` (scanning the installed packages takes tens of ms: a
    launch asks once per node, so the answer is kept while sys.path stays the same)."""
    found = []
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        if dist is not None and _normal(dist.name) == BUILT_IN:
            origin = BUILT_IN
        else:
            origin = f"entry point of {dist.name} {dist.version}" if dist is not None else "entry point"
        found.append(NodeKind(ep.name, ep.value.replace(" ", ""), origin))
    return tuple(found)


def _normal(dist_name: str) -> str:
    return dist_name.lower().replace("_", "-").replace(".", "-")


def built_in() -> dict[str, NodeKind]:
    """touch4d's own nodes (its entry points), by name."""
    return {k.name: k for k in _registered() if k.origin == BUILT_IN}


def entry_points() -> dict[str, NodeKind]:
    """Other packages' nodes, by name (the first installed wins a name two declare)."""
    found: dict[str, NodeKind] = {}
    for kind in _registered():
        if kind.origin != BUILT_IN:
            found.setdefault(kind.name, kind)
    return found


def available() -> dict[str, NodeKind]:
    """Every node that can be named by its short name: touch4d's, then other packages' (a name
    touch4d already has is shadowed and left out: see `shadowed`)."""
    return {**entry_points(), **built_in()}


def shadowed() -> list[NodeKind]:
    """Other packages' nodes whose name a node of touch4d already has (launch them by module path)."""
    mine = built_in()
    return [k for name, k in entry_points().items() if name in mine and mine[name] != k]


def aliases(kinds: dict[str, NodeKind]) -> dict[str, list[str]]:
    """Names that launch the same node, grouped: the shortest name -> the others (`desktop` ->
    [`desktop_tracker`]); a name without aliases maps to []."""
    groups: dict[tuple[str, str], list[str]] = {}
    for name, kind in kinds.items():
        groups.setdefault((kind.target, kind.origin), []).append(name)
    out = {}
    for names in groups.values():
        first, *others = sorted(names, key=lambda n: (len(n), n))
        out[first] = sorted(others)
    return out


def find(ref: str) -> NodeKind:
    """The node `ref` names; NodeNotFound listing the available ones (and the closest) otherwise."""
    if not isinstance(ref, str) or not ref or ref.startswith(("_", ".")):
        raise NodeNotFound(_not_found(ref), got=ref)
    kinds = available()
    if ref in kinds:
        return kinds[ref]
    module, _, attr = ref.partition(":")
    if "." in module or attr:
        if all(p.isidentifier() for p in module.split(".")) and all(p.isidentifier() for p in attr.split(".") if attr):
            try:
                spec = importlib.util.find_spec(module)
            except (ImportError, ValueError):
                spec = None
            if spec is not None:
                return NodeKind(ref, ref, "module path")
        raise NodeNotFound(_not_found(ref, f"no importable module {module}"), got=ref)
    raise NodeNotFound(_not_found(ref, names=kinds), got=ref)


def _not_found(ref, why: str = "", names=None) -> str:
    names = available() if names is None else names
    text = f"a node: one of {', '.join(sorted(names))} (`touch4d node list`), or a module path such as " \
           f"mylab.nodes.my_tracker"
    if why:
        text += f" ({why})"
    if not any(k.origin == BUILT_IN for k in names.values()):
        text += ("; touch4d's own nodes are not registered in this installation (its metadata predates "
                 "them): reinstall it with `pip install -e .` or ./dev")
    elif isinstance(ref, str) and ref.isidentifier() and _find_spec(f"{NODES_PACKAGE}.{ref}") is not None:
        text += (f"; {NODES_PACKAGE}.{ref} exists but is not registered: name it in pyproject.toml's "
                 f"[project.entry-points.\"{ENTRY_POINT_GROUP}\"] and reinstall (`pip install -e .` or ./dev)")
    return text + suggest(ref, names)


def _find_spec(module: str):
    try:
        return importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None


def load(ref: str):
    """The node class that `ref` names."""
    return find(ref).load()


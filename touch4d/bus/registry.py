"""Which node a launch file's `node:` names: a module of touch4d.nodes, an entry point another
installed package declares in the group `touch4d.nodes`, or a module path.

    node: scripted                       # touch4d/nodes/scripted.py (a built-in node)
    node: leap                           # [project.entry-points."touch4d.nodes"] leap = "mylab.nodes.leap_tracker"
    node: mylab.nodes.leap_tracker       # any importable module (or "module:Class")

A node module holds one Node subclass (or names it `NODE = Class` when it holds several or
re-exports one). Built-in names come first, then entry points, then module paths.
"""
from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import inspect
import pkgutil
from dataclasses import dataclass

from touch4d.bus.params import suggest
from touch4d.errors import Touch4dError

ENTRY_POINT_GROUP = "touch4d.nodes"
BUILT_IN = "touch4d"


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
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
                raise NodeNotFound(f"an importable module ({self.origin})", got=f"no module {module_name}") from None
            raise
        obj = module
        for part in attr.split(".") if attr else ():
            obj = getattr(obj, part, None)
            if obj is None:
                raise NodeNotFound(f"a node class ({self.origin})", got=f"{module_name} has no {attr}")
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


def built_in() -> dict[str, NodeKind]:
    import touch4d.nodes

    return {m.name: NodeKind(m.name, f"touch4d.nodes.{m.name}", BUILT_IN)
            for m in pkgutil.iter_modules(touch4d.nodes.__path__) if not m.name.startswith("_")}


def entry_points() -> dict[str, NodeKind]:
    found = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep, "dist", None)
        origin = f"entry point of {dist.name} {dist.version}" if dist is not None else "entry point"
        found.setdefault(ep.name, NodeKind(ep.name, ep.value.replace(" ", ""), origin))
    return found


def available() -> dict[str, NodeKind]:
    """Every node that can be named by its short name: built-ins, then entry points (a name a
    built-in already has is shadowed and left out)."""
    return {**entry_points(), **built_in()}


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
    return text + suggest(ref, names)


def load(ref: str):
    """The node class that `ref` names."""
    return find(ref).load()


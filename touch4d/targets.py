"""Objects named by text, "package.module:Attr" (the form of a Python entry point), imported only when
picked: the tables that name what a user chooses by name (renderer backends, board emulators, nodes) keep
each choice's slow imports (moderngl's shaders, the firmware's build, a node's libraries) out of a process
that never picks it, and all use this one form and this one loader."""
from __future__ import annotations

import importlib


class MissingAttribute(AttributeError):
    """The module of a target imported, but holds no such attribute (an AttributeError raised while
    importing the module is not this one)."""


def load_target(target: str):
    """The object `target` names: "package.module" the module, "package.module:Attr.attr" an attribute of
    it. Whatever importing raises (ModuleNotFoundError: its `name` the module missing), or MissingAttribute,
    for the caller to say what was meant."""
    module, _, attr = target.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split(".") if attr else ():
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise MissingAttribute(f"{module} has no {attr}") from None
    return obj

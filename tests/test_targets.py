"""Objects named by text ("package.module:Attr"), imported when picked: the one loader and the tables that
use it (renderer backends, board emulators, nodes)."""
import sys

import pytest

from touch4d.targets import MissingAttribute, load_target


def test_a_target_names_a_module_or_an_attribute_path_in_it():
    import touch4d.errors

    assert load_target("touch4d.errors") is touch4d.errors
    assert load_target("touch4d.errors:ConfigError") is touch4d.errors.ConfigError
    assert load_target("touch4d.errors:ConfigError.__init__") is touch4d.errors.ConfigError.__init__


def test_what_is_missing_is_told_apart_from_what_importing_raised(tmp_path, monkeypatch):
    with pytest.raises(ModuleNotFoundError) as missing:
        load_target("touch4d.no_such_module:Thing")
    assert missing.value.name == "touch4d.no_such_module"
    with pytest.raises(MissingAttribute, match="touch4d.errors has no Nothing.here"):
        load_target("touch4d.errors:Nothing.here")
    (tmp_path / "broken_target_module.py").write_text("import os\nos.no_such_function()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(AttributeError) as raised:      # the module's own failure, not a missing target
        load_target("broken_target_module:Anything")
    assert not isinstance(raised.value, MissingAttribute)
    sys.modules.pop("broken_target_module", None)


def test_every_backend_and_emulator_named_in_a_table_loads():
    from touch4d.boards.emulator import EMULATORS, GloveEmulator
    from touch4d.render.backends import BACKENDS, Backend

    for name, target in BACKENDS.items():
        assert issubclass(load_target(target), Backend), name
    assert load_target(EMULATORS["python"]) is GloveEmulator
    assert load_target(EMULATORS["firmware"]).__name__ == "FirmwareGloveEmulator"


def test_a_node_module_without_the_named_class_is_said_as_such():
    from touch4d.bus.registry import NodeKind, NodeNotFound

    with pytest.raises(NodeNotFound, match="touch4d.errors has no NoNode"):
        NodeKind("x", "touch4d.errors:NoNode", "module path").load()

"""Packaging: every package folder is installed, messages/ and nodes/ import as touch4d.*, the CLI runs."""
import pathlib
import subprocess
import sys
import tomllib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    dirs = config["package-dir"]
    found = set()
    for package, folder in dirs.items():
        base = ROOT / folder
        for init in base.rglob("__init__.py"):
            rel = init.parent.relative_to(base).parts
            name = ".".join((package, *rel))
            if not any(name.startswith(other + ".") and other != package and other in dirs for other in dirs):
                found.add(name)
    assert found <= listed, f"add to pyproject.toml packages: {sorted(found - listed)}"


def test_messages_and_nodes_import_under_touch4d():
    import touch4d.messages
    import touch4d.nodes

    assert pathlib.Path(touch4d.messages.__file__).parent == ROOT / "messages"
    assert pathlib.Path(touch4d.nodes.__file__).parent == ROOT / "nodes"


def test_cli_lists_its_commands_and_rejects_nonsense():
    ok = subprocess.run([sys.executable, "-m", "touch4d.cli", "--help"], capture_output=True, text=True)
    assert ok.returncode == 0 and "COMMAND" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "touch4d.cli", "no-such-command"], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


def test_each_part_registers_exactly_the_commands_the_cli_lists_for_it():
    import argparse
    import importlib

    from touch4d.cli import PARTS

    for module, commands in PARTS.items():
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).register(sub)
        assert set(sub.choices) == set(commands), module

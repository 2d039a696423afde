"""Nodes from other packages: the example package of tests/plugin, installed, launched by its entry
point and by module path, listed with where it comes from, its parameters checked like any node's."""
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.launchfile import load_launch
from touch4d.bus.testing import collect, launch_process, wait_until
from touch4d.errors import ConfigError
from touch4d.messages import HandPose

pytestmark = pytest.mark.timeout(180)
PLUGIN = Path(__file__).resolve().parent / "plugin"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The example package installed (as pip installs any package) into a folder of its own."""
    tmp = tmp_path_factory.mktemp("plugin")
    source = shutil.copytree(PLUGIN, tmp / "src")   # builds leave files beside the sources
    target = tmp / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index",
                    "--target", str(target), str(source)], check=True, timeout=150)
    return target


def launch_file(tmp_path, node: str, params: str = "{amplitude: 0.4, period: 2.0, rate: 50.0}") -> str:
    path = tmp_path / "wave.yaml"
    path.write_text(f"nodes:\n  tracker: {{node: {node}, params: {params}}}\n")
    return str(path)


def assert_waves(run, amplitude=0.4, period=2.0, rate=50.0):
    """Poses from the plugin's node, where its formula (restated here) puts them."""
    with Node("probe", bus=run.wait_ready(timeout=60), heartbeat=False) as probe:
        poses = collect(probe, "hand/pose", HandPose)
        wait_until(lambda: len(poses) >= 10, timeout=60, spin=probe)
    for msg in poses:
        x = amplitude * math.sin(2 * math.pi * msg.seq / (rate * period))
        np.testing.assert_allclose(msg.position, [x, 0.0, 0.0], atol=1e-12)
    assert len({m.seq for m in poses}) == len(poses)
    assert run.stop(timeout=30) == 0


def test_launched_by_its_entry_point(installed, tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(installed))
    with launch_process([launch_file(tmp_path, "wave")]) as run:
        assert_waves(run)
    assert "waving at 50 Hz" in run.text and "waved" in run.text   # setup and on_shutdown ran
    assert "tracker (wave)" in run.text


def test_launched_by_module_path_without_installing(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(PLUGIN))
    with launch_process([launch_file(tmp_path, "touch4d_example_plugin.wave")]) as run:
        assert_waves(run)
    monkeypatch.syspath_prepend(str(PLUGIN))
    from touch4d.bus import registry

    assert registry.load("touch4d_example_plugin.wave:WaveTracker").__name__ == "WaveTracker"
    assert registry.find("touch4d_example_plugin.wave").origin == "module path"


def test_node_list_shows_where_each_node_comes_from(installed, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(installed))
    done = subprocess.run([sys.executable, "-m", "touch4d.cli", "node", "list"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    rows = {line.split()[0]: line for line in done.stdout.splitlines()}
    assert "entry point of touch4d-example-plugin 0.1.0 (touch4d_example_plugin.wave)" in rows["wave"]
    assert "A hand sweeping along x" in rows["wave"]
    assert rows["scripted"].split()[3] == "touch4d"
    # One row per node, its other name shown as an alias; no plugin node called shadowed when none is.
    assert rows["desktop"].startswith("desktop (alias desktop_tracker)") and "desktop_tracker" not in rows
    assert rows["scripted"].startswith("scripted (alias scripted_tracker)") and "scripted_tracker" not in rows
    assert "not listed" not in done.stdout
    info = subprocess.run([sys.executable, "-m", "touch4d.cli", "node", "info", "wave"], capture_output=True,
                          text=True, timeout=60)
    assert "amplitude: a finite number > 0 (screen units); default 0.5" in info.stdout
    info = subprocess.run([sys.executable, "-m", "touch4d.cli", "node", "info", "desktop_tracker"],
                          capture_output=True, text=True, timeout=60)
    assert info.stdout.startswith("desktop_tracker: touch4d.nodes.desktop_tracker.DesktopTracker (touch4d); "
                                  "also named desktop\n")


def test_a_plugin_nodes_parameters_are_checked_before_launch(installed, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(installed))
    path = launch_file(tmp_path, "wave", "{amplitud: 0.4}")
    with pytest.raises(ConfigError) as err:
        load_launch(path)
    assert err.value.key == "nodes.tracker.params.amplitud" and "did you mean 'amplitude'?" in str(err.value)
    with pytest.raises(ConfigError) as err:
        load_launch(launch_file(tmp_path, "wave"), ["tracker.depth:=2"])
    assert "a finite number >= -1 and <= 1 (screen units) for parameter 'depth' of node wave" in str(err.value)
    with pytest.raises(ConfigError, match="did you mean 'wave'"):
        load_launch(launch_file(tmp_path, "wav"))


def test_a_plugin_node_named_like_a_built_in_one_is_reported_shadowed_and_only_then(monkeypatch):
    from touch4d.bus import registry
    from touch4d.bus.registry import NodeKind

    mine = NodeKind("scene", "touch4d.nodes.scene", "touch4d")
    theirs = NodeKind("scene", "mylab.scene", "entry point of mylab 1.0")
    wave = NodeKind("wave", "mylab.wave", "entry point of mylab 1.0")
    # Fresh objects on every call, as importlib.metadata makes them: equal, never identical.
    monkeypatch.setattr(registry, "_registered", lambda: [NodeKind(*vars(k).values()) for k in (wave, theirs, mine)])
    assert registry.available()["scene"] == mine and registry.available()["wave"] == wave
    assert registry.shadowed() == [theirs]


def test_every_node_module_is_registered_as_an_entry_point():
    """A node added to nodes/ without its line in pyproject.toml could not be launched by name."""
    import tomllib

    root = Path(__file__).resolve().parents[1]
    declared = tomllib.loads((root / "pyproject.toml").read_text())["project"]["entry-points"]["touch4d.nodes"]
    modules = {p.stem for p in (root / "nodes").glob("*.py") if not p.stem.startswith("_")}
    assert modules <= {v.rsplit(".", 1)[-1].partition(":")[0] for v in declared.values()}
    from touch4d.bus import registry

    assert {n: k.target for n, k in registry.built_in().items()} == declared   # the installation is current

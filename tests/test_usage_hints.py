"""What a user copies from a comment or tries by habit works, or says what to do instead: the
command lines in the launch files' comments, and `python -m touch4d.nodes.NAME`."""
import pkgutil
import re
import runpy
import sys
from pathlib import Path

import pytest

import touch4d.nodes
from touch4d.bus.launchfile import load_launch

REPO = Path(__file__).resolve().parents[1]


def commented_overrides():
    """(launch file, the overrides of one comment line) for every comment line that shows some."""
    for path in sorted((REPO / "launch").glob("*.yaml")):
        for line in path.read_text().splitlines():
            if line.lstrip().startswith("#"):
                tokens = re.findall(r"[+\w.]+:=[^\s)`,]+", line)
                if tokens:
                    yield path, tokens


@pytest.mark.parametrize("path, overrides", list(commented_overrides()),
                         ids=lambda v: v.name if isinstance(v, Path) else " ".join(v))
def test_every_command_line_in_a_launch_files_comments_is_accepted(path, overrides):
    assert load_launch(path, overrides)


NODE_MODULES = sorted(m.name for m in pkgutil.iter_modules(touch4d.nodes.__path__) if not m.name.startswith("_"))


@pytest.mark.filterwarnings("ignore:.*found in sys.modules:RuntimeWarning")
@pytest.mark.parametrize("name", NODE_MODULES)
def test_every_node_module_run_as_a_script_runs_its_node(name, monkeypatch, capsys):
    # As `python -m touch4d.nodes.NAME --params ...` runs it (runpy, as __main__): the node is built
    # from the command line, so a misspelt parameter is its error, exit code 2.
    monkeypatch.setattr(sys, "argv", [name, "--params", '{"no_such_param": 1}'])
    with pytest.raises(SystemExit) as done:
        runpy.run_module(f"touch4d.nodes.{name}", run_name="__main__")
    assert done.value.code == 2
    assert "no_such_param" in capsys.readouterr().err


def nodes_md_example() -> str:
    text = (REPO / "docs" / "nodes.md").read_text()
    return re.search(r"```python\n(# mylab/nodes/wave.py\n.*?)```", text, re.S).group(1)


def test_the_node_authors_page_says_where_the_screen_is_and_what_the_scene_node_hears():
    text = (REPO / "docs" / "nodes.md").read_text()
    assert "The screen is the cube `[-1, 1]^3`" in text
    assert "The scene node subscribes `controller/state`" in text


def test_the_node_authors_example_uses_every_parameter_it_declares_and_stays_on_the_screen(tmp_path, monkeypatch):
    import numpy as np

    from touch4d.bus import Node
    from touch4d.bus.testing import collect, running_broker, wait_until
    from touch4d.messages import HandPose

    (tmp_path / "wave_example.py").write_text(nodes_md_example())
    monkeypatch.syspath_prepend(str(tmp_path))
    import wave_example

    declared = set(wave_example.WaveTracker.PARAMS)
    used = set(re.findall(r"""self\.params\[["'](\w+)["']\]""", nodes_md_example()))
    assert declared == used, f"declared but never read: {sorted(declared - used)}"
    with running_broker() as bus:
        node = wave_example.WaveTracker(params={"rate": 200.0, "amplitude": 0.9}, bus=bus)
        with Node("probe", bus=bus, heartbeat=False) as probe:
            poses = collect(probe, "hand/pose", HandPose)
            try:
                wait_until(lambda: (node.spin_once(0.005), probe.spin_once(0.0), len(poses) >= 60)[-1], timeout=30)
            finally:
                node.shutdown()
    x = np.array([p.position for p in poses])
    assert np.all(np.abs(x) <= 1.0) and np.ptp(x[:, 0]) > 0.5     # a sweep, inside the screen cube

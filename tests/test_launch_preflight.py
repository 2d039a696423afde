"""What `touch4d launch` settles before any node starts: every path parameter found once, against
the file (or the command line) that set it, and handed to the node absolute; ports free."""
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from touch4d.bus import Broker, BusConfig, Node
from touch4d.bus import launcher as launcher_module
from touch4d.bus.launchfile import load_launch
from touch4d.bus.preflight import check_launch, load_checked
from touch4d.bus.testing import collect, launch_process, wait_until
from touch4d.cli import main
from touch4d.errors import ConfigError
from touch4d.messages import SceneState

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.timeout(120)


@pytest.fixture
def no_node_starts(monkeypatch):
    """Fails the test if the launcher is ever run (a node would then start)."""
    def run(self):
        raise AssertionError("the launcher ran: nodes were started")
    monkeypatch.setattr(launcher_module.Launcher, "run", run)


def included_scene(tmp_path: Path, scene: str) -> Path:
    """top.yaml (in lab/) includes base/base.yaml (in lab/base/), which sets the scene node's path;
    top.yaml touches the scene node last."""
    base = tmp_path / "lab" / "base"
    base.mkdir(parents=True)
    (base / "mine.yaml").write_text((REPO / "config/scenes/tesseract.yaml").read_text())
    (base / "base.yaml").write_text(f"nodes:\n  scene: {{node: scene, params: {{scene: {scene}}}}}\n")
    top = tmp_path / "lab" / "top.yaml"
    top.write_text("include: [base/base.yaml]\nnodes:\n  scene: {params: {rate: 5.0}}\n")
    return top


def test_a_path_set_in_an_included_file_is_found_beside_that_file_and_the_node_gets_it(tmp_path):
    top = included_scene(tmp_path, "mine.yaml")
    nodes = load_launch(top)
    check_launch(nodes)
    assert nodes["scene"].params["scene"] == str(tmp_path / "lab/base/mine.yaml")
    assert Path(nodes["scene"].params["calibration"]).is_absolute()     # defaults too: found once, here
    with launch_process([str(top)], cwd=tmp_path) as run:
        with Node("probe", bus=run.wait_ready(timeout=60), heartbeat=False) as probe:
            states = collect(probe, "scene/state", SceneState)
            wait_until(lambda: states, timeout=30, spin=probe)
        assert run.stop(timeout=30) == 0


def test_a_missing_path_in_an_included_file_is_blamed_on_that_file(tmp_path):
    top = included_scene(tmp_path, "nope.yaml")
    with pytest.raises(ConfigError) as err:
        check_launch(load_launch(top))
    assert err.value.file == str(tmp_path / "lab/base/base.yaml") and err.value.key == "nodes.scene.params.scene"


def test_a_misspelt_path_on_the_command_line_stops_the_launch_before_any_node(monkeypatch, capsys, no_node_starts):
    monkeypatch.chdir(REPO)
    arg = "scene.scene:=config/scenes/hypercub.yaml"
    assert main(["launch", arg]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"touch4d launch: command line: key '{arg}': expected an existing scene file")
    # In a checkout the packaged config/ is the current directory's: one place, said once.
    assert err.count("hypercub.yaml") == 3 and f"looked in {REPO}/config/scenes/hypercub.yaml (" in err
    assert err.endswith("(did you mean 'config/scenes/hypercube.yaml'?)")


def test_a_misspelt_launch_name_suggests_the_close_one(tmp_path, monkeypatch, capsys, no_node_starts):
    monkeypatch.chdir(tmp_path)
    assert main(["launch", "dmeo"]) == 2
    err = capsys.readouterr().err
    assert "got 'dmeo'" in err and "did you mean 'demo'?" in err and "(demo, desktop, example," in err


def test_a_node_port_in_use_stops_the_launch_before_any_node_and_says_so_whole(monkeypatch, capsys, no_node_starts):
    monkeypatch.chdir(REPO)
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        assert main(["launch", "example", "+web:=webxr", f"web.port:={port}"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"command line: key 'web.port:={port}': expected a TCP port free on 127.0.0.1, got {port}: port " \
           f"{port} on 127.0.0.1 is in use by another program (another touch4d launch?); choose another with " \
           f"web.port:=PORT (0: any free one), or stop what holds it" in err
    # Two nodes of one launch on one port: refused too.
    assert main(["launch", "example", "+web:=webxr", "+web2:=webxr", f"web.port:={port}",
                 f"web2.port:={port}"]) == 2
    assert "node 'web' serves on 127.0.0.1:%d too" % port in capsys.readouterr().err


def test_broker_ports_in_use_suggest_other_ports_or_joining_the_running_broker():
    with Broker(BusConfig(pub_port=0, sub_port=0)) as running:
        with pytest.raises(ConfigError) as err:
            Broker(BusConfig(pub_port=running.pub_port, sub_port=running.sub_port, source="config/bus.yaml")).start()
    text = str(err.value)
    assert err.value.key == "broker.pub_port" and f"got {running.pub_port}" in text
    assert "--no-broker" in text and "--bus FILE" in text and "pub_port" in text


def test_the_launcher_checks_in_a_child_and_imports_no_node_module(tmp_path):
    """load_checked gives what load_launch and check_launch give in-process, without the node modules
    (and their libraries) in the launcher's process; an error is the in-process one."""
    code = (
        "import json, sys\n"
        "from touch4d.bus.preflight import load_checked\n"
        "nodes = load_checked('launch/study.yaml', ['study.participant:=P07'], namespace='P07')\n"
        "print(json.dumps({'specs': {r: [s.module, s.namespace, s.params] for r, s in nodes.items()},\n"
        "                  'imported': sorted(m for m in sys.modules if m.startswith('touch4d.nodes.')\n"
        "                                     or m in ('scipy', 'aiohttp', 'numba'))}, default=str))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=100, check=True)
    got = json.loads(out.stdout)
    assert got["imported"] == []
    nodes = load_launch(REPO / "launch/study.yaml", ["study.participant:=P07"], namespace="P07")
    check_launch(nodes)
    expected = {r: [s.module, s.namespace, s.params] for r, s in nodes.items()}
    assert got["specs"] == json.loads(json.dumps(expected, default=str))
    with pytest.raises(ConfigError, match="study.iti_s"):
        load_checked(REPO / "launch/study.yaml", ["study.iti_s:=-1"])

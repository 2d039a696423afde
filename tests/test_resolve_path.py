"""The one resolver of user-given paths: its order, the packaged defaults, and errors that list
every place looked; the command-line flags, launch files and node parameters that use it."""
import json
from pathlib import Path

import pytest

from touch4d.cli import main
from touch4d.configfile import PathNotFound, resolve_path
from touch4d.defaults import ROOT as DEFAULTS

REPO = Path(__file__).resolve().parents[1]


def write(path: Path, text: str = "x: 1\n") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_the_order_is_absolute_then_current_directory_then_naming_file_then_packaged(tmp_path, monkeypatch):
    cwd, lab = tmp_path / "cwd", tmp_path / "lab"
    launch = write(lab / "launch" / "mine.yaml")
    name = "config/scenes/hypercube.yaml"
    monkeypatch.chdir(write(cwd / "placeholder").parent)
    packaged = (DEFAULTS / name).resolve()
    assert resolve_path(name, launch) == packaged                        # 4. the packaged defaults
    beside = write(lab / "launch" / name)
    assert resolve_path(name, launch) == beside                          # 3. beside the naming file
    assert resolve_path(name, str(launch)) == beside                     #    (named by a string too)
    assert resolve_path(name) == packaged                                #    (only when there is one)
    mine = write(cwd / name)
    assert resolve_path(name, launch) == mine                            # 2. the current directory
    assert resolve_path(beside, launch) == beside                        # 1. absolute, as given
    monkeypatch.setenv("HOME", str(lab))
    assert resolve_path("~/launch/mine.yaml") == launch


def test_in_the_repository_the_packaged_defaults_are_its_config_and_launch_folders():
    assert (DEFAULTS / "config").resolve() == REPO / "config"
    assert (DEFAULTS / "launch").resolve() == REPO / "launch"


def test_only_config_and_launch_paths_reach_the_packaged_defaults(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("__init__.py", "config/../__init__.py", "scenes/hypercube.yaml"):
        with pytest.raises(PathNotFound) as err:
            resolve_path(name)
        assert err.value.places == [tmp_path / name]


def test_not_found_names_the_source_the_key_and_every_place(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    launch = write(tmp_path / "launch" / "lab.yaml")
    with pytest.raises(PathNotFound) as err:
        resolve_path("config/scenes/nope.yaml", launch, key="nodes.scene.params.scene", what="scene file")
    places = [tmp_path / "config/scenes/nope.yaml", tmp_path / "launch/config/scenes/nope.yaml",
              (DEFAULTS / "config").resolve() / "scenes/nope.yaml"]
    assert err.value.places == places
    assert (err.value.file, err.value.key) == (str(launch), "nodes.scene.params.scene")
    text = str(err.value)
    assert "expected an existing scene file" in text and all(str(p) in text for p in places)
    for bad in ("", "  ", 3, None):
        with pytest.raises(Exception) as err:
            resolve_path(bad, "command line", key="--scene")
        assert "--scene" in str(err.value) and not isinstance(err.value, TypeError)


def test_command_line_flags_find_the_packaged_files_from_any_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["tactile", "probe", "--scene", "config/scenes/hypercube.yaml", "--glove",
                 "config/gloves/two-motor.yaml", "--position", "0", "0", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [m["name"] for m in out["motors"]] == ["palm-center", "back-center"]
    assert main(["glove", "busload", "--glove", "config/gloves/two-motor.yaml"]) == 0
    assert str(REPO / "config/gloves/two-motor.yaml") in capsys.readouterr().out
    assert main(["tactile", "probe", "--scene", "scenes/hypercube.yaml", "--position", "0", "0", "0"]) == 2
    err = capsys.readouterr().err
    assert "key '--scene'" in err and "looked in" in err and str(tmp_path / "scenes/hypercube.yaml") in err


def test_a_launch_file_and_its_includes_resolve_from_anywhere(tmp_path, monkeypatch):
    from touch4d.bus.launchfile import load_launch

    monkeypatch.chdir(tmp_path)
    nodes = load_launch("launch/desktop.yaml")            # packaged; includes demo.yaml beside it
    assert nodes["tracker"].module == "desktop" and nodes["motors"].module == "motors"
    assert Path(nodes["motors"].source) == REPO / "launch" / "demo.yaml"
    # A copy in the current directory wins, and its includes are found beside it.
    write(tmp_path / "launch" / "desktop.yaml", "include: [base.yaml]\nnodes:\n  tracker: {node: desktop}\n")
    write(tmp_path / "launch" / "base.yaml", "nodes:\n  talker: {node: example_talker}\n")
    assert list(load_launch("launch/desktop.yaml")) == ["talker", "tracker"]


def test_node_path_parameters_resolve_beside_the_launch_file_that_set_them(tmp_path, monkeypatch):
    from touch4d.bus.testing import running_broker
    from touch4d.nodes.scene import SceneNode

    monkeypatch.chdir(tmp_path)
    launch = write(tmp_path / "lab" / "lab.yaml")
    write(tmp_path / "lab" / "cube.yaml", (REPO / "config/scenes/tesseract.yaml").read_text())
    with running_broker() as bus:
        node = SceneNode(bus=bus, params={"scene": "cube.yaml"}, params_source=str(launch), heartbeat=False)
        try:
            assert node.control.scene.objects[0].shape == "tesseract"
        finally:
            node.shutdown()
        with pytest.raises(PathNotFound) as err:
            SceneNode(bus=bus, params={"scene": "nope.yaml"}, params_source=str(launch), heartbeat=False)
    assert (err.value.file, err.value.key) == (str(launch), "nodes.scene.params.scene")
    assert tmp_path / "lab" / "nope.yaml" in err.value.places

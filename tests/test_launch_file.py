"""Launch files: includes with parameter overrides, command-line overrides, errors naming file and key."""
from pathlib import Path

import pytest

from touch4d.bus.launchfile import load_launch
from touch4d.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_include_then_override_parameters(tmp_path):
    write(tmp_path / "base.yaml", "nodes:\n  talker: {node: example_talker, params: {rate: 90.0, topic: a}}\n"
                                  "  listener: {node: example_listener, respawn: true}\n")
    sub = tmp_path / "sub"
    sub.mkdir()
    top = write(sub / "top.yaml", "include: [../base.yaml]\nnodes:\n  talker: {params: {rate: 30.0}}\n"
                                  "  extra: {node: example_listener, params: {delay: 0.1}}\n")
    nodes = load_launch(top)
    assert list(nodes) == ["talker", "listener", "extra"]
    assert nodes["talker"].module == "example_talker"
    assert nodes["talker"].params == {"rate": 30.0, "topic": "a"}
    assert nodes["talker"].source == str(top)
    assert nodes["listener"].respawn is True and nodes["extra"].params == {"delay": 0.1}


def test_command_line_swaps_sets_and_drops_nodes(tmp_path):
    top = write(tmp_path / "l.yaml", "nodes:\n  tracker: {node: example_talker, params: {rate: 90.0}}\n"
                                     "  other: {node: example_listener}\n")
    nodes = load_launch(top, ["tracker:=example_listener", "tracker.delay:=0.5", "tracker.topic:=hand/pose",
                              "tracker.flags:=[1, two]", "other:=none"])
    assert list(nodes) == ["tracker"]
    assert nodes["tracker"].module == "example_listener"
    assert nodes["tracker"].params == {"delay": 0.5, "topic": "hand/pose", "flags": [1, "two"]}


def test_a_swapped_in_module_gets_its_own_params_not_the_replaced_ones(tmp_path):
    top = write(tmp_path / "l.yaml", "nodes:\n  tracker:\n    node: example_talker\n    params: {rate: 90.0}\n"
                                     "    params_for: {example_listener: {delay: 0.25}}\n")
    assert load_launch(top, ["tracker:=example_talker"])["tracker"].params == {"rate": 90.0}
    swapped = load_launch(top, ["tracker:=example_listener", "tracker.topic:=t"])["tracker"]
    assert swapped.module == "example_listener" and swapped.params == {"delay": 0.25, "topic": "t"}
    bad = write(tmp_path / "b.yaml", "nodes:\n  tracker: {node: example_talker, params_for: {nope: {}}}\n")
    with pytest.raises(ConfigError, match="nodes.tracker.params_for.nope"):
        load_launch(bad)


@pytest.mark.parametrize("text, key", [
    ("nodes:\n  tracker: {node: no_such_node}\n", "nodes.tracker.node"),
    ("nodes:\n  tracker: {node: example_talker, parms: {rate: 1}}\n", "nodes.tracker.parms"),
    ("nodez:\n  tracker: {node: example_talker}\n", "nodez"),
    ("nodes:\n  tracker: {node: example_talker, respawn: 'yes'}\n", "nodes.tracker.respawn"),
    ("nodes:\n  tracker: {node: example_talker, realtime: 1}\n", "nodes.tracker.realtime"),
    ("nodes:\n  tracker: {node: example_talker, respawn_delay: .nan}\n", "nodes.tracker.respawn_delay"),
    ("nodes:\n  tracker: {node: example_talker, params: [1]}\n", "nodes.tracker.params"),
    ("nodes:\n  tracker: {node: 3}\n", "nodes.tracker.node"),
    ("nodes:\n  tracker: {params: {rate: 1}}\n", "nodes.tracker.node"),
    ("nodes:\n  tracker: example_talker\n", "nodes.tracker"),
    ("include: [missing.yaml]\n", "include[0]"),
    ("nodes: [talker]\n", "nodes"),
])
def test_bad_launch_files_name_the_file_and_the_key(tmp_path, text, key):
    path = write(tmp_path / "bad.yaml", text)
    with pytest.raises(ConfigError) as err:
        load_launch(path)
    assert err.value.key == key
    assert Path(err.value.file).name == "bad.yaml"


def test_an_unknown_node_lists_the_known_ones(tmp_path):
    path = write(tmp_path / "bad.yaml", "nodes:\n  tracker: {node: replay_trackr}\n")
    with pytest.raises(ConfigError, match="example_talker") as err:
        load_launch(path)
    assert "replay_trackr" in str(err.value)


@pytest.mark.parametrize("override, key", [
    ("nobody.rate:=3", "nobody.rate:=3"),
    ("tracker:=no_such_node", "tracker:=no_such_node"),
    ("tracker=example_talker", "tracker=example_talker"),
])
def test_bad_overrides_are_named(tmp_path, override, key):
    path = write(tmp_path / "l.yaml", "nodes:\n  tracker: {node: example_talker}\n")
    with pytest.raises(ConfigError) as err:
        load_launch(path, [override])
    assert err.value.key == key and err.value.file == "command line"


def test_include_cycles_are_refused(tmp_path):
    write(tmp_path / "a.yaml", "include: [b.yaml]\n")
    write(tmp_path / "b.yaml", "include: [a.yaml]\n")
    with pytest.raises(ConfigError, match="cycle"):
        load_launch(tmp_path / "a.yaml")


def test_cli_reports_a_bad_launch_file_without_traceback(tmp_path, capsys):
    from touch4d.cli import main

    path = write(tmp_path / "bad.yaml", "nodes:\n  tracker: {node: example_talker, bogus: 1}\n")
    assert main(["launch", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "nodes.tracker.bogus" in err and "Traceback" not in err


def test_the_project_launch_files_are_valid():
    for path in sorted((ROOT / "launch").glob("*.yaml")):
        assert load_launch(path), path


def test_node_process_entry_reports_unknown_modules_and_bad_params(capsys):
    from touch4d.bus.process import main

    assert main(["no_such_node", "--name", "x"]) == 2
    assert "touch4d.nodes.no_such_node not found" in capsys.readouterr().err
    assert main(["example_talker", "--name", "t", "--params", "[1, 2]"]) == 2
    assert "--params: expected a JSON object" in capsys.readouterr().err

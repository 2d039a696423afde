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
                              "other:=none", "+extra:=example_talker", "extra.rate:=3"])
    assert list(nodes) == ["tracker", "extra"]
    assert nodes["tracker"].module == "example_listener"
    assert nodes["tracker"].params == {"delay": 0.5, "topic": "hand/pose"}
    assert nodes["extra"].module == "example_talker" and nodes["extra"].params == {"rate": 3}


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
    ("?\n", "None"),                                   # YAML's explicit key, empty: a null key
    ("1: x\n", "1"),
    ("nodes:\n  tracker: {node: example_talker, 2: x}\n", "nodes.tracker.2"),
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
    err = capsys.readouterr().err
    assert "'no_such_node'" in err and "example_talker" in err and "module path" in err
    assert main(["example_talker", "--name", "t", "--params", "[1, 2]"]) == 2
    assert "--params: expected a JSON object" in capsys.readouterr().err


# ---- checked before anything starts: roles, parameters and their types ----------------------------


DEMO = str(ROOT / "launch" / "demo.yaml")


def launch_error(overrides, path=DEMO) -> ConfigError:
    with pytest.raises(ConfigError) as err:
        load_launch(path, overrides)
    return err.value


def test_an_unknown_role_names_the_file_the_roles_and_the_closest():
    err = launch_error(["rendrer:=none"])
    text = str(err)
    assert err.file == "command line" and err.key == "rendrer:=none" and err.got == "rendrer"
    assert DEMO in text and "did you mean 'renderer'?" in text
    assert "tracker, scene, tactile, motors, renderer, monitor" in text
    assert "+ROLE:=NODE adds a node" in text
    assert "did you mean 'tracker'?" in str(launch_error(["trackr.rate:=5"]))
    assert "did you mean 'scene'?" in str(launch_error(["scen:=scripted"]))


def test_a_typo_of_a_role_removed_earlier_suggests_that_role_and_says_it_is_gone():
    # `study run --simulate` removes the renderer before the user's overrides; the study has a recorder
    text = str(launch_error(["renderer:=none", "rendrer:=none"], path=str(ROOT / "launch" / "study.yaml")))
    assert "(did you mean 'renderer'? an earlier renderer:=none removed it)" in text
    assert "recorder?" not in text and "'recorder'?" not in text


def test_an_undeclared_parameter_names_the_role_the_node_and_its_parameters():
    err = launch_error(["tracker.rat:=5"])
    text = str(err)
    assert err.file == "command line" and err.key == "tracker.rat:=5" and err.got == "rat"
    assert "node scripted (role 'tracker' of " + DEMO + ")" in text
    assert "one of: calibration, finger_speed, fingers, fingers_file, glove, loop, path, paths, rate, start_s" in text and "did you mean 'rate'?" in text


def test_an_undeclared_parameter_in_a_file_names_the_file_and_key(tmp_path):
    path = write(tmp_path / "l.yaml", "nodes:\n  tracker: {node: example_talker, params: {rat: 5.0}}\n")
    err = launch_error([], path)
    assert (err.file, err.key, err.got) == (str(path), "nodes.tracker.params.rat", "rat")
    assert "one of: count, rate, topic" in str(err) and "did you mean 'rate'?" in str(err)
    bad = write(tmp_path / "b.yaml", "nodes:\n  tracker: {node: example_talker, params_for: {replay: {fil: x}}}\n")
    err = launch_error([], bad)
    assert err.key == "nodes.tracker.params_for.replay.fil" and "did you mean 'file'?" in str(err)


@pytest.mark.parametrize("override, expected", [
    ("tracker.rate:=fast", "a finite number > 0 and <= 1000 (Hz) for parameter 'rate'"),
    ("tracker.rate:=-5", "a finite number > 0 and <= 1000 (Hz) for parameter 'rate'"),
    ("tracker.rate:=.nan", "a finite number > 0"),
    ("tracker.loop:=maybe", "true or false for parameter 'loop'"),
    ("tactile.projection:=fisheye", "one of scene, orthographic, perspective for parameter 'projection'"),
    ("renderer.width:=8.5", "an integer >= 16 and <= 8192 (pixels)"),
    ("scene.spin:=[1, 2]", "a mapping for parameter 'spin'"),
    ("tactile.alpha:=steep", "a finite number, or null for parameter 'alpha'"),
])
def test_a_wrong_parameter_type_or_value_names_the_role_the_file_and_what_is_valid(override, expected):
    err = launch_error([override])
    assert err.file == "command line" and err.key == override
    assert expected in str(err) and f"(role '{override.split('.')[0]}' of {DEMO})" in str(err)


def test_a_wrong_type_in_a_file_is_named_there(tmp_path):
    path = write(tmp_path / "l.yaml", "nodes:\n  renderer: {node: renderer, params: {headless: 'yes'}}\n")
    err = launch_error([], path)
    assert (err.file, err.key, err.got) == (str(path), "nodes.renderer.params.headless", "yes")
    assert "true or false" in str(err)


def test_a_node_name_with_a_typo_gets_a_suggestion():
    err = launch_error(["tracker:=scriptd"])
    assert err.key == "tracker:=scriptd" and "did you mean 'scripted'?" in str(err)
    err = launch_error(["tracker:=mylab.no_such_module"])
    assert "no importable module mylab.no_such_module" in str(err)


def test_adding_a_node_needs_a_new_role():
    assert "+ROLE:=NODE with a new role" in str(launch_error(["+tracker:=scripted"]))
    assert load_launch(DEMO, ["+recorder:=recorder", "recorder.topics:=[hand/pose]"])["recorder"].params == {
        "topics": ["hand/pose"]}


def test_the_launch_command_refuses_a_bad_override_before_starting_anything(capsys):
    from touch4d.cli import main

    assert main(["launch", "rendrer:=none"]) == 2
    captured = capsys.readouterr()
    assert "rendrer" in captured.err and "did you mean 'renderer'?" in captured.err and "Traceback" not in captured.err
    assert "broker" not in captured.out and "started" not in captured.out


def test_a_node_checks_its_parameters_itself_too():
    """Run without the launcher (`touch4d node run`), the node says the same."""
    from touch4d.bus.process import main

    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "touch4d.bus", "example_talker", "--name", "talker",
                           "--params", '{"rat": 5}'], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "parameters of node 'talker'" in done.stderr and "did you mean 'rate'?" in done.stderr
    assert main  # the same entry point the launcher uses


def test_a_bare_launch_name_is_a_file_of_launch(tmp_path, monkeypatch):
    from touch4d.commands.bus import launch_file_path

    monkeypatch.chdir(tmp_path)
    assert launch_file_path("pi").name == "pi.yaml" and launch_file_path("pi").parent.name == "launch"
    (tmp_path / "launch").mkdir()
    (tmp_path / "launch" / "pi.yaml").write_text("nodes: {}\n")
    assert launch_file_path("pi") == tmp_path / "launch" / "pi.yaml"      # yours first
    (tmp_path / "pi").write_text("nodes: {}\n")
    assert launch_file_path("pi") == tmp_path / "pi"                       # a file of that name wins
    with pytest.raises(ConfigError) as err:
        launch_file_path("nosuch")
    assert "launch/nosuch.yaml" in str(err.value)

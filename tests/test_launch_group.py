"""Nodes that share a process (a launch file's `group`): one executor, one thread, restarted whole."""
import os
import re
import signal
from pathlib import Path
from types import SimpleNamespace

import pytest

from touch4d.bus import Executor, Node
from touch4d.bus.launchfile import load_launch, processes
from touch4d.bus.process import main as process_main
from touch4d.bus.testing import collect, launch_process, pids_alive, running_broker, wait_until
from touch4d.errors import ConfigError
from touch4d.messages import HandPose, Heartbeat
from touch4d.nodes.example_listener import ExampleListener
from touch4d.nodes.example_talker import ExampleTalker

pytestmark = pytest.mark.timeout(120)
EXAMPLE = Path(__file__).resolve().parents[1] / "launch" / "example.yaml"


def grouped(tmp_path, extra: str = "") -> Path:
    """launch/example.yaml with its talker and listener in one group."""
    path = tmp_path / "grouped.yaml"
    path.write_text(f"include: [{EXAMPLE}]\nnodes:\n  talker: {{group: pair{extra}}}\n  listener: {{group: pair}}\n")
    return path


def beats_of(probe, roles, exclude_pid=None, timeout=30.0):
    """role -> pid from the heartbeats, once every role has one (from a pid other than `exclude_pid`)."""
    beats = collect(probe, "node/heartbeat", Heartbeat)
    pids = {}

    def all_seen():
        pids.update({b.node: b.pid for b in beats if b.pid != exclude_pid})
        return set(roles) <= set(pids)

    wait_until(all_seen, timeout=timeout, spin=probe)
    return pids


def test_two_nodes_on_one_executor_talk_over_the_bus_and_one_shutting_down_leaves_the_other():
    with running_broker() as bus:
        executor = Executor()
        talker = ExampleTalker("talker", {"rate": 50.0}, bus=bus, executor=executor)
        listener = ExampleListener("listener", {"relay_topic": "example/relay"}, bus=bus, executor=executor)
        with Node("probe", bus=bus, heartbeat=False) as probe:
            relayed = collect(probe, "example/relay", HandPose)

            both = SimpleNamespace(spin_once=lambda timeout: executor.spin_once(timeout / 2) + probe.spin_once(timeout / 2))
            wait_until(lambda: len(relayed) >= 5, timeout=20, spin=both)
            assert listener.heard >= 5
            talker.shutdown()   # its sockets and timers leave the executor; the listener goes on
            assert not executor.stopping and len(executor.timers) >= 1
            heard = listener.heard
            for _ in range(30):
                executor.spin_once(0.01)
            assert listener.heard <= heard + 2          # nothing new comes: the talker is gone
            assert all(t.cancelled for t in talker._timers)
        listener.shutdown()
        executor.close()


def test_a_grouped_launch_runs_one_process_whose_nodes_talk(tmp_path):
    with launch_process([str(grouped(tmp_path))]) as run:
        run.wait_for_line(r"\[launch\].*started 2 node\(s\) in 1 process\(es\): pair \(talker: example_talker, "
                          r"listener: example_listener\)", timeout=30)
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            relayed = collect(probe, "example/relay", HandPose)
            pids = beats_of(probe, ["talker", "listener"])
            wait_until(lambda: len(relayed) >= 5, timeout=30, spin=probe)
        assert pids["talker"] == pids["listener"]          # one process
        assert run.stop(signal.SIGTERM, timeout=30) == 0
        wait_until(lambda: not pids_alive([pids["talker"]]), timeout=10)
    assert "[pair]" in run.text and "INFO listener: heard" in run.text   # both shut down, output prefixed


def test_a_crashed_group_comes_back_whole_and_its_nodes_talk_again(tmp_path):
    # example.yaml's listener respawns (after 0.5 s): its group comes back as one, after its longest delay
    with launch_process([str(grouped(tmp_path, ", respawn_delay: 0.7"))]) as run:
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            first = beats_of(probe, ["talker", "listener"])
        os.kill(first["talker"], signal.SIGKILL)           # a crash: the whole process is gone
        run.wait_for_line(r"\[launch\].*group 'pair' \(talker: example_talker, listener: example_listener\) "
                          r"was killed by SIGKILL", timeout=30)
        run.wait_for_line(r"\[launch\].*respawning 'pair' in 0.7 s", timeout=5)
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            relayed = collect(probe, "example/relay", HandPose)
            back = beats_of(probe, ["talker", "listener"], exclude_pid=first["talker"])
            wait_until(lambda: len(relayed) >= 3, timeout=30, spin=probe)
        assert back["talker"] == back["listener"] != first["talker"]
        assert run.stop(signal.SIGTERM, timeout=30) == 0
        wait_until(lambda: not pids_alive([back["talker"]]), timeout=10)


def test_a_group_whose_node_fails_to_start_stops_the_launch_naming_the_node_and_the_cause(tmp_path):
    scene = tmp_path / "bad-scene.yaml"
    scene.write_text("objects:\n  - {shape: tesseract, size: -1}\n")
    path = tmp_path / "stack.yaml"
    path.write_text(f"nodes:\n  talker: {{node: example_talker, group: pair}}\n"
                    f"  scene: {{node: scene, group: pair, params: {{scene: '{scene}'}}}}\n")
    with launch_process([str(path)]) as run:
        code = run.proc.wait(60)
        run.join()
    assert code == 2   # a config error
    last = run.text.rstrip().splitlines()[-1]
    assert "group 'pair' (talker: example_talker, scene: scene) failed to start" in last, last
    assert all(text in last for text in ["node scene:", "bad-scene.yaml", "objects[0].size"]), last


@pytest.mark.parametrize("text, key, expected", [
    ("nodes:\n  talker: {node: example_talker, group: 'my pair'}\n", "nodes.talker.group", "a group name"),
    ("nodes:\n  talker: {node: example_talker, group: [a]}\n", "nodes.talker.group", "a group name"),
    ("nodes:\n  talker: {node: example_talker, group: listener}\n  listener: {node: example_listener}\n",
     "nodes.talker.group", "not the role of a node outside the group"),
    ("nodes:\n  talker: {node: example_talker, private: [example/pose]}\n", "nodes.talker.private", "a `group`"),
    ("nodes:\n  talker: {node: example_talker, group: g, private: [safety/stop]}\n", "nodes.talker.private[0]",
     "the heartbeats or the stop"),
    ("nodes:\n  talker: {node: example_talker, group: g, private: [example/pose, /abs]}\n",
     "nodes.talker.private[1]", "a topic of the node's namespace"),
])
def test_a_bad_group_is_refused_naming_the_file_and_the_key(tmp_path, text, key, expected):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_launch(path)
    assert err.value.key == key and Path(err.value.file).name == "bad.yaml"
    assert expected in str(err.value)


def test_processes_group_nodes_in_file_order_and_leave_the_others_alone(tmp_path):
    path = tmp_path / "mixed.yaml"
    path.write_text("nodes:\n  a: {node: example_talker, group: g}\n  b: {node: example_listener}\n"
                    "  c: {node: example_listener, group: g, respawn: true}\n")
    procs = processes(load_launch(path))
    assert {name: [s.role for s in specs] for name, specs in procs.items()} == {"g": ["a", "c"], "b": ["b"]}
    # without `group`, every project launch file keeps one process per node
    for launch in sorted(EXAMPLE.parent.glob("*.yaml")):
        nodes = load_launch(launch)
        assert list(processes(nodes)) == list(nodes), launch.name


@pytest.mark.parametrize("nodes, expected", [
    ("{}", "--nodes: expected a JSON list"),
    ("[1]", '--nodes[0]: expected an object with a "node"'),
    ('[{"node": "no_such_node", "name": "x"}]', "node x: node 'no_such_node'"),
])
def test_a_group_process_with_bad_nodes_says_which_and_exits_2(nodes, expected, capsys):
    assert process_main(["--group", "pair", "--nodes", nodes]) == 2
    assert expected in capsys.readouterr().err


@pytest.mark.parametrize("nodes, expected", [
    ([1], 'g[0]: expected an object with a "node"'),
    ([{"node": "no_such_node", "name": "x"}], "node x: node 'no_such_node'"),
    ([{"node": "example_talker", "name": "t", "private": "hand/pose"}], "g[0].private: expected a list of topics"),
])
def test_a_bad_group_list_is_a_touch4d_error_that_names_the_entry(nodes, expected):
    """GroupError is one of touch4d's errors (reported to a user without a traceback, caught with the
    others), and still a ValueError for code that catches that."""
    from touch4d.bus.process import GroupError, group_members
    from touch4d.errors import Touch4dError

    with pytest.raises(GroupError, match=re.escape(expected)) as info:
        group_members(nodes, "", "g")
    assert isinstance(info.value, Touch4dError) and isinstance(info.value, ValueError)

"""`touch4d launch` as a user runs it: live prefixed output, respawn, clean stops, nothing left behind."""
import os
import signal
import time

import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, launch_process, pids_alive, wait_until
from touch4d.messages import HandPose, Heartbeat

pytestmark = pytest.mark.timeout(120)


def heartbeat_pids(run, roles, timeout=30.0):
    """The pid of each role, from heartbeats heard on the launch's bus."""
    with Node("probe", bus=run.bus, heartbeat=False) as probe:
        beats = collect(probe, "node/heartbeat", Heartbeat)
        pids = {}

        def all_seen():
            pids.update({b.node: b.pid for b in beats})
            return set(roles) <= set(pids)

        wait_until(all_seen, timeout=timeout, spin=probe)
    return pids


def test_ctrl_c_stops_every_node_and_exits_0_with_live_prefixed_output():
    with launch_process(["launch/example.yaml"]) as run:
        # Output arrives while the nodes run, each line prefixed with the role.
        run.wait_for_line(r"^\[talker\]\s+INFO talker: publishing HandPose on example/pose", timeout=30)
        run.wait_for_line(r"^\[listener\]\s+INFO listener: listening on example/pose", timeout=30)
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            relayed = collect(probe, "example/relay", HandPose)
            wait_until(lambda: len(relayed) >= 5, timeout=30, spin=probe)
        pids = heartbeat_pids(run, ["talker", "listener"])
        assert run.proc.poll() is None
        started = time.monotonic()
        os.killpg(run.proc.pid, signal.SIGINT)  # what Ctrl+C in a terminal does: the whole group
        assert run.proc.wait(30) == 0
        elapsed = time.monotonic() - started
        wait_until(lambda: not pids_alive(pids.values()), timeout=10)
    assert elapsed < 10  # the launcher's own limit is 1.5 s of grace; this only guards against a hang
    assert "[launch]   stopping (SIGINT)" in run.text and run.text.rstrip().endswith("stopped")
    assert "heard" in run.wait_for_line(r"^\[listener\].*heard \d+ message", timeout=1)


def test_a_killed_node_with_respawn_comes_back_and_sigterm_stops_all():
    with launch_process(["launch/example.yaml", "listener.delay:=0.001"]) as run:
        first = heartbeat_pids(run, ["talker", "listener"])
        os.kill(first["listener"], signal.SIGKILL)
        run.wait_for_line(r"\[launch\].*node 'listener' \(example_listener\) was killed by SIGKILL", timeout=30)
        run.wait_for_line(r"\[launch\].*respawning 'listener'", timeout=5)
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            beats = collect(probe, "node/heartbeat", Heartbeat)
            back = wait_until(lambda: [b for b in beats if b.node == "listener" and b.pid != first["listener"]],
                              timeout=30, spin=probe)
        assert run.stop(signal.SIGTERM, timeout=30) == 0
        wait_until(lambda: not pids_alive([first["talker"], back[0].pid]), timeout=10)
    assert "stopping (SIGTERM)" in run.text


def test_a_node_stuck_past_the_grace_is_killed_and_the_launch_still_stops_cleanly():
    from touch4d.bus.launcher import STOP_GRACE
    assert STOP_GRACE < 2.0  # a clean stop is over within 2 s
    with launch_process(["launch/example.yaml", "listener.delay:=120"]) as run:
        pids = heartbeat_pids(run, ["talker", "listener"])
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            poses = collect(probe, "example/pose", HandPose)
            wait_until(lambda: len(poses) >= 3, timeout=30, spin=probe)  # the listener is now asleep in a callback
        assert run.stop(signal.SIGTERM, timeout=30) == 0
        wait_until(lambda: not pids_alive(pids.values()), timeout=10)
    assert "node 'listener' did not stop within" in run.text and "killing it" in run.text
    assert "[talker]" in run.text and run.text.rstrip().endswith("stopped")


def test_duration_stops_cleanly_with_exit_0():
    # The duration counts from the nodes' start: on a loaded machine 2 s may end before the talker
    # has spoken (still importing), which would stop nothing that runs; then again for longer.
    for duration in (2, 10, 40):
        with launch_process(["launch/example.yaml", "--duration", str(duration)]) as run:
            assert run.proc.wait(duration + 60) == 0
            run.join()
        assert f"stopping (--duration {duration} s)" in run.text and run.text.rstrip().endswith("stopped")
        if "[talker]" in run.text:
            break
    assert "[talker]" in run.text and "killing it" not in run.text, run.text


def test_nodes_die_with_a_killed_launcher():
    with launch_process(["launch/example.yaml"]) as run:
        pids = heartbeat_pids(run, ["talker", "listener"])
        os.kill(run.proc.pid, signal.SIGKILL)
        run.proc.wait(10)
        wait_until(lambda: not pids_alive(pids.values()), timeout=15)


def test_nodes_of_a_launch_with_curve_keys_talk(tmp_path):
    from touch4d.bus.keys import keygen

    keygen(tmp_path / "keys", "broker")
    keygen(tmp_path / "keys" / "clients", "pc")
    config = tmp_path / "bus.yaml"
    config.write_text("broker: {bind: 127.0.0.1, pub_port: 0, sub_port: 0}\n"
                      "curve: {server_public: keys/broker.key, server_secret: keys/broker.key_secret,\n"
                      "        client_secret: keys/clients/pc.key_secret, authorized: [keys/clients]}\n")
    with launch_process(["launch/example.yaml"], bus_config=str(config)) as run:
        bus = run.bus
        assert bus.curve is not None and bus.curve.server_secret is None
        with Node("probe", bus=bus, heartbeat=False) as probe:
            relayed = collect(probe, "example/relay", HandPose)
            wait_until(lambda: len(relayed) >= 3, timeout=30, spin=probe)
        assert run.stop(timeout=30) == 0
    assert "(CURVE)" in run.text


def test_a_node_marked_realtime_runs_with_sched_fifo_when_permitted(tmp_path):
    from touch4d.bus.realtime import realtime_permitted

    launch = tmp_path / "rt.yaml"
    launch.write_text("nodes:\n  talker: {node: example_talker, realtime: true}\n"
                      "  listener: {node: example_listener}\n")
    with launch_process([str(launch)]) as run:
        pids = heartbeat_pids(run, ["talker", "listener"])
        policies = {role: os.sched_getscheduler(pid) for role, pid in pids.items()}
        threads = os.listdir(f"/proc/{pids['talker']}/task")
        thread_policies = {os.sched_getscheduler(int(t)) for t in threads}
        assert run.stop(timeout=30) == 0
    assert policies["listener"] == os.SCHED_OTHER
    if realtime_permitted():
        assert policies["talker"] == os.SCHED_FIFO
        assert thread_policies == {os.SCHED_FIFO}, "the ZeroMQ I/O threads inherit the priority"
        assert "real-time priority (SCHED_FIFO" in run.text
    else:
        assert policies["talker"] == os.SCHED_OTHER
        assert "real-time priority not permitted" in run.text


@pytest.mark.parametrize("role, entry, expected", [
    ("scene", "{node: scene, params: {scene: 'BAD'}}", ["bad-scene.yaml", "objects[0].size", "a finite number > 0, got -1"]),
])
def test_a_node_failing_at_start_with_a_config_error_stops_the_launch_with_its_error_last(tmp_path, role, entry,
                                                                                          expected):
    scene = tmp_path / "bad-scene.yaml"
    scene.write_text("objects:\n  - {shape: tesseract, size: -1}\n")
    launch = tmp_path / "stack.yaml"
    launch.write_text(f"nodes:\n  talker: {{node: example_talker}}\n  {role}: {entry.replace('BAD', str(scene))}\n")
    with launch_process([str(launch)]) as run:
        code = run.proc.wait(60)
        run.join()
    assert code == 2  # a config error
    last = run.text.rstrip().splitlines()[-1]
    # The cause, named as the file at fault names it, is what the user reads last.
    assert last.startswith("[launch]") and f"node '{role}' ({role}) failed to start" in last
    assert all(text in last for text in expected), last
    assert "[talker]" in run.text and "stopping (node" in run.text  # the others were started, then stopped


def test_a_missing_file_stops_the_launch_before_any_node_starts(tmp_path):
    launch = tmp_path / "stack.yaml"
    launch.write_text("nodes:\n  talker: {node: example_talker}\n"
                      "  tactile: {node: tactile, params: {glove: no-such-glove.yaml}}\n")
    with launch_process([str(launch)]) as run:
        code = run.proc.wait(60)
        run.join()
    assert code == 2
    last = run.text.rstrip().splitlines()[-1]
    assert last.startswith(f"touch4d launch: {launch}: key 'nodes.tactile.params.glove': expected an existing "
                           "glove file, got 'no-such-glove.yaml': looked in "), last
    assert f"{tmp_path}/no-such-glove.yaml" in last and "[talker]" not in run.text   # nothing was started


def test_a_failing_node_with_respawn_keeps_the_launch_and_the_monitor_names_the_topic_without_publisher(tmp_path):
    scene = tmp_path / "bad-scene.yaml"
    scene.write_text("objects:\n  - {shape: tesseract, size: -1}\n")
    launch = tmp_path / "stack.yaml"
    launch.write_text("nodes:\n"
                      f"  scene: {{node: scene, params: {{scene: '{scene}'}}, respawn: true}}\n"
                      "  listener: {node: example_listener, params: {topic: scene/state}}\n"
                      "  monitor: {node: monitor, params: {period: 0.5}}\n")
    with launch_process([str(launch)]) as run:
        line = run.wait_for_line(r"^\[monitor\].*no publisher", timeout=60)
        run.wait_for_line(r"\[launch\].*respawning 'scene'", timeout=10)
        assert run.proc.poll() is None
        run.stop(timeout=30)
    assert "scene/state" in line and "listener" in line


def test_two_publishers_of_one_input_are_warned_by_the_launcher_and_the_monitor():
    with launch_process(["launch/example.yaml", "+talker2:=example_talker", "+monitor:=monitor"]) as run:
        line = run.wait_for_line(r"^\[launch\].*warning: example/pose has 2 publishers", timeout=30)
        assert "(talker, talker2)" in line and "latest-only" in line
        run.wait_for_line(r"^\[monitor\].*several publishers: example/pose \(talker, talker2\)", timeout=30)
        run.wait_for_line(r"^\[monitor\].*WARNING.*example/pose has 2 publishers", timeout=5)
        assert run.stop(timeout=30) == 0
    assert run.text.count("warning: example/pose has 2 publishers") == 1   # said once


def test_ctrl_c_while_the_broker_starts_stops_the_launch_with_nothing_started_and_the_broker_closed(monkeypatch):
    """The first moments of `touch4d launch`: a Ctrl+C there is a stop like any other, not an
    exception that leaves the broker's thread and sockets open (the interpreter then hangs at exit)."""
    import io
    import threading

    from touch4d.bus import broker as broker_module
    from touch4d.bus.config import BusConfig
    from touch4d.bus.launcher import Launcher
    from touch4d.bus.launchfile import load_launch

    real_start = broker_module.Broker.start
    started = []

    def start_then_ctrl_c(self):
        endpoints = real_start(self)
        started.append(self)
        os.kill(os.getpid(), signal.SIGINT)   # arrives in the middle of the launcher's start
        return endpoints

    monkeypatch.setattr(broker_module.Broker, "start", start_then_ctrl_c)
    out = io.BytesIO()
    nodes = load_launch("launch/example.yaml")
    launcher = Launcher(nodes, BusConfig(pub_port=0, sub_port=0, source="<test>"), out=out)
    before = signal.getsignal(signal.SIGINT)
    assert launcher.run() == 0
    text = out.getvalue().decode()
    assert "stopping (SIGINT)" in text and text.rstrip().endswith("stopped"), text
    assert all(child.proc is None for child in launcher.children.values()), "a node started after the Ctrl+C"
    assert started and started[0]._thread is None
    assert not [t for t in threading.enumerate() if t.name == "touch4d-broker"], "the broker's thread is still running"
    assert signal.getsignal(signal.SIGINT) is before   # the caller's handler is back

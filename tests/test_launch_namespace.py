"""Namespaces, as in ROS: every topic of a namespaced node or launch lies under NS/, so two stacks
on one broker never hear each other; heartbeats and the broadcast stop stay global; the tools take
a namespace; a recording made in one namespace replays into another."""
from __future__ import annotations

import io
import threading
from pathlib import Path

import numpy as np
import pytest

from touch4d.bus import Node, names
from touch4d.bus.introspect import topic_list, topic_pub
from touch4d.bus.launchfile import load_launch
from touch4d.bus.testing import collect, free_port, launch_process, running_broker, wait_until
from touch4d.errors import ConfigError
from touch4d.log.reader import LogReader
from touch4d.log.recorder import Recorder
from touch4d.log.replay import BusSender, Plan, Replayer, ReplayOptions
from touch4d.messages import HandPose, Heartbeat, Stop

REPO = Path(__file__).resolve().parents[1]


def pose(x=0.0):
    return HandPose(position=np.array([x, 0.0, 0.0]), orientation=np.array([0.0, 0.0, 0.0, 1.0]), valid=True)


def spin_until(nodes, predicate, timeout=10.0):
    def spin_all():
        for node in nodes:
            node.spin_once(0.005)
        return predicate()
    return wait_until(spin_all, timeout=timeout)


def raw_topics(node):
    """Every topic `node` hears (raw, all), as it names them."""
    seen = []
    node.create_raw_subscription("", lambda topic, payload: seen.append(topic))
    return seen


# ---- the rules, without a bus ---------------------------------------------------------------------------


def test_topics_resolve_under_the_namespace_except_the_global_ones():
    assert names.resolve("hand/pose", "P07") == "P07/hand/pose"
    assert names.resolve("hand/pose", "") == "hand/pose"
    assert names.resolve("node/heartbeat", "P07") == "node/heartbeat"
    assert names.resolve("/scene/state", "P07") == "scene/state"          # absolute
    assert names.resolve("hand/pose", "lab/P07") == "lab/P07/hand/pose"
    assert names.relative("P07/hand/pose", "P07") == "hand/pose"
    assert names.relative("P08/hand/pose", "P07") is None
    assert names.relative("safety/stop", "P07") == "safety/stop"
    assert names.rebase("hand/pose", "P07", "") == "P07/hand/pose"
    assert names.rebase("hand/pose", "P07", "P08") is None
    assert names.in_namespace("P07/tracker", "P07") and not names.in_namespace("tracker", "P07")
    assert names.check_namespace("/P07/") == "P07"
    for bad in ("P 07", "a//b", "_bus", "é"):
        with pytest.raises(ValueError, match="namespace"):
            names.check_namespace(bad)


def test_a_launch_files_ns_and_the_command_lines_namespace(tmp_path):
    (tmp_path / "stack.yaml").write_text("ns: P07\nnodes:\n  talker: {node: example_talker}\n")
    assert {s.namespace for s in load_launch(tmp_path / "stack.yaml").values()} == {"P07"}
    assert {s.namespace for s in load_launch(tmp_path / "stack.yaml", namespace="P08").values()} == {"P08"}
    assert {s.namespace for s in load_launch(REPO / "launch/example.yaml").values()} == {""}
    (tmp_path / "bad.yaml").write_text("ns: 'P 07'\nnodes:\n  talker: {node: example_talker}\n")
    with pytest.raises(ConfigError, match=r"bad.yaml.*'ns'.*namespace"):
        load_launch(tmp_path / "bad.yaml")
    with pytest.raises(ConfigError, match="--namespace"):
        load_launch(tmp_path / "stack.yaml", namespace="a b")


# ---- nodes on one broker ----------------------------------------------------------------------------------


def test_two_namespaces_on_one_broker_do_not_hear_each_other():
    with running_broker() as bus, Node("a", bus=bus, namespace="A") as a, Node("b", bus=bus, namespace="B") as b, \
            Node("a2", bus=bus, namespace="A") as a2, Node("probe", bus=bus) as probe:
        heard_a, heard_b = collect(a2, "hand/pose", HandPose), collect(b, "hand/pose", HandPose)
        everything = raw_topics(probe)
        pub = a.create_publisher("hand/pose", HandPose)
        for k in range(5):
            pub.publish(pose(k))
        wait_until(lambda: len(heard_a) == 5, spin=a2, timeout=10)
        for _ in range(20):
            b.spin_once(0.01)
            probe.spin_once(0.01)
        assert [m.position[0] for m in heard_a] == [0, 1, 2, 3, 4]
        assert heard_b == []
        assert set(everything) - {"node/heartbeat"} == {"A/hand/pose"}


def test_every_listener_hears_every_stacks_beats_and_a_stack_can_listen_to_its_own_alone():
    """Heartbeats stay one global topic to whoever listens to node/heartbeat (a node in a namespace
    too), while on the wire a namespaced node's beat carries its namespace: a socket subscribed to
    names.heartbeat_key("A") (how a stack's recorder and launcher listen) gets stack A's beats only,
    and no other stack's wakes it."""
    import zmq
    from touch4d.bus import transport
    from touch4d.messages import decode

    with running_broker() as bus, Node("a", bus=bus, namespace="A") as a, Node("b", bus=bus, namespace="B") as b, \
            Node("g", bus=bus) as g, Node("probe", bus=bus, heartbeat=False, namespace="C") as probe:
        beats = collect(probe, "node/heartbeat", Heartbeat)
        everything = raw_topics(probe)
        own = transport.subscriber(zmq.Context.instance(), bus, topics=[names.heartbeat_key("A")])
        try:
            spin_until([a, b, g, probe], lambda: {"A/a", "B/b", "g"} <= {m.node for m in beats}, timeout=15)
            spin_until([a, b, g, probe], lambda: len([m for m in beats if m.node == "B/b"]) >= 2, timeout=15)
            frames = []

            def own_heard() -> bool:                               # its subscription needs a moment too
                while own.poll(0):
                    frames.append(own.recv_multipart())
                return len(frames) >= 2
            spin_until([a, b, g, probe], own_heard, timeout=15)
            assert a.stats_flat()["published"] == 0                 # its own beats are not its messages
        finally:
            own.close(linger=0)
    assert {m.node for m in beats} >= {"A/a", "B/b", "g"}
    assert set(everything) == {"node/heartbeat"}               # as the bus names it, from every stack
    assert frames and {f[0] for f in frames} == {b"node/heartbeat/A/"}
    assert {decode(f[-1], Heartbeat).node for f in frames} == {"A/a"}
    with Node("forger", bus=bus, heartbeat=False, start=False) as forger:   # the wire prefix is the beats' own
        for topic in ("node/heartbeat/A/", "/node/heartbeat/B/x"):
            with pytest.raises(ValueError, match="node/heartbeat/"):
                forger.create_publisher(topic, Heartbeat)


def test_the_broadcast_stop_reaches_every_namespace_a_namespaced_one_only_its_own():
    with running_broker() as bus, Node("a", bus=bus, namespace="A") as a, Node("b", bus=bus, namespace="B") as b, \
            Node("console", bus=bus) as console:
        stops_a, stops_b = collect(a, "safety/stop", Stop), collect(b, "safety/stop", Stop)
        console.create_publisher("safety/stop", Stop).publish(Stop(reason="everyone", origin="test"))
        spin_until([a, b], lambda: stops_a and stops_b)
        assert [s.reason for s in stops_a] == [s.reason for s in stops_b] == ["everyone"]
        a.create_publisher("safety/stop", Stop).publish(Stop(reason="A only", origin="test"))
        spin_until([a, b], lambda: len(stops_a) == 2)
        for _ in range(20):
            b.spin_once(0.01)
        assert stops_a[-1].reason == "A only" and len(stops_b) == 1


def test_heartbeats_stay_global_named_ns_slash_role_with_relative_topics():
    with running_broker() as bus, Node("watcher", bus=bus, heartbeat=False) as watcher:
        beats = collect(watcher, "node/heartbeat", Heartbeat)
        with Node("tracker", bus=bus, namespace="P07") as node:
            node.create_publisher("hand/pose", HandPose)
            node.create_subscription("scene/state", HandPose, lambda m: None)
            spin_until([node, watcher], lambda: beats)
        beat = beats[-1]
        assert beat.node == "P07/tracker"
        assert beat.publishes == ["hand/pose"] and "scene/state" in beat.subscribes


def test_topic_pub_and_list_in_a_namespace():
    with running_broker() as bus, Node("probe", bus=bus, heartbeat=False) as probe, \
            Node("tracker", bus=bus, namespace="P07") as tracker:
        everything = raw_topics(probe)
        heard = collect(tracker, "hand/pose", HandPose)
        out = io.StringIO()
        topic_pub("hand/pose", "{valid: true, position: [0.5, 0, 0], orientation: [0, 0, 0, 1]}", bus, out=out,
                  namespace="P07")
        wait_until(lambda: heard, spin=tracker, timeout=10)
        probe.spin_once(0.1)
        assert "P07/hand/pose" in everything and "hand/pose" not in everything
        assert "on P07/hand/pose" in out.getvalue()
        pub = tracker.create_publisher("tactile/motors", HandPose)
        other = Node("other", bus=bus, namespace="P08")
        try:
            other_pub = other.create_publisher("hand/pose", HandPose)
            rows: dict = {}
            done = threading.Event()

            def listing():
                rows.update(topic_list(bus, 1.5, out=io.StringIO(), namespace="P07"))
                done.set()
            thread = threading.Thread(target=listing)
            thread.start()
            while not done.is_set():
                pub.publish(pose())
                other_pub.publish(pose())
                tracker.spin_once(0.02)
                other.spin_once(0.02)
            thread.join()
        finally:
            other.shutdown()
        assert "tactile/motors" in rows and "hand/pose" not in rows and "P08/hand/pose" not in rows
        assert "P07/tracker" in rows["node/heartbeat"]["publishers"]


def test_a_recording_made_in_one_namespace_replays_into_another(tmp_path):
    log = tmp_path / "p07.mcap"
    with running_broker() as bus, Node("tracker", bus=bus, namespace="P07") as tracker, \
            Node("replayed", bus=bus, namespace="P08", heartbeat=False) as replayed:
        recorder = Recorder(bus, log, namespace="P07", realtime=False)
        recorder.start()
        pub = tracker.create_publisher("hand/pose", HandPose)
        other = Node("noise", bus=bus, namespace="P09", heartbeat=False)
        try:
            other.create_publisher("hand/pose", HandPose).publish(pose(9.0))   # another stack: not recorded
            for k in range(5):
                pub.publish(pose(float(k)))
            wait_until(lambda: recorder.received >= 5, timeout=10)
        finally:
            other.shutdown()
        recorder.stop()
        reader = LogReader(log)
        assert "hand/pose" in reader.topics() and not any(t.startswith(("P07", "P09")) for t in reader.topics())
        heard = collect(replayed, "hand/pose", HandPose)
        options = ReplayOptions(rate=50.0, topics=["hand/pose"])
        sender = BusSender(bus, namespace="P08", realtime=False)
        try:
            Replayer(reader, Plan(reader, options), options, sender).run()
        finally:
            sender.close()
        wait_until(lambda: len(heard) == 5, spin=replayed, timeout=10)
        assert [m.position[0] for m in heard] == [0, 1, 2, 3, 4]


def test_two_launches_on_one_broker_each_in_its_namespace(tmp_path):
    bus_file = tmp_path / "bus.yaml"
    bus_file.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {free_port()}, sub_port: {free_port()}}}\n"
                        "connect: 127.0.0.1\n")
    with launch_process(["launch/example.yaml", "--namespace", "A"], bus_config=str(bus_file)) as a:
        bus = a.wait_ready(60)
        with launch_process(["launch/example.yaml", "--namespace", "B", "--no-broker"], bus_config=str(bus_file)) as b:
            b.wait_ready(60)
            probe = Node("probe", bus=bus, heartbeat=False)
            try:
                relayed = {ns: collect(probe, f"/{ns}/example/relay", HandPose) for ns in "AB"}
                everything = raw_topics(probe)
                wait_until(lambda: all(len(r) >= 10 for r in relayed.values()), spin=probe, timeout=60)
            finally:
                probe.shutdown()
    # each listener relays its own talker's messages only: no seq twice (two talkers would give each twice)
    for ns, msgs in relayed.items():
        seqs = [m.seq for m in msgs]
        assert len(set(seqs)) == len(seqs), f"{ns}: the listener heard another stack"
    assert {"A/example/pose", "B/example/pose", "A/example/relay", "B/example/relay"} <= set(everything)
    assert not {"example/pose", "example/relay"} & set(everything)


def test_a_namespaced_recording_holds_its_own_stacks_heartbeats_only(tmp_path):
    """Heartbeats share one global topic: a participant's log keeps its own nodes' beats (and nested
    namespaces'), never another participant's (their ids and stats are not this participant's data)."""
    log = tmp_path / "p07.mcap"
    with running_broker() as bus:
        recorder = Recorder(bus, log, namespace="P07", realtime=False)
        recorder.start()
        nodes = [Node("tracker", bus=bus, namespace=ns) for ns in ("P070", "P08", None, "P07", "P07/sub")]
        try:
            spin_until(nodes, lambda: recorder.received >= 2, timeout=20)   # each node beats once at start
            for _ in range(40):                                            # the others' beats arrive too
                for node in nodes:
                    node.spin_once(0.005)
        finally:
            for node in nodes:
                node.shutdown()
        recorder.stop()
    beats = [m.decode()["node"] for m in LogReader(log).messages({"node/heartbeat"})]
    assert set(beats) == {"P07/tracker", "P07/sub/tracker"}

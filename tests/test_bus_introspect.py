"""`touch4d topic list|echo|hz|pub` and `touch4d node list` against a live bus."""
import io
import numpy as np
import pytest
import yaml

from touch4d.bus import Node
from touch4d.bus.config import ENV_VAR
from touch4d.bus.introspect import build_message, node_list, topic_echo, topic_hz, topic_list, topic_pub
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.errors import ConfigError
from touch4d.messages import HandPose, Stop

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def live_bus():
    """A broker and a talker publishing HandPose on example/pose at 50 Hz."""
    with running_broker() as bus:
        with node_process("example_talker", bus, name="talker", params={"rate": 50.0}) as talker:
            talker.wait_for_line("publishing HandPose", timeout=30)
            yield bus


def test_topic_list_shows_types_rates_and_publishers(live_bus):
    out = io.StringIO()
    rows = topic_list(live_bus, duration=2.0, out=out)
    assert rows["example/pose"]["type"] == "HandPose" and rows["example/pose"]["publishers"] == ["talker"]
    assert 10 < rows["example/pose"]["rate"] < 200
    assert rows["node/heartbeat"]["type"] == "Heartbeat"
    assert "example/pose" in out.getvalue() and "HandPose" in out.getvalue()


def test_topic_echo_prints_messages_as_yaml(live_bus):
    out = io.StringIO()
    assert topic_echo("example/pose", live_bus, count=3, duration=30, out=out) == 3
    docs = [d for d in yaml.safe_load_all(out.getvalue()) if d]
    assert [d["type"] for d in docs] == ["HandPose"] * 3
    assert np.diff([d["seq"] for d in docs]).tolist() == [1, 1]
    assert len(docs[0]["position"]) == 3 and docs[0]["valid"] is True


def test_topic_hz_measures_the_rate(live_bus):
    out = io.StringIO()
    rate = topic_hz("example/pose", live_bus, duration=1.5, window=0.5, out=out)
    assert 10 < rate < 200
    assert "example/pose:" in out.getvalue() and "Hz" in out.getvalue()


def test_node_list_shows_live_nodes_from_heartbeats(live_bus):
    out = io.StringIO()
    beats = node_list(live_bus, duration=2.0, out=out)
    assert beats["talker"].kind == "example_talker" and beats["talker"].publishes == ["example/pose"]
    assert "talker" in out.getvalue()


def test_topic_pub_builds_and_sends_a_message(live_bus):
    with Node("probe", bus=live_bus, heartbeat=False) as probe:
        stops = collect(probe, "safety/stop", Stop)
        poses = collect(probe, "test/pose", HandPose)
        assert topic_pub("safety/stop", "{reason: test, origin: cli}", live_bus, out=io.StringIO()) == 1
        assert topic_pub("test/pose", "{position: [1, 2, 3], orientation: [0, 0, 0, 1], valid: true}", live_bus,
                         type_name="HandPose", rate=50.0, count=3, out=io.StringIO()) == 3
        wait_until(lambda: stops and len(poses) == 3, timeout=10, spin=probe)
    assert (stops[0].reason, stops[0].origin) == ("test", "cli")
    assert poses[2].seq == 2 and poses[2].position.tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize("topic, text, type_name, match", [
    ("hand/pose", "{position: [1, 2], valid: true}", None, "HandPose.position"),
    ("hand/pose", "{positon: [1, 2, 3]}", None, "fields of HandPose"),
    ("my/topic", "{}", None, "--type"),
    ("my/topic", "{}", "Nope", "one of"),
    ("safety/stop", "[1, 2]", None, "mapping"),
])
def test_topic_pub_reports_bad_input(topic, text, type_name, match):
    with pytest.raises(ConfigError, match=match):
        build_message(topic, text, type_name)


def test_the_cli_commands_reach_the_bus(live_bus, monkeypatch, capsys):
    from touch4d.cli import main

    monkeypatch.setenv(ENV_VAR, live_bus.to_json())   # as in a process the launcher started
    assert main(["node", "list", "--live", "--duration", "2.0"]) == 0
    assert "example_talker" in capsys.readouterr().out
    with Node("probe", bus=live_bus, heartbeat=False) as probe:
        stops = collect(probe, "safety/stop", Stop)
        assert main(["topic", "pub", "safety/stop", "{reason: r, origin: o}"]) == 0
        wait_until(lambda: stops, timeout=10, spin=probe)
    assert main(["topic", "echo", "example/pose", "-n", "1"]) == 0
    assert "type: HandPose" in capsys.readouterr().out
    assert main(["topic", "pub", "safety/stop", "{reason: 3}"]) == 2
    err = capsys.readouterr().err
    assert "Stop.reason" in err and "Traceback" not in err


def test_tools_say_when_no_broker_answers(monkeypatch):
    from touch4d.bus import introspect
    from touch4d.bus.config import BusConfig, BusUnreachable

    monkeypatch.setattr(introspect, "CONNECT_TIMEOUT", 0.5)
    from touch4d.bus.testing import free_port

    bus = BusConfig(pub_port=free_port(), sub_port=free_port(), source="test.yaml")
    with pytest.raises(BusUnreachable, match="no broker at tcp://127.0.0.1"):
        node_list(bus, duration=1.0, out=io.StringIO())


def test_topic_pub_without_a_broker_is_one_clear_error_and_no_warning(tmp_path, monkeypatch, capsys, caplog):
    from touch4d.bus import introspect
    from touch4d.bus.testing import free_port
    from touch4d.cli import main

    monkeypatch.setattr(introspect, "CONNECT_TIMEOUT", 0.5)
    bus_file = tmp_path / "bus.yaml"
    port = free_port()
    bus_file.write_text(f"broker: {{pub_port: {port}, sub_port: {free_port()}}}\n")
    assert main(["topic", "pub", "safety/stop", "{reason: test, origin: me}", "--bus", str(bus_file)]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"touch4d topic: no broker at tcp://127.0.0.1:{port} (bus config: "
                                         f"{bus_file}); is `touch4d launch` running?"]
    assert [r.getMessage() for r in caplog.records if r.levelname in ("WARNING", "ERROR")] == []


def test_echo_on_a_topic_nobody_publishes_says_so_within_two_seconds_and_lists_the_live_topics(live_bus):
    out, err = io.StringIO(), io.StringIO()
    assert topic_echo("example/pos", live_bus, duration=2.0, out=out, err=err) == 0
    assert out.getvalue() == ""
    text = err.getvalue()
    assert "# nobody publishes example/pos (did you mean 'example/pose'?)" in text
    assert "live topics: example/pose, node/heartbeat;" in text
    err = io.StringIO()
    assert topic_hz("tactile/motors", live_bus, duration=2.0, out=io.StringIO(), err=err) is None
    assert "# nobody publishes tactile/motors; live topics: example/pose, node/heartbeat" in err.getvalue()


def test_echo_on_a_published_topic_says_nothing_of_the_kind(live_bus):
    err = io.StringIO()
    assert topic_echo("example/pose", live_bus, count=1, duration=30, out=io.StringIO(), err=err) == 1
    assert topic_hz("example/pose", live_bus, duration=2.0, out=io.StringIO(), err=err) > 10
    assert err.getvalue() == ""

"""A container (touch4d.bus.container) and its pool (touch4d.bus.pool): several groups, each under its namespace, on one executor in
one process, loaded and unloaded while it runs; a dead container started again with its groups by
its pool; a node that asks to stop restarts its own group only."""
from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from touch4d.bus import Executor, Node
from touch4d.bus import container as container_module
from touch4d.bus import pool as pool_module
from touch4d.bus.container import Container
from touch4d.bus.pool import ContainerPool
from touch4d.bus.realtime import realtime_permitted
from touch4d.bus.testing import collect, running_broker, wait_until
from touch4d.log.reader import LogReader
from touch4d.messages import HandPose

pytestmark = pytest.mark.timeout(120)


def _pair(rate: float = 50.0) -> list[dict]:
    """launch/example.yaml's talker and listener as a group, the talker's poses kept in the process."""
    return [{"node": "example_talker", "name": "talker", "params": {"topic": "example/pose", "rate": rate},
             "private": ["example/pose"]},
            {"node": "example_listener", "name": "listener",
             "params": {"topic": "example/pose", "relay_topic": "example/relay"}}]


def _bus_file(tmp_path: Path, bus) -> Path:
    path = tmp_path / "bus.yaml"
    path.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {bus.pub_port}, sub_port: {bus.sub_port}}}\n"
                    "connect: 127.0.0.1\n")
    return path


def _said(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def test_two_groups_share_a_container_each_in_its_namespace_one_unloaded_one_bad_and_a_dead_container_comes_back(tmp_path):
    with running_broker() as bus, Node("probe", bus=bus.for_clients(), heartbeat=False) as probe:
        relayed = {ns: collect(probe, f"{ns}/example/relay", HandPose) for ns in ("A", "B")}
        private: list = []
        probe.create_raw_subscription("A/example/pose", lambda topic, payload: private.append(topic))
        pool = ContainerPool(2, _bus_file(tmp_path, bus), tmp_path / "logs")
        try:
            def command(ns, nodes=None):
                return lambda: {"namespace": ns, "nodes": nodes or _pair(), "ready_file": str(tmp_path / f"{ns}.ready"),
                                "log": str(tmp_path / f"{ns}.log")}

            assert pool.load("A", command("A")) == pool.load("B", command("B"))     # one process for both
            assert len(pool.pids()) == 1
            first = pool.pids()[0]
            wait_until(lambda: _said(tmp_path / "A.ready") == _said(tmp_path / "B.ready") == "ready", timeout=60)
            wait_until(lambda: len(relayed["A"]) >= 5 and len(relayed["B"]) >= 5, timeout=30, spin=probe)
            assert private == []           # a group's private topic never reaches the broker
            # each group's log holds its own nodes' lines, and what the container says of it
            log_a = (tmp_path / "A.log").read_text()
            assert "A/listener" in log_a and "B/" not in log_a and "every topic under A/" in log_a

            # a third group cannot start (no such node): said in its ready file; the others go on
            assert pool.load("C", command("C", [{"node": "no_such_node", "name": "x"}])) != pool.container_of("A")
            wait_until(lambda: _said(tmp_path / "C.ready").startswith("failed: node x: node 'no_such_node'"),
                       timeout=60)
            assert not pool.running("C") and pool.running("A")   # placed, but it said it failed
            pool.unload("C")

            pool.unload("A")               # its nodes stop; B's go on in the same process
            time.sleep(0.5)
            probe.spin(0.3)
            a_count, b_count = len(relayed["A"]), len(relayed["B"])
            probe.spin(1.0)
            assert len(relayed["A"]) == a_count and len(relayed["B"]) >= b_count + 20
            assert pool.pids() == [first]
            assert "A: unloaded" in (tmp_path / "A.log").read_text()

            os.kill(first, signal.SIGKILL)  # the container dies: started again with B
            wait_until(lambda: not pool.running("B"), timeout=10)
            (tmp_path / "B.ready").unlink()
            assert pool.check() == {"B": "again"} and pool.running("B") and pool.pids() != [first]
            wait_until(lambda: _said(tmp_path / "B.ready") == "ready", timeout=60)
            b_count = len(relayed["B"])
            wait_until(lambda: len(relayed["B"]) >= b_count + 5, timeout=30, spin=probe)
            assert pool.restarts == 1
            survivor = pool.pids()[0]
        finally:
            pool.close()
        assert pool.pids() == []
        wait_until(lambda: not Path(f"/proc/{survivor}").exists() or "Z" in
                   Path(f"/proc/{survivor}/stat").read_text().rsplit(")", 1)[1].split()[0], timeout=10)


def test_a_pool_spreads_groups_over_its_containers_first_then_fills_the_least_loaded(tmp_path):
    with running_broker() as bus:
        pool = ContainerPool(3, _bus_file(tmp_path, bus), tmp_path / "logs", spread=2)
        try:
            def empty(gid):
                return lambda: {"namespace": gid, "nodes": [], "ready_file": str(tmp_path / f"{gid}.ready")}
            placed = [pool.load(gid, empty(gid)) for gid in "ABCDEF"]
            assert placed == ["container-1", "container-2", "container-1", "container-2", "container-1", "container-2"]
            pool.unload("A")
            pool.unload("C")
            assert pool.load("G", empty("G")) == "container-1"         # the least loaded
            assert pool.load("H", empty("H")) == "container-1"
            assert pool.load("I", empty("I")) == "container-3"         # both full (3 each): a third
            wait_until(lambda: all(_said(tmp_path / f"{g}.ready") == "ready" for g in "BDEFGHI"), timeout=60)
            for gid in "BDF":
                pool.unload(gid)
            assert len(pool.pids()) == 2                                # container-2 left empty: stopped
        finally:
            pool.close()


def _policies(pid: int) -> dict[int, int]:
    """Each thread of process `pid`: its scheduling policy (os.SCHED_OTHER, os.SCHED_FIFO, ...)."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out[int(task.name)] = os.sched_getscheduler(int(task.name)) & ~os.SCHED_RESET_ON_FORK
        except OSError:   # a thread that ended meanwhile
            pass
    return out


def test_a_realtime_group_raises_its_containers_loop_thread_alone_and_a_plain_one_none(tmp_path):
    """A group whose node says `realtime` (a served participant's haptic loop): its container's loop
    thread runs SCHED_FIFO, and the threads started after it do not inherit that; the container of a
    group that does not ask stays as it was. Where SCHED_FIFO is not permitted (no root, no
    CAP_SYS_NICE) the loop stays normal and the group's log says why."""
    permitted = realtime_permitted()
    with running_broker() as bus:
        pool = ContainerPool(1, _bus_file(tmp_path, bus), tmp_path / "logs", spread=2)
        try:
            def command(ns, realtime):
                recorder = {"node": "recorder", "name": "recorder", "params": {"file": str(tmp_path / f"{ns}.mcap")}}
                talker, listener = _pair()
                talker = {**talker, "realtime": True} if realtime else talker
                return lambda: {"namespace": ns, "nodes": [talker, listener, recorder],
                                "ready_file": str(tmp_path / f"{ns}.ready"), "log": str(tmp_path / f"{ns}.log")}

            assert pool.load("R", command("R", True)) != pool.load("N", command("N", False))
            wait_until(lambda: _said(tmp_path / "R.ready") == _said(tmp_path / "N.ready") == "ready", timeout=60)
            raised, plain = _policies(pool.processes[0].proc.pid), _policies(pool.processes[1].proc.pid)
            loop = raised.pop(pool.processes[0].proc.pid)
            assert plain.pop(pool.processes[1].proc.pid) == os.SCHED_OTHER
            # The same nodes' other threads, thread for thread: the recorder's writer and its pool stay
            # normal (the receiver, which stamps, and ZeroMQ's I/O threads are real-time in both where
            # permitted).
            assert sorted(raised.values()) == sorted(plain.values()) and os.SCHED_OTHER in raised.values()
            log = (tmp_path / "R.log").read_text()
            if permitted:
                assert loop == os.SCHED_FIFO and "the container's loop runs at real-time priority (SCHED_FIFO 9)" in log
            else:
                assert loop == os.SCHED_OTHER and "R: real-time priority not permitted" in log
        finally:
            pool.close()


def test_a_realtime_group_where_that_is_not_permitted_loads_at_normal_priority_and_says_so(tmp_path, monkeypatch, caplog):
    asked = []
    monkeypatch.setattr(container_module, "raise_loop_priority", lambda: asked.append(1) or False)
    with running_broker() as bus:
        executor = Executor()
        box = Container(executor, bus.for_clients())
        try:
            for gid in ("A", "B"):
                talker, listener = _pair()
                box.load({"load": gid, "namespace": gid, "nodes": [{**talker, "realtime": True}, listener],
                          "ready_file": str(tmp_path / f"{gid}.ready")})
                assert _said(tmp_path / f"{gid}.ready") == "ready"
            assert asked == [1]                  # asked once, at the first such group
            assert "A: real-time priority not permitted (needs root or CAP_SYS_NICE)" in caplog.text
            assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_OTHER
        finally:
            box.unload_all()
            executor.close()


def test_a_node_that_asks_to_stop_restarts_its_own_group_and_the_others_run_on(tmp_path, monkeypatch):
    monkeypatch.setattr(container_module, "RESPAWN_DELAY_S", 0.1)
    with running_broker() as bus:
        executor = Executor()
        box = Container(executor, bus.for_clients())
        try:
            for ns in ("A", "B"):
                recorder = {"node": "recorder", "name": "recorder", "params": {"file": str(tmp_path / f"{ns}.mcap")}}
                box.load({"load": ns, "namespace": ns, "nodes": [*_pair(), recorder],
                          "ready_file": str(tmp_path / f"{ns}.ready")})
            assert _said(tmp_path / "A.ready") == "ready" and _said(tmp_path / "B.ready") == "ready"
            executor.spin(0.5)
            assert executor.local.private == {b"A/example/pose", b"B/example/pose"}
            a_nodes, b_nodes = list(box.groups["A"].nodes), list(box.groups["B"].nodes)
            a_nodes[1].request_shutdown()          # e.g. a recorder whose disk is full (its group's recorder: its log ends)
            deadline = time.monotonic() + 10
            while box.groups["A"].nodes == a_nodes and time.monotonic() < deadline:
                executor.spin(0.5)                 # returns early: the container has work between spins
                box.run_pending()
            assert not executor.stopping           # the process runs on
            assert box.groups["A"].nodes != a_nodes and all(n._closed for n in a_nodes)
            assert box.groups["B"].nodes == b_nodes and not any(n._closed for n in b_nodes)
            box.unload("B")
            assert executor.local.private == {b"A/example/pose"}
            # each group's recorder logged its own private poses, not the other group's
            topics = set(LogReader(tmp_path / "B.mcap").topics())
            assert "example/pose" in topics and not any(t.startswith("A/") for t in topics)
        finally:
            box.unload_all()
            executor.close()


def test_the_ready_file_names_the_port_a_page_server_bound_for_port_0(tmp_path):
    """A port picked by the supervisor and bound later in the container could be taken meanwhile (any
    connection's own end may get it): the node binds any free one, and the ready file says which."""
    import urllib.request
    with running_broker() as bus:
        executor = Executor()
        box = Container(executor, bus.for_clients())
        try:
            tracker = {"node": "webxr", "name": "tracker",
                       "params": {"port": 0, "save_calibration": False, "cert_dir": str(tmp_path / "tls")}}
            box.load({"load": "A", "namespace": "A", "nodes": [tracker], "ready_file": str(tmp_path / "A.ready")})
            box.load({"load": "B", "namespace": "B", "nodes": _pair(), "ready_file": str(tmp_path / "B.ready")})
            said = _said(tmp_path / "A.ready")
            assert said.startswith("ready {") and _said(tmp_path / "B.ready") == "ready"   # B serves nothing
            port = json.loads(said.removeprefix("ready"))["tracker"]["page"]
            assert port == box.groups["A"].nodes[0].server.port > 0
            served = threading.Thread(target=executor.spin, args=(3.0,))
            served.start()
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as response:
                    assert response.status == 200 and b"<canvas" in response.read()
            finally:
                executor.request_shutdown()
                served.join()
        finally:
            box.unload_all()
            executor.close()


def test_bad_commands_are_said_and_the_container_goes_on(caplog):
    executor = Executor()
    box = Container(executor, bus=None)
    box.feed(b'{"load": "A", "nodes": "not a list"}\n[1, 2]\nnot json\n{"unl')
    assert [c.get("load") for c in box.pending] == ["A"]
    assert "got b'[1, 2]'" in caplog.text and "got b'not json'" in caplog.text
    box.feed(b'oad": "B"}\n')
    assert box.pending[-1] == {"unload": "B"}
    box.run_pending()   # the load refused (its nodes are no list), the unload of nothing: nothing happens
    assert "load A: nodes: expected a JSON list" in caplog.text and box.groups == {}
    box.groups["X"] = container_module.Group("X", {"namespace": "A"})   # a group loaded under A already
    box.load({"load": "Y", "namespace": "A", "nodes": []})
    assert "load Y: namespace 'A' is another loaded group's" in caplog.text and set(box.groups) == {"X"}
    executor.close()


CRASHER = '''
import os
from touch4d.bus import Node, Param


class Crasher(Node):
    """Kills its whole process a moment after it starts (as a native fault in a node would)."""

    PARAMS = {"after_s": Param(0.3, "how long it runs first", unit="s")}

    def setup(self) -> None:
        self.call_later(self.params["after_s"], lambda: os._exit(3))
'''


def test_a_group_that_keeps_killing_its_container_ends_up_alone_then_stopped_and_the_others_run_on(tmp_path):
    (tmp_path / "crasher_node.py").write_text(CRASHER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))}
    with running_broker() as bus, Node("probe", bus=bus.for_clients(), heartbeat=False) as probe:
        relayed = {ns: collect(probe, f"{ns}/example/relay", HandPose) for ns in ("A", "B")}
        pool = ContainerPool(4, _bus_file(tmp_path, bus), tmp_path / "logs", popen={"env": env})

        def command(ns, nodes):
            return lambda: {"namespace": ns, "nodes": nodes, "ready_file": str(tmp_path / f"{ns}.ready"),
                            "log": str(tmp_path / f"{ns}.log")}

        def next_death() -> dict:
            wait_until(lambda: any(not p.alive for p in pool.processes), timeout=60)
            return pool.check()

        try:
            pool.load("A", command("A", _pair()))
            pool.load("B", command("B", _pair()))
            pool.load("X", command("X", [{"node": "crasher_node:Crasher", "name": "crasher"}]))
            assert len(pool.pids()) == 1                                    # the three share a process
            # the first death: all three together again, in one new process
            assert next_death() == {"A": "again", "B": "again", "X": "again"} and len(pool.pids()) == 1
            # the second within the window: each alone
            assert next_death() == {"A": "alone", "B": "alone", "X": "alone"} and len(pool.pids()) == 3
            assert len({pool.container_of(g) for g in "ABX"}) == 3
            # the third, X alone in its process: not started again, and it says why
            assert next_death() == {"X": "given up"}
            assert not pool.running("X") and pool.container_of("X") is None
            assert _said(tmp_path / "X.ready") == f"failed: its process died 3 times in {pool_module.CRASH_WINDOW_S:g} s; not started again"
            assert "not started again" in (tmp_path / "X.log").read_text()
            # the others run on, each in its own process; nothing else dies
            wait_until(lambda: _said(tmp_path / "A.ready") == _said(tmp_path / "B.ready") == "ready", timeout=60)
            counts = {ns: len(relayed[ns]) for ns in "AB"}
            wait_until(lambda: all(len(relayed[ns]) >= counts[ns] + 10 for ns in "AB"), timeout=30, spin=probe)
            assert pool.check() == {} and pool.restarts == 1 + 3 and len(pool.pids()) == 2
            # a group that kept dying is loaded alone from then on (e.g. its participant's link opened again)
            pool.load("X", command("X", [{"node": "crasher_node:Crasher", "name": "crasher", "params": {"after_s": 60}}]))
            assert pool.processes[-1].solo and len(pool.pids()) == 3
            # a group that never died shares as before, never with a solo one: a container of its own here
            # (A's and B's are solo), which is not solo: the next ordinary group joins it
            assert pool.load("C", command("C", [])) not in {pool.container_of(g) for g in "ABX"}
            assert not pool.processes[-1].solo and len(pool.pids()) == 4
            assert pool.load("D", command("D", [])) == pool.container_of("C")
        finally:
            pool.close()
        assert pool.pids() == []


def test_a_death_counts_even_when_its_group_is_taken_out_before_the_pool_looks(tmp_path):
    """The study server may see a stack gone (and unload it) before the pool's check: the death counts."""
    (tmp_path / "crasher_node.py").write_text(CRASHER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))}
    with running_broker() as bus:
        pool = ContainerPool(4, _bus_file(tmp_path, bus), tmp_path / "logs", popen={"env": env})
        crasher = lambda: {"namespace": "X", "nodes": [{"node": "crasher_node:Crasher", "name": "crasher"}],  # noqa: E731
                           "ready_file": str(tmp_path / "X.ready")}
        try:
            for _ in range(pool_module.ISOLATE_AFTER):
                pool.load("X", crasher)
                assert not pool.processes[-1].solo
                wait_until(lambda: not pool.running("X"), timeout=60)
                pool.unload("X")                   # out before any check()
            assert pool.check() == {}
            pool.load("X", crasher)                # died ISOLATE_AFTER times within the window: alone from now on
            assert pool.processes[-1].solo
        finally:
            pool.close()


def test_a_container_that_reads_no_commands_never_holds_its_supervisor_and_is_started_again(tmp_path, monkeypatch):
    monkeypatch.setattr(pool_module, "UNREAD_LIMIT_S", 1.0)
    with running_broker() as bus:
        pool = ContainerPool(100, _bus_file(tmp_path, bus), tmp_path / "logs")

        def empty(gid):   # padded: twenty of them are more than a pipe holds (64 kB)
            return lambda: {"namespace": gid, "nodes": [], "ready_file": str(tmp_path / f"{gid}.ready"),
                            "note": "x" * 4096}
        try:
            pool.load("A", empty("A"))
            wait_until(lambda: _said(tmp_path / "A.ready") == "ready", timeout=60)
            stuck = pool.pids()[0]
            os.kill(stuck, signal.SIGSTOP)            # hung: it reads nothing more
            started = time.monotonic()
            groups = [f"G{k:02d}" for k in range(20)]
            for gid in groups:
                pool.load(gid, empty(gid))            # a blocking write would wait here for ever
            assert time.monotonic() - started < 5
            assert pool.check() == {} and pool.pids() == [stuck]   # not yet taken for hung
            time.sleep(1.5)
            (tmp_path / "A.ready").unlink()
            outcome = pool.check()                    # now: killed, and started again with every group
            assert outcome == {gid: "again" for gid in ["A", *groups]}
            assert stuck not in pool.pids() and len(pool.pids()) == 1
            # the new one takes its commands as it reads them: what its pipe did not take goes at each
            # check (the study server checks every half second)
            wait_until(lambda: pool.check() == {} and all(_said(tmp_path / f"{g}.ready") == "ready"
                                                          for g in ["A", *groups]), timeout=60)
        finally:
            pool.close()

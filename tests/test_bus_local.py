"""Intra-process delivery (touch4d.bus.local): nodes of one executor hand messages over in-process,
and the broker still carries them to everyone else."""
from __future__ import annotations

import time

import numpy as np
import pytest

from touch4d.bus import BusConfig, Node
from touch4d.bus.executor import Executor
from touch4d.bus.local import MAX_AWAITED, LocalCopies
from touch4d.bus.testing import collect, free_port, node_process, running_broker
from touch4d.messages import HandPose

pytestmark = pytest.mark.timeout(90)

N = 200


def _spin_until(executors, done, timeout=20.0) -> None:
    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        for ex in executors:
            ex.spin_once(0.01)


def _pose(i: int) -> HandPose:
    return HandPose(position=[i / N, -i / N, 0.5], valid=True)


def test_nodes_of_one_process_and_a_subscriber_in_another_get_every_message_in_order():
    with running_broker() as bus, node_process("example_listener", bus, name="remote",
                                               params={"topic": "example/pose", "relay_topic": "example/relayed"}) as remote:
        assert remote.started
        shared = Executor()
        talker = Node("talker", bus=bus, executor=shared)
        local = Node("local", bus=bus, executor=shared)
        observer = Node("observer", bus=bus)                       # an executor of its own: via the broker
        try:
            heard_here = collect(local, "example/pose", HandPose)
            heard_there = collect(observer, "example/relayed", HandPose)
            pub = talker.create_publisher("example/pose", HandPose)
            for i in range(N):
                pub.publish(_pose(i))
                if i % 20 == 0:
                    shared.spin_once(0)
            _spin_until([shared, observer.executor], lambda: len(heard_here) >= N and len(heard_there) >= N)
            _spin_until([shared, observer.executor], lambda: False, timeout=0.3)   # any duplicate comes meanwhile
            expected = np.array([_pose(i).position for i in range(N)])
            assert [m.seq for m in heard_here] == list(range(N))       # each once, in order
            np.testing.assert_array_equal([m.position for m in heard_here], expected)
            assert all(m.valid and m.stamp > 0 for m in heard_here)
            np.testing.assert_array_equal([m.position for m in heard_there], expected)   # the other process's
            assert local.stats["example/pose"] == {"received": N, "dropped": 0, "malformed": 0, "gaps": 0}
        finally:
            for node in (talker, local, observer):
                node.shutdown()
            shared.close()


def test_a_process_hears_its_own_messages_without_a_broker():
    """Handed over in-process: no broker round trip (here: no broker at all)."""
    bus = BusConfig(pub_port=free_port(), sub_port=free_port(), source="<no broker>")
    shared = Executor()
    talker = Node("talker", bus=bus, executor=shared, connect_timeout=0.2, heartbeat=False)
    local = Node("local", bus=bus, executor=shared, connect_timeout=0.2, heartbeat=False)
    try:
        heard = collect(local, "example/pose", HandPose)
        latest = collect(local, "example/latest", HandPose, latest_only=True)
        pub = talker.create_publisher("example/pose", HandPose)
        pub_latest = talker.create_publisher("example/latest", HandPose)
        for i in range(5):
            pub.publish(_pose(i))
            pub_latest.publish(_pose(i))
        _spin_until([shared], lambda: len(heard) >= 5, timeout=2.0)
        assert [m.seq for m in heard] == [0, 1, 2, 3, 4]
        assert [m.seq for m in latest] == [4]                        # latest-only: the backlog skipped
        assert local.stats["example/latest"]["dropped"] == 4
    finally:
        talker.shutdown()
        local.shutdown()
        shared.close()


def test_the_brokers_copies_are_recognised_a_lost_one_passed_over_and_others_kept():
    copies = LocalCopies()
    for payload in (b"a", b"b", b"c", b"d"):
        copies.expect(b"t", payload, "A")
    assert copies.seen(b"t", b"a")
    assert copies.seen(b"t", b"c")            # b never came (lost on the way): passed over
    assert not copies.seen(b"t", b"b")        # ... and so not skipped were it to come after all
    assert not copies.seen(b"t", b"x")        # another process's message on the topic
    assert not copies.seen(b"u", b"d")        # another topic
    assert copies.seen(b"t", b"d") and not copies.seen(b"t", b"d")
    for i in range(MAX_AWAITED + 10):          # a broker gone: what is awaited stays bounded
        copies.expect(b"t", b"%d" % i, "A")
    assert len(copies.awaited[b"t"]) == MAX_AWAITED


def test_two_publishers_copies_may_come_interleaved_otherwise_and_each_is_skipped_once():
    """Two nodes of the process publishing on one topic: two sockets, whose copies the broker may
    forward in another order than they were handed over."""
    copies = LocalCopies()
    for payload, publisher in ((b"a1", "A"), (b"b1", "B"), (b"a2", "A"), (b"b2", "B")):
        copies.expect(b"t", payload, publisher)
    assert copies.seen(b"t", b"b1")           # before a1: a1 is A's, not lost
    assert copies.seen(b"t", b"b2")
    assert copies.seen(b"t", b"a1") and copies.seen(b"t", b"a2")
    assert not copies.awaited[b"t"]


def test_a_private_topic_reaches_its_process_typed_and_raw_and_never_the_broker():
    """A group's private topic (a launch file's `private`): its subscribers and raw subscribers (a
    recorder) in the process get every message in order; a node of another executor on the same
    broker gets none, while a public topic of the same publisher still reaches it."""
    with running_broker() as bus:
        shared = Executor()
        shared.local.private = frozenset({b"P07/example/pose"})
        talker = Node("talker", bus=bus, executor=shared, namespace="P07")
        local = Node("local", bus=bus, executor=shared, namespace="P07")
        outside = Node("outside", bus=bus, namespace="P07")                 # another process, as far as the bus goes
        try:
            heard = collect(local, "example/pose", HandPose)
            recorded = []
            local.create_raw_subscription("", lambda topic, payload: recorded.append(topic))
            heard_outside = collect(outside, "example/pose", HandPose)
            public_outside = collect(outside, "example/public", HandPose)
            raw_outside = []
            outside.create_raw_subscription("example/", lambda topic, payload: raw_outside.append(topic))
            pub, public = talker.create_publisher("example/pose", HandPose), talker.create_publisher("example/public", HandPose)
            for i in range(N):
                pub.publish(_pose(i))
                public.publish(_pose(i))
            _spin_until([shared, outside.executor], lambda: len(heard) >= N and len(public_outside) >= N)
            _spin_until([shared, outside.executor], lambda: False, timeout=0.3)   # a stray copy comes meanwhile
            assert [m.seq for m in heard] == list(range(N))                      # each once, in order
            np.testing.assert_array_equal([m.position for m in heard], [_pose(i).position for i in range(N)])
            assert recorded.count("example/pose") == N                             # relative to the namespace
            assert heard_outside == [] and "example/pose" not in raw_outside
            assert len(public_outside) == N and raw_outside.count("example/public") == N
            assert not local._local_copies.awaited.get(b"P07/example/pose")      # no broker copy awaited
        finally:
            for node in (talker, local, outside):
                node.shutdown()
            shared.close()

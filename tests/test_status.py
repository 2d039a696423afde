"""The stack status line: rates, touched motors and latency from what passed on the bus."""
import numpy as np

from touch4d.messages import MotorCommand, MotorStatus, MotorTrace
from touch4d.status import StackStatus


def test_status_line_counts_rates_motors_latency_and_boards():
    st = StackStatus(window=2.0)
    for i in range(180):  # 90 Hz for 2 s
        st.on_message("hand/pose", 100.0 + i / 90)
    st.on_message("tactile/motors", 101.9)
    for i in range(10):
        st.on_motors(MotorCommand(names=list("abcd"), intensity=[0, 0.5, 1.0, 0.0], stamp=101.9,
                                  source_stamp=101.9 - 0.002 * i), 101.95)
    st.on_motor_status(MotorStatus(boards=[dict(id=1, online=True, faults=[], last_frame=1.0, state="operational"),
                                           dict(id=2, online=False, faults=["timeout"], last_frame=0.0, state="offline")],
                                   duty=np.zeros(4), bus_load=0.21))
    line = st.line(now=101.99)
    assert "hand/pose 90 Hz" in line
    assert "touched 2/4 motors" in line
    assert "p50 9.0 ms" in line
    assert "boards 1/2 online, CAN load 21%" in line


def test_old_arrivals_leave_the_window():
    st = StackStatus(window=1.0)
    st.on_message("hand/pose", 0.0)
    assert st.rate("hand/pose", 0.5) == 1.0
    st.on_message("hand/pose", 5.0)
    assert st.rate("hand/pose", 5.0) == 1.0 and st.latency_ms(5.0) is None


def test_traced_frames_replace_the_command_latency_when_the_motor_node_traces():
    st = StackStatus(window=2.0)
    st.on_motors(MotorCommand(names=["a"], intensity=[1.0], stamp=10.001, source_stamp=10.0), 10.5)
    assert "pose->motors p50 1.0 ms" in st.line(now=10.6)
    st.on_trace(MotorTrace(source_stamps=np.array([10.0, 10.1]), frame_times=np.array([10.003, 10.105])), 10.6)
    line = st.line(now=10.7)
    assert "pose->CAN p50 4.0 ms" in line and "pose->motors" not in line


def beat(node, publishes=(), subscribes=()):
    from touch4d.messages import Heartbeat

    return Heartbeat(node=node, pid=1, kind=node, publishes=list(publishes), subscribes=list(subscribes), stats={})


def test_topics_that_nodes_wait_for_and_nobody_publishes_are_named_with_the_waiting_nodes():
    st = StackStatus(window=2.0)
    st.on_heartbeat(beat("tactile", ["tactile/motors"], ["hand/pose", "scene/state"]), 10.0)
    st.on_heartbeat(beat("motors", ["motors/status"], ["tactile/motors", "safety/stop?"]), 10.0)
    st.on_heartbeat(beat("renderer", [], ["hand/pose", "scene/state", "tactile/motors"]), 10.0)
    st.on_heartbeat(beat("monitor", [], ["*", "motors/status?"]), 10.0)
    assert "no publisher" not in st.line(now=11.0)  # not before every live node has had time to beat
    st.on_message("hand/pose", 12.5)  # published by something without a heartbeat (a replayed log)
    line = st.line(now=13.0)
    assert line.endswith("no publisher: scene/state (renderer, tactile)")
    st.on_heartbeat(beat("scene", ["scene/state"], ["controller/state"]), 13.5)
    assert st.unpublished(14.0) == {"controller/state": ["scene"]}
    # A node that stopped beating no longer publishes (nor waits for) anything.
    for t in (15.0, 16.0, 17.0, 18.0):
        for name, pubs, subs in (("tactile", ["tactile/motors"], ["hand/pose", "scene/state"]),
                                 ("motors", [], ["tactile/motors"]), ("renderer", [], ["scene/state"])):
            st.on_heartbeat(beat(name, pubs, subs), t)
    # (and the replayed hand/pose has left the window)
    assert st.unpublished(18.0) == {"hand/pose": ["tactile"], "scene/state": ["renderer", "tactile"]}


def test_the_line_says_which_hand_the_tactile_node_follows():
    from touch4d.messages import Heartbeat

    st = StackStatus(window=2.0)
    assert "hand (" not in st.line(now=1.0) and "fingers" not in st.line(now=1.0)
    st.on_heartbeat(Heartbeat(node="tactile", pid=1, kind="tactile", publishes=[], subscribes=[],
                              stats={"hand_joints": 1}), 1.0)
    assert "fingers tracked (hand/joints)" in st.line(now=1.5)
    st.on_heartbeat(Heartbeat(node="tactile", pid=1, kind="tactile", publishes=[], subscribes=[],
                              stats={"hand_joints": 0}), 2.0)
    assert "rigid hand (hand/pose)" in st.line(now=2.5)
    assert "rigid hand" not in st.line(now=10.0)     # the tactile node has gone


def test_an_input_published_by_two_nodes_is_named_with_both_but_not_an_optional_one():
    from touch4d.status import StackStatus

    s = StackStatus()
    for hb in (beat("tracker", ["hand/pose", "safety/stop"]), beat("tracker2", ["hand/pose", "safety/stop"]),
               beat("tactile", ["tactile/motors"], ["hand/pose", "safety/stop?"]), beat("rec", [], ["*"])):
        s.on_heartbeat(hb, 100.0)
    assert s.shared(100.0) == {"hand/pose": ["tracker", "tracker2"]}
    assert "several publishers: hand/pose (tracker, tracker2)" in s.line(100.0)
    assert s.shared(100.0 + 10) == {}   # gone nodes publish nothing

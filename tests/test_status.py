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

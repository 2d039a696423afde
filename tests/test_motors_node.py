"""The motor node on a real topic bus and python-can's virtual bus, with the board emulator."""
from __future__ import annotations

import errno
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest
import yaml

from touch4d.bus import Broker, BusConfig, Node
from touch4d.errors import ConfigError
from touch4d.boards.config import load_glove_can
from touch4d.boards.protocol import GloveProtocol
from touch4d.messages import MotorCommand, MotorStatus, MotorTrace, Stop
from touch4d.nodes.motors import MotorsNode

pytestmark = pytest.mark.timeout(60)

TEST_GLOVE = Path(__file__).parent / "data" / "glove_can_test.yaml"
CFG = load_glove_can(TEST_GLOVE)
NAMES = list(CFG.motor_names)
WAIT = 10.0  # generous: the machine is shared


@pytest.fixture
def bus():
    with Broker(BusConfig(pub_port=0, sub_port=0)) as endpoints:
        yield endpoints


class Rig:
    """A motor node (emulated boards, private CAN channel) and a tester node, spun together."""

    def __init__(self, bus, glove=TEST_GLOVE, bus_factory=None, channel=None, **params):
        self.channel = channel or f"motors-{uuid.uuid4().hex}"
        self.node = MotorsNode(params={"glove": str(glove), "channel": self.channel, "emulate": True,
                                       "status_hz": 20.0, **params}, bus=bus, start=False)
        self.node.can_bus_factory = bus_factory
        self.node.start()
        self.tester = Node("tester", bus=bus, heartbeat=False)
        self.status: list[MotorStatus] = []
        self.tester.create_subscription("motors/status", MotorStatus, self.status.append)
        self.cmd = self.tester.create_publisher("tactile/motors", MotorCommand)
        self.stop_pub = self.tester.create_publisher("safety/stop", Stop)
        self.emu = self.node.emulator

    def spin(self, seconds: float, intensity=None, until=None) -> bool:
        """Spin both nodes; publish `intensity` every 10 ms if given; stop early when `until()` holds."""
        end = time.monotonic() + seconds
        next_cmd = 0.0
        while time.monotonic() < end:
            if intensity is not None and time.monotonic() >= next_cmd:
                self.cmd.publish(MotorCommand(names=NAMES, intensity=np.asarray(intensity, dtype=float)))
                next_cmd = time.monotonic() + 0.01
            self.node.spin_once(0.002)
            self.tester.spin_once(0.0)
            if until is not None and until():
                return True
        return until is None

    def close(self):
        for n in (self.tester, self.node):
            n.shutdown()


@pytest.fixture
def rig(bus):
    r = Rig(bus)
    try:
        yield r
    finally:
        r.close()


# The test glove's duty curve (its `can.duty`): duty = 0.3 + 0.5 V for V >= 0.02, else 0; V above
# 1 counts as 1; the frame carries round(127 duty). Worked by hand for the intensities used below:
LEVEL = {0.8: 89, 0.9: 95}                  # 0.7 and 0.75 x 127 = 88.9 and 95.25


def levels(value) -> list[int]:
    return [LEVEL[value]] * 30


def test_intensities_arrive_as_duty_on_the_right_board_and_channel(rig):
    # Off, under the deadband, at it (0.31 x 127 = 39.37), over full scale (0.8 x 127 = 101.6);
    # then a distinct level per motor, from the intensity that gives it: V = (level / 127 - 0.3) / 0.5.
    want = [0, 0, 39, 102] + [40 + 2 * k for k in range(4, 30)]
    v = np.array([0.0, 0.01, 0.02, 1.2] + [(level / 127 - 0.3) / 0.5 for level in want[4:]])
    assert rig.spin(WAIT, intensity=v, until=lambda: rig.emu.motor_levels() == want)
    for k, level in enumerate(want):
        assert rig.emu.levels(1 + k // 8)[k % 8] == level

    def reported() -> bool:  # a status published after the boards answered and the duties went out
        last = rig.status[-1] if rig.status else None
        return (last is not None and [b["state"] for b in last.boards] == ["operational"] * 4
                and np.allclose(last.duty, np.array(want) / 127))

    assert rig.spin(WAIT, intensity=v, until=reported)
    assert all(b["online"] and b["faults"] == [] for b in rig.status[-1].boards)
    assert 0 < rig.status[-1].bus_load < 0.7


def record_sent(node) -> list[tuple[float, int, tuple]]:
    """(driver time, board, levels) of every duty frame the node sends from now on."""
    log = []
    sent = node.driver.sent

    def recording(out, now):
        if out.board:
            log.append((now, out.board, out.levels))
        sent(out, now)

    node.driver.sent = recording
    return log


def test_silence_turns_every_motor_off_within_the_watchdog(rig):
    v = np.full(30, 0.7)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    frames = record_sent(rig.node)
    assert rig.spin(WAIT, until=lambda: not any(rig.emu.motor_levels()))
    # Timed on the driver's clock, not the test's: no frame turns a motor on later than the
    # watchdog after the last command, and every board's first frame after that is all zero.
    expiry = rig.node.driver.last_command_at + CFG.watchdog_s
    assert all(t <= expiry for t, _, levels in frames if any(levels))
    for board in (1, 2, 3, 4):
        after = [levels for t, b, levels in frames if b == board and t > expiry]
        assert after and after[0] == (0,) * 8
    assert rig.node.driver.errors["watchdog_off"] >= 1
    # the node keeps refreshing zeros: the boards do not trip their own watchdog
    assert_no_trip_but_from_a_pause(rig, frames)


def test_a_receive_failure_does_not_stop_the_refresh_or_the_watchdog(rig):
    v = np.full(30, 0.7)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))

    def broken(msg):
        raise RuntimeError("decoder bug")  # not a FrameError: escapes the frame handling

    frames = record_sent(rig.node)
    rig.node.protocol.decode = broken
    assert rig.spin(WAIT, until=lambda: not any(rig.emu.motor_levels()))
    assert rig.node.driver.errors["receive_error"] >= 1
    assert rig.node.driver.errors["watchdog_off"] >= 1
    # the zeros came from the node's refresh, not from the boards' own watchdog: each board's first
    # frame after the watchdog's expiry is all zero, and the refresh goes on
    expiry = rig.node.driver.last_command_at + CFG.watchdog_s
    for board in (1, 2, 3, 4):
        after = [levels for t, b, levels in frames if b == board and t > expiry]
        assert after and after[0] == (0,) * 8
    more = len(frames)
    rig.spin(0.3)
    assert {b for _, b, _ in frames[more:]} == {1, 2, 3, 4}
    assert_no_trip_but_from_a_pause(rig, frames)


def assert_no_trip_but_from_a_pause(rig, frames) -> None:
    """No board tripped its own watchdog (the node's refresh fed them all), unless this busy test
    process paused between two of that board's frames for half the board's watchdog or more: a
    trip then is the pause's, not the node's (the frames' times are the driver's, when each was sent)."""
    paused = {b for b in (1, 2, 3, 4)
              if np.any(np.diff([t for t, board, _ in frames if board == b]) >= CFG.board_watchdog_s / 2)}
    tripped = {board for board, b in rig.emu.boards.items() if b.watchdog_tripped}
    assert tripped <= paused, (tripped, paused)


def test_stale_commands_never_turn_a_motor_on(bus, tmp_path):
    # A watchdog far longer than the node needs to act on one command: "at once" is then told
    # apart from "after the watchdog".
    rig = Rig(bus, glove=glove_with(tmp_path, watchdog_s=3.0, command_max_age_s=0.1))
    try:
        check_stale_commands(rig)
    finally:
        rig.close()


def check_stale_commands(rig):
    v = np.full(30, 0.7)

    def publish(age):
        rig.cmd.publish(MotorCommand(names=NAMES, intensity=v, source_stamp=time.time() - age))

    assert rig.spin(WAIT, until=lambda: all(b["online"] for b in rig.status[-1].boards) if rig.status else False)
    for _ in range(30):   # delayed by a stall upstream: 0.5 s old on arrival
        publish(0.5)
        assert not rig.spin(0.01, until=lambda: any(rig.emu.motor_levels()))
    assert rig.node.driver.errors["stale_command"] >= 1
    assert rig.spin(WAIT, until=lambda: (rig.status[-1].errors.get("stale_command", 0) >= 1) if rig.status else False)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))   # fresh ones do
    stale = rig.node.driver.errors["stale_command"]
    sent = time.monotonic()
    publish(0.5)   # a stale one after fresh ones: off at once, not after the watchdog
    assert rig.spin(WAIT, until=lambda: not any(rig.emu.motor_levels()))
    assert time.monotonic() - sent < 1.0 and rig.node.driver.errors["stale_command"] == stale + 1


def test_the_age_check_can_be_turned_off_for_unsynchronised_clocks(bus, tmp_path):
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["can"]["command_max_age_s"] = 0
    glove = tmp_path / "no-ntp.yaml"
    glove.write_text(yaml.safe_dump(data))
    r = Rig(bus, glove=glove)
    try:
        old = time.time() - 3600.0   # the PC's clock an hour behind the Pi's

        def publish():
            r.cmd.publish(MotorCommand(names=NAMES, intensity=np.full(30, 0.7), source_stamp=old))

        end = time.monotonic() + WAIT
        while not all(r.emu.motor_levels()) and time.monotonic() < end:
            publish()
            r.spin(0.01)
        assert all(r.emu.motor_levels()) and r.node.driver.errors["stale_command"] == 0
    finally:
        r.close()


def test_board_watchdog_turns_off_when_the_node_stops_sending(rig):
    v = np.full(30, 0.7)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    rig.node.link.close()  # the node's CAN side goes quiet (as if unplugged); the emulator keeps running
    rig.node.link.ensure_open = lambda: "bus_closed"
    deadline = time.monotonic() + WAIT
    while any(rig.emu.motor_levels()) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not any(rig.emu.motor_levels())
    assert all(b.watchdog_tripped for b in rig.emu.boards.values())


def test_stop_turns_everything_off_and_holds(rig):
    v = np.full(30, 0.7)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    rig.stop_pub.publish(Stop(reason="test", origin="tester"))
    # commands keep coming: the stop still wins
    assert rig.spin(WAIT, intensity=v, until=lambda: not any(rig.emu.motor_levels()))
    assert all(b.nmt_state == "STOPPED" for b in rig.emu.boards.values())
    assert rig.spin(0.3, intensity=v) and not any(rig.emu.motor_levels())
    assert rig.spin(WAIT, intensity=v, until=lambda: rig.status and rig.status[-1].errors.get("stops") == 1)


def glove_with(tmp_path, **can_keys) -> Path:
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["can"].update(can_keys)
    glove = tmp_path / "glove.yaml"
    glove.write_text(yaml.safe_dump(data))   # float('inf') is written as YAML .inf
    return glove


def test_a_momentary_stop_releases_after_the_hold(bus, tmp_path):
    r = Rig(bus, glove=glove_with(tmp_path, stop_hold_s=0.3))
    try:
        v = np.full(30, 0.7)
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        r.stop_pub.publish(Stop(reason="test", origin="tester"))
        assert r.spin(WAIT, intensity=v, until=lambda: not any(r.emu.motor_levels()))
        # the hold ends, the boards are started again and the commands drive them
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        assert all(b.nmt_state == "OPERATIONAL" for b in r.emu.boards.values())
    finally:
        r.close()


def test_an_infinite_stop_hold_latches_until_restart(bus, tmp_path):
    glove = glove_with(tmp_path, stop_hold_s=float("inf"))
    assert ".inf" in glove.read_text() and load_glove_can(glove).stop_hold_s == float("inf")
    r = Rig(bus, glove=glove)
    try:
        v = np.full(30, 0.7)
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        r.stop_pub.publish(Stop(reason="test", origin="tester"))
        assert r.spin(WAIT, intensity=v, until=lambda: not any(r.emu.motor_levels()))
        # well past the default hold (1 s), commands still coming: nothing turns on again
        assert not r.spin(1.5, intensity=v, until=lambda: any(r.emu.motor_levels()))
        assert all(b.nmt_state == "STOPPED" for b in r.emu.boards.values())
        assert r.node.driver.errors["ignored_during_stop"] > 10
    finally:
        r.close()
    # a restarted node starts the boards again
    r = Rig(bus, glove=glove, channel=r.channel)
    try:
        assert r.spin(WAIT, intensity=np.full(30, 0.7), until=lambda: all(r.emu.motor_levels()))
    finally:
        r.close()


def node_frames(spy, first_wait: float, then_wait: float, limit: int | None = None) -> list:
    """The NMT and duty frames (the node's, not the boards') a spy on the CAN bus sees, in order."""
    proto = GloveProtocol(CFG)
    frames = []
    m = spy.recv(timeout=first_wait)
    while m is not None and (limit is None or len(frames) < limit):
        f = proto.decode(m)
        if f.kind in ("nmt", "duty"):
            frames.append(f)
        m = spy.recv(timeout=then_wait)
    return frames


def assert_stop_then_zero(frames: list) -> None:
    """The first frame is the broadcast NMT STOP, and every duty frame after it is all zero."""
    assert frames and frames[0].kind == "nmt" and frames[0].signals == {"Command": 2, "Node": 0}
    assert all(GloveProtocol.levels(f, 8) == [0] * 8 for f in frames if f.kind == "duty")


def test_stop_reaches_the_boards_within_one_frame(rig):
    v = np.full(30, 0.7)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    with can.Bus(interface="virtual", channel=rig.channel) as spy:
        rig.node.on_stop(Stop(reason="direct", origin="test"))
        # the boards keep talking: read the node's first frames only
        sent = node_frames(spy, first_wait=WAIT, then_wait=1.0, limit=5)
    assert_stop_then_zero(sent)


def test_a_removed_board_is_reported_while_the_others_keep_working(rig):
    v = np.full(30, 0.5)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    rig.emu.remove(2)

    def reported():
        if not rig.status:
            return False
        boards = {b["id"]: b for b in rig.status[-1].boards}
        return boards[2]["online"] is False and "not_answering" in boards[2]["faults"]

    assert rig.spin(WAIT, intensity=v, until=reported)
    boards = {b["id"]: b for b in rig.status[-1].boards}
    assert all(boards[b]["online"] for b in (1, 3, 4)) and boards[2]["state"] == "offline"
    w = np.full(30, 0.9)
    want = levels(0.9)
    others = [k for k in range(30) if k // 8 != 1]  # motors not on board 2
    assert rig.spin(WAIT, intensity=w, until=lambda: [rig.emu.motor_levels()[k] for k in others]
                    == [want[k] for k in others])
    # plugged back in: it boots, the node starts it again and it follows the commands
    rig.emu.restore(2)
    assert rig.spin(WAIT, intensity=w, until=lambda: rig.emu.motor_levels() == want)
    assert rig.node.driver.errors["nmt_restart"] >= 1


def test_malformed_and_unknown_frames_are_ignored_and_counted(rig):
    v = np.full(30, 0.5)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    with can.Bus(interface="virtual", channel=rig.channel) as rogue:
        rogue.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))     # short status
        rogue.send(can.Message(arbitration_id=0x202, data=b"\x00" * 3, is_extended_id=False))  # short duty
        rogue.send(can.Message(arbitration_id=0x555, data=b"\x00", is_extended_id=False))      # unknown
        rogue.send(can.Message(arbitration_id=0x18FF00AA, data=b"\x00", is_extended_id=True))  # unknown

        def counted():
            e = rig.status[-1].errors if rig.status else {}
            return e.get("malformed_rx", 0) >= 2 and e.get("unknown_rx", 0) >= 2

        assert rig.spin(WAIT, intensity=v, until=counted)
    assert rig.emu.counters["malformed"] >= 2 and rig.emu.counters["unknown"] >= 2
    # Still working: the boards follow the node (waited for, since a stall of the loaded test machine
    # longer than the boards' watchdog switches them off until the next refresh).
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))


def test_thermal_limit_through_the_node(bus, tmp_path):
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["can"]["thermal"] = {"max_on_s": 0.4, "cool_s": 0.6}
    glove = tmp_path / "hot.yaml"
    glove.write_text(yaml.safe_dump(data))
    r = Rig(bus, glove=glove)
    try:
        v = np.full(30, 0.5)
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        on = time.monotonic()
        assert r.spin(WAIT, intensity=v, until=lambda: not any(r.emu.motor_levels()))
        off = time.monotonic()
        assert off - on < 0.4 + 2.0
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        # off for about cool_s (0.6 s) although commanded on all along; the margin covers a slow test loop
        assert time.monotonic() - off >= 0.3
    finally:
        r.close()


class FlakyBus:
    """A virtual bus whose sends can be made to fail like a real controller's."""

    def __init__(self, channel):
        self.inner = can.Bus(interface="virtual", channel=channel)
        self.fail: Exception | None = None
        self.bus_off = False

    def send(self, msg, timeout=None):
        if self.fail is not None:
            raise self.fail
        self.inner.send(msg, timeout)

    def recv(self, timeout=None):
        return self.inner.recv(timeout)

    @property
    def state(self):
        return can.BusState.ERROR if self.bus_off else can.BusState.ACTIVE

    def shutdown(self):
        self.inner.shutdown()


@pytest.mark.parametrize("error, kind", [
    (can.CanOperationError("Failed to transmit: No buffer space available", errno.ENOBUFS), "tx_queue_full"),
    (can.CanOperationError("Failed to transmit: Network is down", errno.ENETDOWN), "bus_off"),
    (can.CanOperationError("Failed to transmit: I/O error", errno.EIO), "send_error"),
])
def test_send_faults_are_reported_and_retried_without_crashing(bus, error, kind):
    holder = {}
    channel = f"motors-{uuid.uuid4().hex}"

    def factory():
        holder["bus"] = FlakyBus(channel)
        return holder["bus"]

    r = Rig(bus, bus_factory=factory, channel=channel)
    try:
        v = np.full(30, 0.5)
        assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
        holder["bus"].fail = error
        holder["bus"].bus_off = kind == "bus_off"
        assert r.spin(WAIT, intensity=v, until=lambda: r.status and r.status[-1].errors.get(kind, 0) > 0)
        # the boards lose their commands: their own watchdog turns them off
        assert r.spin(WAIT, intensity=v, until=lambda: not any(r.emu.motor_levels()))
        holder["bus"].fail = None
        holder["bus"].bus_off = False
        w = np.full(30, 0.8)
        want = levels(0.8)
        assert r.spin(WAIT, intensity=w, until=lambda: r.emu.motor_levels() == want)
        assert all(b["online"] for b in r.status[-1].boards) or r.spin(
            WAIT, intensity=w, until=lambda: all(b["online"] for b in r.status[-1].boards))
    finally:
        r.close()


class RaisingStop(FlakyBus):
    """A driver that raises something other than can.CanError on the NMT STOP frame."""

    def send(self, msg, timeout=None):
        if msg.arbitration_id == CFG.ids.stop and msg.data[0] == 2:
            raise ValueError("driver bug on the stop frame")
        self.inner.send(msg, timeout)


def test_shutdown_sends_zero_duty_even_when_the_stop_frame_raises(bus):
    channel = f"motors-{uuid.uuid4().hex}"
    r = Rig(bus, bus_factory=lambda: RaisingStop(channel), channel=channel)
    with can.Bus(interface="virtual", channel=channel) as spy:
        try:
            assert r.spin(WAIT, intensity=np.full(30, 0.5), until=lambda: all(r.emu.motor_levels()))
            while spy.recv(timeout=0) is not None:
                pass
        finally:
            r.close()    # must not raise
        proto = GloveProtocol(CFG)
        zeros = set()
        m = spy.recv(timeout=1.0)
        while m is not None:
            f = proto.decode(m)
            if f.kind == "duty" and GloveProtocol.levels(f, 8) == [0] * 8:
                zeros.add(f.board)
            m = spy.recv(timeout=0.2)
    assert zeros == {1, 2, 3, 4}
    assert r.node.driver.errors["send_error"] >= 1


def test_a_full_virtual_receive_queue_is_reported_as_a_full_transmit_queue(rig):
    v = np.full(30, 0.5)
    assert rig.spin(WAIT, intensity=v, until=lambda: all(rig.emu.motor_levels()))
    stalled = can.Bus(interface="virtual", channel=rig.channel, rx_queue_size=1)
    try:
        assert rig.spin(WAIT, intensity=v,
                        until=lambda: rig.status and rig.status[-1].errors.get("tx_queue_full", 0) > 0)
    finally:
        stalled.shutdown()
    assert all(rig.emu.motor_levels())


def test_shutdown_sends_stop_before_exit(bus):
    r = Rig(bus)
    channel = r.channel
    with can.Bus(interface="virtual", channel=channel) as spy:
        try:
            v = np.full(30, 0.5)
            assert r.spin(WAIT, intensity=v, until=lambda: all(r.emu.motor_levels()))
            while spy.recv(timeout=0) is not None:
                pass
        finally:
            r.close()
        frames = node_frames(spy, first_wait=1.0, then_wait=0.2)
    assert_stop_then_zero(frames)


def test_a_configuration_over_the_bus_load_limit_is_refused(bus, tmp_path):
    data = yaml.safe_load(TEST_GLOVE.read_text())
    data["can"]["bitrate"] = 125000
    glove = tmp_path / "slow.yaml"
    glove.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="slow.yaml.*bus load"):
        MotorsNode(params={"glove": str(glove), "channel": "never"}, bus=bus)


@pytest.mark.parametrize("status_hz", [0.0, -1.0, float("inf"), float("nan")])
def test_a_bad_parameter_is_refused_with_its_name(bus, status_hz):
    with pytest.raises(ConfigError, match=r"launch\.yaml.*nodes\.motors\.params\.status_hz.*finite number > 0"):
        MotorsNode(params={"glove": str(TEST_GLOVE), "channel": "never", "status_hz": status_hz}, bus=bus,
                   params_source="launch.yaml")
    with pytest.raises(ConfigError, match="status_hz"):
        MotorsNode(params={"glove": str(TEST_GLOVE), "channel": "never", "status_hz": status_hz}, bus=bus)


def test_trace_carries_each_command_source_stamp_and_a_frame_time_after_it(bus, tmp_path):
    # no age check and a long watchdog: a pause of this busy process must not turn the motors off
    r = Rig(bus, glove=glove_with(tmp_path, watchdog_s=3.0, command_max_age_s=0), trace=True)
    traces: list[MotorTrace] = []
    r.tester.create_subscription("motors/trace", MotorTrace, traces.append)
    try:
        stats = r.node.stats_flat
        assert r.spin(WAIT, intensity=np.full(30, 0.1), until=lambda: stats()["trace_traced"] >= 1)  # connected
        r.spin(0.2)
        before = stats()
        traces.clear()
        sent = []
        for k in range(20):
            v = np.full(30, 0.3 + 0.03 * k)    # every command changes every board
            stamp = time.time()
            sent.append(stamp)
            r.cmd.publish(MotorCommand(names=NAMES, intensity=v, source_stamp=stamp))
            r.spin(0.02)
        # every command above taken before the repeat (on a loaded machine the latest-only subscription
        # would otherwise drop the last change for the repeat, which then is a change)
        handled = lambda: sum(stats().get(k, 0) - before.get(k, 0) for k in  # noqa: E731
                              ("trace_traced", "trace_superseded", "tactile/motors:dropped"))
        assert r.spin(WAIT, until=lambda: handled() == len(sent))
        same = time.time()
        r.cmd.publish(MotorCommand(names=NAMES, intensity=v, source_stamp=same))   # nothing to send
        assert r.spin(WAIT, until=lambda: stats()["trace_unchanged"] - before["trace_unchanged"] == 1 and traces
                      and sum(len(t.source_stamps) for t in traces) == stats()["trace_traced"] - before["trace_traced"])
        assert r.emu.motor_levels() == [93] * 30       # V = 0.87: 0.735 x 127 = 93.3
        stamps = np.concatenate([t.source_stamps for t in traces])
        times = np.concatenate([t.frame_times for t in traces])
        assert set(stamps) <= set(sent) and same not in stamps
        assert np.all(times >= stamps) and np.all(times <= time.time())
        after = stats()
        counted = {k: after[k] - before.get(k, 0) for k in after}
        # every command published is traced, superseded, unchanged or skipped by the latest-only subscription
        assert (counted["trace_traced"] + counted["trace_superseded"] + counted["trace_unchanged"]
                + counted["tactile/motors:dropped"]) == len(sent) + 1
        assert counted["trace_traced"] >= len(sent) // 2   # spaced 20 ms apart: most go at once
    finally:
        r.close()


def test_no_trace_without_the_parameter(rig):
    traces = []
    rig.tester.create_subscription("motors/trace", MotorTrace, traces.append)
    assert rig.spin(0.5, intensity=np.full(30, 0.5), until=lambda: False) is False
    assert traces == [] and "trace_traced" not in rig.node.stats_flat()


def board_periods(sent) -> dict[int, float]:
    """Each board's refresh period on the driver's clock: the median interval between its duty
    frames, which a pause of this process (one long interval, then a catch-up burst) leaves alone."""
    return {b: float(np.median(np.diff([t for t, board, _ in sent if board == b]))) for b in (1, 2, 3, 4)}


def late_intervals(sent, longer_than: float) -> int:
    """How many intervals between a board's duty frames (any board) exceeded `longer_than` s."""
    return sum(int(np.sum(np.diff([t for t, board, _ in sent if board == b]) > longer_than)) for b in (1, 2, 3, 4))


@pytest.fixture
def patient_rig(bus, tmp_path):
    """A rig whose node takes a command however late this busy process hands it over (no age check):
    a pause turns the motors off only through the watchdog, until the next command."""
    r = Rig(bus, glove=glove_with(tmp_path, command_max_age_s=0))
    try:
        yield r
    finally:
        r.close()


def test_an_idle_node_refreshes_the_boards_at_the_idle_rate_and_speeds_up_for_a_command(patient_rig):
    rig = patient_rig

    def window(seconds, intensity=None):
        first = len(sent)
        rig.spin(seconds, intensity=intensity)
        return sent[first:]

    assert rig.spin(WAIT, until=lambda: bool(rig.status) and all(b["online"] for b in rig.status[-1].boards))
    # the boards' start-up (NMT START) is paced at the full rate; then the node idles
    assert rig.spin(WAIT, until=lambda: rig.node.refresh_timer.period == pytest.approx(1 / 25))
    trips_before = sum(b.counters["watchdog_trips"] for b in rig.emu.boards.values())
    sent = record_sent(rig.node)
    idle = window(1.0)
    assert all(levels == (0,) * 8 for _, _, levels in idle)
    # 25 Hz (the default idle_refresh_hz), not 200, on every board
    assert rig.node.refresh_timer.period == pytest.approx(1 / 25)
    assert all(1 / 30 < p < 1 / 20 for p in board_periods(idle).values()), board_periods(idle)
    busy = window(1.0, intensity=np.full(30, 0.5))
    assert rig.node.refresh_timer.period == pytest.approx(1 / 200)
    assert all(p < 2 / 200 for p in board_periods(busy).values()), board_periods(busy)  # 200 Hz, 5 ms
    # the idle boards were fed all along: still online, no fault, nothing tripped by their watchdog
    assert rig.spin(WAIT, until=lambda: rig.emu.motor_levels() == [0] * 30)
    idle_again = window(1.0)
    assert rig.node.refresh_timer.period == pytest.approx(1 / 25)
    assert all(1 / 30 < p < 1 / 20 for p in board_periods(idle_again).values()), board_periods(idle_again)
    last = rig.status[-1].boards
    assert all(b["online"] and b["faults"] == [] for b in last), last
    # A board trips when no frame reached it for board_watchdog_s (100 ms, 2.5 idle periods). A
    # frame the node sent late (this process paused: a loaded machine, a garbage collection) may
    # trip its board, and one pause between the node's clock and the boards trips all four at once;
    # anything more is frames the boards did not take (an idle rate too slow trips every board
    # about every period, dozens of trips here).
    trips = sum(b.counters["watchdog_trips"] for b in rig.emu.boards.values()) - trips_before
    late = late_intervals(sent, CFG.board_watchdog_s / 2)
    assert trips <= late + 4, (trips, late)

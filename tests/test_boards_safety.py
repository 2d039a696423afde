"""Failing safe at the glove: every way the motor commands can stop ends with every motor off.

The motor node runs in this process with emulated boards on a private virtual CAN channel; each
test makes the motors buzz, breaks one link of the chain and waits (generously) for silence.
"""
from __future__ import annotations

import dataclasses
import errno
import logging
import os
import signal
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from touch4d.bus import Broker, BusConfig, Node
from touch4d.bus.testing import node_process
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import MAX_WAIT_S, GloveEmulator
from touch4d.boards.link import CanLink
from touch4d.boards.protocol import GloveProtocol
from touch4d.messages import HandPose, MotorCommand, SceneState, Stop
from touch4d.nodes.motors import MotorsNode

pytestmark = pytest.mark.timeout(90)

TEST_GLOVE = Path(__file__).parent / "data" / "glove_can_test.yaml"
WAIT = 15.0  # generous: the machine is shared


class Chain:
    """Broker, motor node (emulated boards) and a tester node that publishes what the test needs."""

    def __init__(self, glove=TEST_GLOVE, bus_factory=None, channel=None):
        self.broker = Broker(BusConfig(pub_port=0, sub_port=0))
        self.bus = self.broker.start()
        self.broker_up = True
        self.channel = channel or f"safety-{uuid.uuid4().hex}"
        self.node = MotorsNode(params={"glove": str(glove), "channel": self.channel, "emulate": True},
                               bus=self.bus, heartbeat=False, start=False)
        self.node.can_bus_factory = bus_factory
        self.node.start()
        self.emu = self.node.emulator
        self.names = list(self.node.cfg.motor_names)
        self.tester = Node("tester", bus=self.bus, heartbeat=False)
        self.cmd = self.tester.create_publisher("tactile/motors", MotorCommand)

    def spin_until(self, until, publish=None, timeout=WAIT) -> bool:
        """Spin both nodes, calling `publish()` every 10 ms, until `until()` holds."""
        end = time.monotonic() + timeout
        next_pub = 0.0
        while time.monotonic() < end:
            if publish is not None and time.monotonic() >= next_pub:
                publish()
                next_pub = time.monotonic() + 0.01
            self.node.spin_once(0.002)
            self.tester.spin_once(0.0)
            if until():
                return True
        return False

    def command(self, value=0.7):
        self.cmd.publish(MotorCommand(names=self.names, intensity=np.full(len(self.names), value)))

    def buzzing(self) -> bool:
        return all(self.emu.motor_levels())

    def silent(self) -> bool:
        return not any(self.emu.motor_levels())

    def stop_broker(self):
        if self.broker_up:
            self.broker_up = False
            self.broker.stop()

    def close(self):
        try:
            self.tester.shutdown()
            self.node.shutdown()
        finally:
            self.stop_broker()


@pytest.fixture
def chain():
    c = Chain()
    try:
        yield c
    finally:
        c.close()


def test_broker_death_turns_every_motor_off(chain):
    assert chain.spin_until(chain.buzzing, publish=chain.command)
    chain.stop_broker()
    assert chain.spin_until(chain.silent, publish=chain.command)  # the tester keeps trying: nothing arrives
    assert chain.node.driver.errors["watchdog_off"] >= 1


def test_an_exception_in_the_command_callback_leaves_the_motors_off(chain):
    assert chain.spin_until(chain.buzzing, publish=chain.command)

    def broken(*args):
        raise RuntimeError("bug in the command path")

    chain.node.driver.command = broken
    assert chain.spin_until(chain.silent, publish=chain.command)
    assert chain.node.stats_flat()["errors"] >= 1       # counted, and the node keeps serving
    assert chain.node.driver.errors["watchdog_off"] >= 1


def test_an_unexpected_send_exception_is_counted_and_the_boards_watchdog_turns_off(chain):
    assert chain.spin_until(chain.buzzing, publish=chain.command)

    def broken(msg, timeout=None):
        raise RuntimeError("driver bug")  # not a can.CanError

    chain.node.link.bus.send = broken
    assert chain.spin_until(chain.silent, publish=chain.command)
    assert all(b.watchdog_tripped for b in chain.emu.boards.values())   # nothing reaches them
    assert chain.node.driver.errors["send_error"] >= 1                  # the node kept going


class Raising:
    """A python-can bus whose send and recv raise what a driver should not (but may)."""

    def __init__(self, exc):
        self.exc = exc

    def send(self, msg, timeout=None):
        raise self.exc

    def recv(self, timeout=None):
        raise self.exc

    def shutdown(self):
        raise self.exc


@pytest.mark.parametrize("exc", [OSError(errno.EIO, "Input/output error"), ValueError("bad dlc"),
                                 AttributeError("'NoneType' object has no attribute 'send'")])
def test_the_link_turns_any_exception_into_a_counted_fault_logged_once(exc, caplog):
    proto = GloveProtocol(load_glove_can(TEST_GLOVE))
    link = CanLink("virtual", "unused", 500000, bus=Raising(exc))
    with caplog.at_level(logging.WARNING, logger="touch4d.boards.link"):
        for _ in range(3):
            assert link.send(proto.nmt("STOP")) == "send_error"
            assert link.receive() == ([], "receive_error")
    assert type(exc).__name__ in link.last_error
    assert [r.getMessage().split(" from ")[1].split(" ")[0] for r in caplog.records] == ["send", "receive"]
    link.close()   # must not raise either
    assert link.bus is None


class DropFirstStop:
    """A virtual bus that loses the first broadcast NMT STOP, as a board that misses it would."""

    def __init__(self, channel, protocol):
        self.inner = can.Bus(interface="virtual", channel=channel)
        self.protocol = protocol
        self.dropped = 0

    def send(self, msg, timeout=None):
        frame = self.protocol.decode(msg)
        if frame.kind == "nmt" and frame.signals["Command"] == 2 and not self.dropped:
            self.dropped += 1
            return
        self.inner.send(msg, timeout)

    def recv(self, timeout=None):
        return self.inner.recv(timeout)

    @property
    def state(self):
        return can.BusState.ACTIVE

    def shutdown(self):
        self.inner.shutdown()


def test_boards_that_miss_the_stop_are_still_turned_off_and_stopped_again():
    channel = f"safety-{uuid.uuid4().hex}"
    holder = {}

    def factory():
        holder["bus"] = DropFirstStop(channel, GloveProtocol(load_glove_can(TEST_GLOVE)))
        return holder["bus"]

    c = Chain(bus_factory=factory, channel=channel)
    try:
        stop = c.tester.create_publisher("safety/stop", Stop)
        assert c.spin_until(c.buzzing, publish=c.command)
        stop.publish(Stop(reason="test", origin="tester"))
        # The STOP frame is lost, the zero duty frames that follow it are not; commands keep coming.
        assert c.spin_until(c.silent, publish=c.command)
        assert holder["bus"].dropped == 1
        assert c.spin_until(lambda: all(b.nmt_state == "STOPPED" for b in c.emu.boards.values()),
                            publish=c.command)
        assert c.node.driver.errors["nmt_restop"] >= 1
        assert c.silent()
    finally:
        c.close()


def tesseract_scene() -> SceneState:
    obj = SceneObject(name="cube", shape="tesseract", size=1.2, position=np.array([0, 0, 0, 1.6]))
    return Scene(objects=[obj], projection="orthographic", revision=1).to_message()


def test_a_killed_tactile_node_leaves_every_motor_off():
    c = Chain(glove="")  # the default glove, the tactile node's
    try:
        scene_pub = c.tester.create_publisher("scene/state", SceneState)
        pose_pub = c.tester.create_publisher("hand/pose", HandPose)
        scene = tesseract_scene()

        def publish():
            scene_pub.publish(scene)
            pose_pub.publish(HandPose(position=np.array([-0.14, -0.18, 0.0]),
                                      orientation=np.array([0.0, 0.0, 0.0, 1.0]), valid=True))

        with node_process("tactile", c.bus) as tactile:
            assert c.spin_until(c.buzzing, publish=publish, timeout=60), tactile.text
            os.kill(tactile.proc.pid, signal.SIGKILL)
            tactile.proc.wait(WAIT)
            assert c.spin_until(c.silent, publish=publish)   # the tracker keeps going; tactile is gone
        assert c.node.driver.errors["watchdog_off"] >= 1
    finally:
        c.close()


def test_the_emulator_blocks_only_until_a_board_watchdog_is_due():
    cfg = dataclasses.replace(load_glove_can(TEST_GLOVE), status_hz=1.0, heartbeat_hz=1.0)
    clock = {"t": 100.0}
    emu = GloveEmulator(cfg, interface="virtual", channel=f"safety-{uuid.uuid4().hex}", clock=lambda: clock["t"])
    try:
        proto = GloveProtocol(cfg)
        emu.step(timeout=0)                        # boot-up heartbeats and first status go out
        assert emu.next_wait(100.0) == MAX_WAIT_S    # nothing due within the cap
        for msg in [proto.nmt("START")] + [proto.duty(b.id, [50] * 8, 1) for b in cfg.boards]:
            emu.process(msg, 100.0)
        emu.step(timeout=0)                        # the status on the change of state
        clock["t"] = 100.08
        assert emu.next_wait(100.08) == pytest.approx(cfg.board_watchdog_s - 0.08)   # the watchdog is next
        assert all(emu.motor_levels())
        clock["t"] = 100.0 + cfg.board_watchdog_s + 0.001
        assert emu.next_wait(clock["t"]) == 0.0
        emu.step()
        assert not any(emu.motor_levels()) and all(b.watchdog_tripped for b in emu.boards.values())
    finally:
        emu.stop()

"""A frozen motor node (SIGSTOP for 2 s in the middle of a touch, then SIGCONT): the boards turn
every channel off by their own watchdog within 100 ms of the last duty frame, and the commands
that queued up during the freeze, all older than `can.command_max_age_s` when the node wakes, never
reach a board. On the Python board emulator and on the firmware's core.

The motor node runs as its own process; the boards run in this process, on a CAN bus the two share
(python-can's udp_multicast on loopback, on a group of this test's own), with a listener beside
them that records every frame on the bus."""
from __future__ import annotations

import dataclasses
import os
import signal
import tempfile
import threading
import time
from pathlib import Path

import can
import numpy as np
import pytest
import yaml

from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import make_glove_emulator
from touch4d.boards.protocol import GloveProtocol
from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.messages import MotorCommand, MotorStatus

pytestmark = pytest.mark.timeout(120)
FREEZE_S = 2.0
QUIET_S = 0.3          # commands stop this long before the node wakes: every queued one is stale
WATCHDOG_SLACK_S = 0.05  # the emulator's thread and this test's sampling on a shared machine


class Frames(can.Listener):
    """Every frame on the bus, with the monotonic time it was seen."""

    def __init__(self):
        self.frames: list[tuple[float, can.Message]] = []
        self.lock = threading.Lock()

    def on_message_received(self, msg):
        with self.lock:
            self.frames.append((time.monotonic(), msg))

    def duty_after(self, protocol: GloveProtocol, since: float) -> list[tuple[float, int, list[int]]]:
        """(time, board, levels) of every duty frame seen after `since`."""
        with self.lock:
            frames = [(t, m) for t, m in self.frames if t > since]
        out = []
        for t, m in frames:
            frame = protocol.decode(m)
            if frame is not None and frame.kind == "duty":
                out.append((t, frame.board, protocol.levels(frame, 8)))
        return out


def glove_file(group: str, max_age: float | None) -> Path:
    data = yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "glove.yaml").read_text())
    data["can"].update(interface="udp_multicast", channel=group)
    if max_age is not None:
        data["can"]["command_max_age_s"] = max_age
    path = Path(tempfile.mkdtemp(prefix="freeze-")) / "glove.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def freeze_motor_node(kind: str, group: str, max_age: float | None = None) -> dict:
    glove = glove_file(group, max_age)
    cfg = load_glove_can(glove)
    protocol = GloveProtocol(cfg)
    emu = make_glove_emulator(kind, cfg).start()
    listen = can.Bus(interface="udp_multicast", channel=group)
    frames = Frames()
    notifier = can.Notifier(listen, [frames])
    names = list(cfg.motor_names)
    result = {}
    try:
        with running_broker() as bus, node_process("motors", bus, params={"glove": str(glove)}) as motors:
            with Node("tester", bus=bus, heartbeat=False) as tester:
                cmd = tester.create_publisher("tactile/motors", MotorCommand)
                status = collect(tester, "motors/status", MotorStatus)

                def touch():
                    cmd.publish(MotorCommand(names=names, intensity=np.full(len(names), 0.7)))
                    tester.spin_once(0.01)
                    return all(emu.motor_levels())

                wait_until(touch, timeout=60, interval=0.0)
                os.kill(motors.pid, signal.SIGSTOP)
                frozen_at = time.monotonic()
                off_at = None
                try:
                    while time.monotonic() < frozen_at + FREEZE_S:   # the tracker and tactile go on
                        if time.monotonic() < frozen_at + FREEZE_S - QUIET_S:
                            cmd.publish(MotorCommand(names=names, intensity=np.full(len(names), 0.7)))
                        if off_at is None and not any(emu.motor_levels()):
                            off_at = time.monotonic()
                        time.sleep(0.002)
                finally:
                    os.kill(motors.pid, signal.SIGCONT)
                woke_at = time.monotonic()
                last_frame = max(t for t, _, _ in frames.duty_after(protocol, 0.0) if t <= frozen_at + 0.01)
                on_after = []
                while time.monotonic() < woke_at + 1.0:               # the queued commands arrive
                    if any(emu.motor_levels()):
                        on_after.append(time.monotonic() - woke_at)
                    tester.spin_once(0.002)
                result.update(woke_at=woke_at, frozen_at=frozen_at, off_at=off_at, last_frame=last_frame, on_after=on_after,
                              duty_after=[d for d in frames.duty_after(protocol, woke_at) if any(d[2])],
                              zero_after=[d for d in frames.duty_after(protocol, woke_at) if not any(d[2])],
                              stale=max((s.errors.get("stale_command", 0) for s in status), default=0))
                # The node is alive, not just silent: a fresh command turns the motors on again.
                result["recovered"] = wait_until(touch, timeout=30, interval=0.0)
    finally:
        notifier.stop()
        listen.shutdown()
        emu.stop()
    return result


@pytest.mark.parametrize("kind", ["python", "firmware"])
def test_a_frozen_motor_node_never_delivers_its_stale_commands_and_the_boards_go_off_by_themselves(kind, can_group):
    r = freeze_motor_node(kind, can_group)
    assert r["off_at"] is not None, "the boards stayed on through a 2 s freeze"
    # The boards' own watchdog (100 ms since the last applied duty frame; the node is frozen).
    assert r["off_at"] - r["last_frame"] <= 0.1 + WATCHDOG_SLACK_S, r["off_at"] - r["last_frame"]
    assert r["off_at"] - r["frozen_at"] <= 0.1 + WATCHDOG_SLACK_S, r["off_at"] - r["frozen_at"]
    # Woken, the node reads commands 0.3-2 s old: none turns a motor on. Only a frame the freeze caught
    # in the instant before it left (the last Python lines before the send) may go out late; the node
    # corrects it with zero duty at once, before the board's next refresh would.
    late = r["duty_after"]
    assert len(late) <= 1, late
    for t, board, _ in late:
        assert any(b == board and not any(levels) and t < u < t + 0.02 for u, b, levels in r["zero_after"]), late
    assert len(r["on_after"]) <= 5 and all(dt < 0.03 for dt in r["on_after"]), r["on_after"]
    assert r["stale"] >= 1
    assert r["recovered"]


def test_a_stall_between_deciding_the_duties_and_sending_them_sends_no_stale_command():
    """The freeze above lands at a random point of the node's loop; here it lands, every time, in
    the worst place: after the node decided a command's duties and before it sent them."""
    import uuid

    from touch4d.bus.testing import running_broker as broker
    from touch4d.nodes.motors import MotorsNode

    channel = f"stall-{uuid.uuid4().hex}"
    listen = can.Bus(interface="virtual", channel=channel)
    with broker() as bus:
        node = MotorsNode(params={"channel": channel}, bus=bus, heartbeat=False)
        try:
            names = list(node.cfg.motor_names)
            decide, stalls = node.driver.outgoing, []

            def decide_then_stall(*args, **kwargs):
                out = decide(*args, **kwargs)
                if any(o.board for o in out) and not stalls:
                    stalls.append(1)
                    time.sleep(0.3)                  # SIGSTOP here: the process is frozen for 0.3 s
                return out

            node.driver.outgoing = decide_then_stall
            node.on_command(MotorCommand(names=names, intensity=np.full(len(names), 0.7), stamp=time.time(),
                                         source_stamp=time.time()))
            frames = []
            while (msg := listen.recv(0.05)) is not None:
                frames.append(PROTOCOL.decode(msg))
        finally:
            node.shutdown()
            listen.shutdown()
    duty = [PROTOCOL.levels(f, 8) for f in frames if f is not None and f.kind == "duty"]
    assert duty and not any(any(levels) for levels in duty), duty   # decided again: all off
    assert node.driver.errors["stalled"] == 1


PROTOCOL = GloveProtocol(load_glove_can(None))

"""The study's gate: what each condition allows, and the motor node holding every duty at 0 in a visual
trial (read as CAN frames on the virtual bus and as the emulated boards' levels), whatever the
tactile node commands, also after the study node has gone silent."""
from __future__ import annotations

import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.boards.protocol import GloveProtocol
from touch4d.bus import Broker, BusConfig, Node
from touch4d.messages import MotorCommand, StudyTrial
from touch4d.nodes.motors import MotorsNode
from touch4d.study.gate import CLOSED, OPEN, Allowed, StudyGate, allowed

pytestmark = pytest.mark.timeout(60)

TEST_GLOVE = Path(__file__).parent / "data" / "glove_can_test.yaml"
CFG = load_glove_can(TEST_GLOVE)
NAMES = list(CFG.motor_names)


def trial(condition="visual", phase="stimulus", index=0) -> StudyTrial:
    return StudyTrial(study="s", participant="P01", phase=phase, index=index, total=3, condition=condition,
                      task="front", kind="front-element", stimulus="face", prompt="?",
                      options=["face", "edge", "vertex"], time_limit_s=10.0)


def test_each_condition_allows_what_it_names_and_only_in_the_stimulus_phase():
    assert allowed("visual") == Allowed(objects=True, motors=False)
    assert allowed("touch") == Allowed(objects=False, motors=True)
    assert allowed("visual+touch") == Allowed(objects=True, motors=True)
    for phase in ("idle", "break", "paused", "done"):
        for condition in ("visual", "touch", "visual+touch"):
            assert allowed(condition, phase) == CLOSED
    assert allowed("smell") == CLOSED
    assert StudyGate("closed").state == CLOSED       # a study's launch: closed until the study says more
    with pytest.raises(ValueError, match="open, closed"):
        StudyGate("ajar")
    gate = StudyGate()
    assert gate.state == OPEN                       # no study: the demo as it always was
    assert gate.update(trial("touch")) and gate.motors and not gate.objects
    assert not gate.update(trial("touch", index=1))  # same gate, next trial: no change
    assert gate.update(trial("touch", "idle")) and gate.state == CLOSED


class Rig:
    """A motor node (emulated boards) on a private virtual CAN channel, a listener on that channel, and
    a tester node publishing tactile/motors and study/trial."""

    def __init__(self, bus):
        self.channel = f"gate-{uuid.uuid4().hex}"
        self.node = MotorsNode(params={"glove": str(TEST_GLOVE), "channel": self.channel, "emulate": True},
                               bus=bus)
        self.tester = Node("tester", bus=bus, heartbeat=False)
        self.cmd = self.tester.create_publisher("tactile/motors", MotorCommand)
        self.trial = self.tester.create_publisher("study/trial", StudyTrial)
        self.listener = can.Bus(interface="virtual", channel=self.channel)
        self.protocol = GloveProtocol(CFG)
        self.channels = {b.id: b.channels for b in CFG.boards}
        self.frames: list[tuple[float, int, int]] = []     # (time, board, highest level in the frame)

    def spin(self, seconds, intensity=None, until=None) -> bool:
        end = time.monotonic() + seconds
        next_cmd = 0.0
        while time.monotonic() < end:
            if intensity is not None and time.monotonic() >= next_cmd:
                self.cmd.publish(MotorCommand(names=NAMES, intensity=np.full(len(NAMES), intensity)))
                next_cmd = time.monotonic() + 0.01
            self.node.spin_once(0.002)
            self.tester.spin_once(0.0)
            while (msg := self.listener.recv(0)) is not None:
                frame = self.protocol.decode(msg)
                if frame is not None and frame.kind == "duty":
                    self.frames.append((time.monotonic(), frame.board,
                                        max(self.protocol.levels(frame, self.channels[frame.board]))))
            if until is not None and until():
                return True
        return until is None

    def duty_frames_on_since(self, t0: float) -> int:
        return sum(1 for when, _, level in self.frames if when >= t0 and level > 0)

    def close(self):
        self.listener.shutdown()
        for n in (self.tester, self.node):
            n.shutdown()


@pytest.fixture
def rig():
    with Broker(BusConfig(pub_port=0, sub_port=0)) as bus:
        r = Rig(bus)
        try:
            yield r
        finally:
            r.close()


def test_a_visual_trial_holds_every_duty_at_zero_and_the_last_gate_holds_when_the_study_falls_silent(rig):
    # no study yet: the motors follow the tactile node
    assert rig.spin(10, intensity=0.7, until=lambda: min(rig.node.emulator.motor_levels()) > 0)
    # a visual trial: off at once, and no duty frame with a motor on while 0.7 keeps being commanded
    rig.trial.publish(trial("visual"))
    assert rig.spin(10, intensity=0.7, until=lambda: max(rig.node.emulator.motor_levels()) == 0)
    t0 = time.monotonic()
    rig.spin(1.0, intensity=0.7)        # the study node says nothing more (dead): its last gate holds
    assert rig.duty_frames_on_since(t0) == 0
    assert len([f for f in rig.frames if f[0] >= t0]) >= 4 * len(CFG.boards)   # zero frames kept flowing
    assert max(rig.node.status().duty) == 0.0
    # a touch trial opens it
    rig.trial.publish(trial("touch", index=1))
    assert rig.spin(10, intensity=0.7, until=lambda: min(rig.node.emulator.motor_levels()) > 0)
    # between trials the motors go off at once, without waiting for the next command
    rig.trial.publish(trial("touch", "idle", index=2))
    assert rig.spin(10, until=lambda: max(rig.node.emulator.motor_levels()) == 0)
    t1 = time.monotonic()
    rig.spin(0.5, intensity=0.7)
    assert rig.duty_frames_on_since(t1) == 0


@pytest.mark.timeout(300)
def test_the_renderer_draws_no_object_pixel_in_a_touch_trial_and_shows_the_prompt():
    """The renderer node (headless, its own draw path): a green tesseract is drawn with no study and in a
    visual trial, and not one green pixel is in a touch trial, while the hand and the prompt still are."""
    from touch4d.bus.testing import running_broker, wait_until
    from touch4d.geometry.scene import parse_scene
    from touch4d.messages import HandPose
    from touch4d.nodes.renderer import RendererNode

    green_scene = parse_scene({"objects": [{"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5],
                                            "color": [0, 1, 0, 1]}]}).to_message()
    with running_broker() as bus:
        node = RendererNode(params={"headless": True, "width": 240, "height": 240, "samples": 0, "rate": 30.0,
                                    "show_status": False, "show_frame": False, "show_tactile": False,
                                    "camera": "yaw=0,pitch=0,distance=4,target=0:0:0,ortho"},
                            bus=bus, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            scene_pub = probe.create_publisher("scene/state", type(green_scene))
            trial_pub = probe.create_publisher("study/trial", StudyTrial)
            pose_pub = probe.create_publisher("hand/pose", HandPose)

            def shown(predicate, *messages):
                def check():
                    for pub, msg in messages:
                        pub.publish(msg)
                    node.spin_once(0.05)
                    if not node.counts["frames"]:
                        return None
                    img = node.renderer.read()
                    return [img] if predicate(img) else None
                return wait_until(check, timeout=120, interval=0.0)[0]

            # the object: pure green; the hand's y axis (0.3, 1, 0.3) is not counted
            green = lambda img: int(((img[..., 1] > 150) & (img[..., 0] < 50) & (img[..., 2] < 50)).sum())  # noqa: E731
            shown(lambda img: green(img) > 200, (scene_pub, green_scene))
            hand = HandPose(position=np.array([0.0, 0.0, 0.0]), orientation=np.array([0.0, 0, 0, 1]), valid=True)
            touch = trial("touch")
            count = node.counts["frames"]
            img = shown(lambda img: node.counts["frames"] > count + 2,
                        (scene_pub, green_scene), (trial_pub, touch), (pose_pub, hand))
            assert node.gate.trial is not None and node.gate.trial.condition == "touch"
            assert green(img) == 0
            hand_pixels = ((img[..., 0] > 180) & (img[..., 1] > 160) & (img[..., 2] > 130)).sum()
            assert hand_pixels > 20                                   # the hand is still drawn
            assert (np.abs(img[:40, :200, :3].astype(int) - img[-1, -1, :3]).sum(axis=2) > 60).sum() > 100  # text
            shown(lambda img: green(img) > 200, (trial_pub, trial("visual", index=1)))
        finally:
            probe.shutdown()
            node.shutdown()

"""Recordings carry the articulated hand: a log with hand/joints replays into a live tactile node,
which follows the recorded fingers."""
import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.log.reader import LogReader
from touch4d.log.writer import LogWriter
from touch4d.messages import HandPose, MotorCommand, encode
from touch4d.nodes.tactile import TactileNode
from touch4d.tactile.glove import load_glove
from touch4d.hands import HandShape

WHERE = np.array([0.0, -0.1, 0.0])
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.mark.timeout(90)
def test_a_recorded_curled_index_replays_through_the_tactile_node(tmp_path):
    glove = load_glove()
    path = tmp_path / "fingers.mcap"
    curled = glove.skeleton.joint_set(WHERE, IDENTITY, glove.units_per_metre, HandShape(curl={"index": 1.0}))
    t0 = 1_700_000_000.0
    with LogWriter(path) as w:
        for i in range(100):                       # 100 Hz for a second: the joints, then the pose
            stamp = t0 + 0.01 * i
            w.write("hand/joints", encode(curled.message(stamp)), int(stamp * 1e9))
            w.write("hand/pose", encode(HandPose(position=WHERE, orientation=IDENTITY, valid=True, stamp=stamp,
                                                 source_stamp=stamp)), int(stamp * 1e9) + 1000)
    assert LogReader(path).topics() == {"hand/joints": "HandJoints", "hand/pose": "HandPose"}
    box = Scene(objects=[SceneObject(name="box", shape="tesseract", size=1.0, position=np.array([0, 0, 0.44, 2.0]),
                                     orientation=np.eye(4), color=np.ones(4))], projection="orthographic")
    with running_broker() as bus:
        tactile = TactileNode(bus=bus, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            tactile.engine.set_scene(box.to_message())
            motors = collect(probe, "tactile/motors", MotorCommand)
            with node_process("replay", bus, name="tracker", params={"file": str(path), "loop": True}) as proc:
                proc.wait_for_line("replaying", timeout=30)
                wait_until(lambda: (tactile.spin_once(0.005), probe.spin_once(0.005)) and len(motors) >= 30,
                           timeout=30, interval=0.0)
        finally:
            probe.shutdown()
            tactile.shutdown()
    assert tactile.counts["joints"] >= 20 and tactile.hand.using == "joints"
    index = [i for i, n in enumerate(glove.motor_names) if n.startswith("index-")]
    palm = [i for i, n in enumerate(glove.motor_names) if n.startswith("palm-")]
    last = motors[-1].intensity
    assert np.all(last[index] == 0) and np.all(last[palm] > 0.3)     # the recorded fingers, not a rigid hand
    assert abs(motors[-1].source_stamp - time.time()) < 30           # restamped: live to the motor node

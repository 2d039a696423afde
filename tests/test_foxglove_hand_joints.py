"""Foxglove's 3D view draws the articulated hand: samples on their bones and the joints' skeleton."""
import time

import numpy as np
import pytest

from test_foxglove_node import GLOVE, POSITION, QUAT, SUBPROTOCOL, FoxgloveClient, protobuf_class
from websockets.sync.client import connect

from touch4d.bus import Node
from touch4d.bus.testing import free_port, node_process, running_broker
from touch4d.messages import HandJoints, HandPose
from touch4d.hands import HandShape
from touch4d.tactile.skeleton import outline_segments

pytestmark = pytest.mark.timeout(120)


def test_foxglove_draws_the_hand_where_its_joints_put_the_samples():
    port = free_port()
    upm = GLOVE.units_per_metre
    joints = GLOVE.skeleton.joint_set(POSITION, QUAT, upm, HandShape(curl={"index": 1.0, "ring": 0.5}))
    with running_broker() as bus, node_process("foxglove", bus, params={"port": port}) as proc:
        proc.wait_for_line(r"Foxglove: open ws://", timeout=60)
        with Node("probe", bus=bus, heartbeat=False) as probe:
            joints_pub = probe.create_publisher("hand/joints", HandJoints)
            pose_pub = probe.create_publisher("hand/pose", HandPose)
            with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
                client = FoxgloveClient(ws)
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:
                    now = time.time()
                    joints_pub.publish(joints.message(now))
                    pose_pub.publish(HandPose(position=POSITION, orientation=QUAT, valid=True, stamp=now))
                    for _ in range(4):
                        client.pump({"foxglove/scene"})
                    updates = client.messages.get("foxglove/scene", [])
                    scene = protobuf_class(client.channel("foxglove/scene")) if updates else None
                    if updates and scene.FromString(updates[-1]).entities[1].lines:
                        break
    update = protobuf_class(client.channel("foxglove/scene")).FromString(client.messages["foxglove/scene"][-1])
    hand = {e.id: e for e in update.entities}["hand"]
    centres = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in hand.spheres])
    placed = GLOVE.skeleton.place("samples", GLOVE.skeleton.transforms(joints.names, joints.positions,
                                                                        joints.orientations, "left", upm))
    np.testing.assert_allclose(centres, placed, atol=1e-9)
    rigid = GLOVE.skeleton.joint_set(POSITION, QUAT, upm)
    assert np.abs(centres - GLOVE.skeleton.place("samples", GLOVE.skeleton.transforms(
        rigid.names, rigid.positions, rigid.orientations, "left", upm))).max() > 0.1       # fingers bent
    ends = np.array([[p.x, p.y, p.z] for p in hand.lines[0].points]).reshape(-1, 2, 3)
    np.testing.assert_allclose(ends, outline_segments(joints.positions), atol=1e-9)

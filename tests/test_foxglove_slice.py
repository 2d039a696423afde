"""The Foxglove node in the slice view: foxglove/scene carries each object's cross-section at
w = slice_w as triangles in its cells' colours, besides the screen and the hand."""
import time

import numpy as np
import pytest
from websockets.sync.client import connect

from touch4d.bus import Node
from touch4d.bus.testing import free_port, node_process, running_broker
from touch4d.geometry.scene import load_scene
from touch4d.messages import HandPose
from touch4d.render.frame import CELL_PALETTE

from test_foxglove_node import SUBPROTOCOL, FoxgloveClient, protobuf_class

pytestmark = pytest.mark.timeout(120)


def test_the_slice_view_is_drawn_as_the_sections_triangles():
    port = free_port()
    scene = load_scene("config/scenes/hypercube.yaml")      # a tesseract of size 1.2 at w = 1.5
    scene.view, scene.slice_w = "slice", 1.5
    msg = scene.to_message()
    with running_broker() as bus, node_process("foxglove", bus, params={"port": port}) as proc:
        proc.wait_for_line(rf"Foxglove: open ws://127\.0\.0\.1:{port}", timeout=60)
        with Node("probe", bus=bus, heartbeat=False) as probe:
            states = probe.create_publisher("scene/state", type(msg))
            pose = probe.create_publisher("hand/pose", HandPose)
            with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
                client = FoxgloveClient(ws)
                deadline = time.monotonic() + 60
                update = None
                while time.monotonic() < deadline:
                    states.publish(msg)
                    pose.publish(HandPose(position=np.array([0.0, 0.0, 1.5]), valid=True))
                    for _ in range(4):
                        client.pump({"foxglove/scene"})
                    if client.messages.get("foxglove/scene"):
                        cls = protobuf_class(client.channel("foxglove/scene"))
                        update = cls.FromString(client.messages["foxglove/scene"][-1])
                        if any(e.id == "slice" for e in update.entities):
                            break
    entities = {e.id: e for e in update.entities}
    assert "slice" in entities, sorted(entities)
    triangles = entities["slice"].triangles[0]
    points = np.array([[p.x, p.y, p.z] for p in triangles.points])
    # the section is the cube [-0.6, 0.6]^3: 6 square faces, 2 triangles each, corners on the cube
    assert points.shape == (36, 3) and np.allclose(np.abs(points), 0.6, atol=1e-6)
    colors = np.array([[c.r, c.g, c.b] for c in triangles.colors])
    hue = colors / colors.max(axis=1, keepdims=True)
    palette = CELL_PALETTE / CELL_PALETTE.max(axis=1, keepdims=True)
    assert np.all(np.min(np.abs(hue[:, None] - palette[None]).max(axis=-1), axis=1) < 1e-5)

"""The Foxglove node, watched as Foxglove watches it: a WebSocket client speaking the Foxglove protocol
subscribes to the advertised channels and decodes what arrives (JSON topics; the protobuf 3D scene)."""
import base64
import json
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from websockets.sync.client import connect

from touch4d.bus import Node
from touch4d.bus.testing import free_port, node_process, running_broker
from touch4d.errors import ConfigError
from touch4d.log.schema import message_schema
from touch4d.messages import HandPose, MotorCommand, MotorStatus, TactileField
from touch4d.tactile.glove import load_glove

pytestmark = pytest.mark.timeout(120)
SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the foxglove.websocket.v1 wire format)
GLOVE = load_glove()
N = len(GLOVE.samples)
NAMES = [f"m{i}" for i in range(5)]
INTENSITY = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
S = np.linspace(0.0, 1.0, N)
POSITION = np.array([0.2, -0.1, 0.3])
QUAT = Rotation.from_euler("z", 30, degrees=True).as_quat()  # x, y, z, w


class FoxgloveClient:
    """The client side of the Foxglove WebSocket protocol: advertisements, subscriptions, message frames."""

    def __init__(self, ws):
        self.ws = ws
        self.channels: dict[int, dict] = {}
        self.subscribed: dict[int, int] = {}  # subscription id -> channel id
        self.messages: dict[str, list[bytes]] = {}

    def pump(self, topics, timeout: float = 0.05) -> None:
        """Read what arrived; subscribe to `topics` as their channels are advertised."""
        try:
            frame = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "advertise":
                for channel in msg["channels"]:
                    self.channels[channel["id"]] = channel
                    if channel["topic"] in topics:
                        sub_id = len(self.subscribed) + 1
                        self.subscribed[sub_id] = channel["id"]
                        self.ws.send(json.dumps({"op": "subscribe",
                                                 "subscriptions": [{"id": sub_id, "channelId": channel["id"]}]}))
            return
        opcode, sub_id, _log_time = struct.unpack_from("<BIQ", frame)
        assert opcode == 1  # message data
        topic = self.channels[self.subscribed[sub_id]]["topic"]
        self.messages.setdefault(topic, []).append(frame[13:])

    def channel(self, topic: str) -> dict:
        return next(c for c in self.channels.values() if c["topic"] == topic)


def protobuf_class(channel: dict):
    """The message class of a protobuf channel, built from the schema it advertises."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def listening_address(port: int) -> str:
    """The local address a TCP socket listens on at `port` (from /proc/net/tcp)."""
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        addr, p = local.split(":")
        if int(p, 16) == port and state == "0A":
            return ".".join(str(b) for b in bytes.fromhex(addr)[::-1])
    return ""


def test_foxglove_client_gets_the_topics_as_json_and_the_hand_and_screen_in_3d():
    port = free_port()
    topics = {"tactile/motors", "tactile/field", "motors/status", "foxglove/scene"}
    with running_broker() as bus, node_process("foxglove", bus, params={"port": port}) as proc:
        proc.wait_for_line(rf"Foxglove: open ws://127\.0\.0\.1:{port}", timeout=60)
        assert listening_address(port) == "127.0.0.1"  # loopback by default
        with Node("probe", bus=bus, heartbeat=False) as probe:
            motors = probe.create_publisher("tactile/motors", MotorCommand)
            field = probe.create_publisher("tactile/field", TactileField)
            status = probe.create_publisher("motors/status", MotorStatus)
            pose = probe.create_publisher("hand/pose", HandPose)
            with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
                client = FoxgloveClient(ws)
                deadline = time.monotonic() + 60
                while not topics <= set(client.messages) and time.monotonic() < deadline:
                    motors.publish(MotorCommand(names=NAMES, intensity=INTENSITY))
                    field.publish(TactileField(positions=np.zeros((N, 3)), l=np.full(N, np.nan), s=S, h=S,
                                               alpha=3.0, beta=0.5, gamma=1.0))
                    status.publish(MotorStatus(boards=[dict(id=1, online=True, faults=[], last_frame=1.0,
                                                            state="operational")], duty=INTENSITY, bus_load=0.25,
                                               errors={"bus_off": 0}))
                    pose.publish(HandPose(position=POSITION, orientation=QUAT, valid=True))
                    for _ in range(4):
                        client.pump(topics)
    assert topics <= set(client.messages), f"received only {sorted(client.messages)}"

    # tactile/motors: JSON with the log export's schema, the intensities as sent.
    channel = client.channel("tactile/motors")
    assert (channel["encoding"], channel["schemaName"], channel["schemaEncoding"]) == ("json", "MotorCommand",
                                                                                       "jsonschema")
    assert json.loads(channel["schema"]) == message_schema("MotorCommand")
    msg = json.loads(client.messages["tactile/motors"][-1])
    assert msg["type"] == "MotorCommand" and msg["names"] == NAMES and msg["intensity"] == INTENSITY.tolist()
    # the tactile field plots as arrays (NaN as null), motor status as it is
    fields = json.loads(client.messages["tactile/field"][-1])
    assert fields["s"] == S.tolist() and fields["l"] == [None] * N
    board = json.loads(client.messages["motors/status"][-1])["boards"][0]
    assert board == {"id": 1, "online": True, "faults": [], "last_frame": 1.0, "state": "operational"}

    # foxglove/scene: the screen as a wire cube of edge 2, the hand's samples where the pose puts them.
    channel = client.channel("foxglove/scene")
    assert (channel["encoding"], channel["schemaName"]) == ("protobuf", "foxglove.SceneUpdate")
    update = protobuf_class(channel).FromString(client.messages["foxglove/scene"][-1])
    entities = {e.id: e for e in update.entities}
    assert entities["screen"].frame_id == entities["hand"].frame_id == "screen"
    ends = np.array([[p.x, p.y, p.z] for p in entities["screen"].lines[0].points]).reshape(-1, 2, 3)
    assert len(ends) == 12 and np.all(np.abs(ends) == 1.0)
    assert np.all(np.count_nonzero(ends[:, 0] != ends[:, 1], axis=1) == 1)  # each edge along one axis
    centres = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in entities["hand"].spheres])
    expected = Rotation.from_quat(QUAT).apply(GLOVE.samples) * (2.0 / GLOVE.screen_edge_m) + POSITION
    np.testing.assert_allclose(centres, expected, atol=1e-9)
    red = np.array([s.color.r for s in entities["hand"].spheres])
    np.testing.assert_allclose(red, 0.5 + 0.5 * S, atol=1e-6)  # coloured by what each sample feels


def test_a_port_in_use_is_a_clear_error():
    port = free_port()
    with running_broker() as bus, node_process("foxglove", bus, params={"port": port}) as proc:
        proc.wait_for_line("Foxglove: open", timeout=60)
        from touch4d.nodes.foxglove import FoxgloveNode

        with pytest.raises(ConfigError, match=rf"key 'port': expected a free port on 127.0.0.1.*got {port}"):
            FoxgloveNode(params={"port": port}, bus=bus, heartbeat=False)


def test_a_client_offering_only_the_older_subprotocol_is_refused_as_the_readme_says():
    """foxglove-sdk 0.30 speaks `foxglove.sdk.v1` only: a client offering only `foxglove.websocket.v1`
    (Lichtblick, older Foxglove) gets HTTP 400. The README says so; when the SDK accepts it, say that."""
    import foxglove
    from websockets.exceptions import InvalidStatus

    server = foxglove.start_server(name="touch4d", host="127.0.0.1", port=0, context=foxglove.Context())
    try:
        with pytest.raises(InvalidStatus, match="400"):
            with connect(f"ws://127.0.0.1:{server.port}", subprotocols=["foxglove.websocket.v1"], open_timeout=10):
                pass
        with connect(f"ws://127.0.0.1:{server.port}", subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["op"] == "serverInfo"
    finally:
        server.stop()
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "`foxglove.websocket.v1`" in readme and "Lichtblick" in readme

"""Foxglove node: the running stack, live in Foxglove, over its WebSocket protocol (foxglove-sdk).

Every bus topic (or those of `topics`) is served as JSON with the JSON schema of its message type,
the same schemas and JSON form as `touch4d log export --format foxglove` (touch4d.log.schema), so
arrays such as `tactile/motors.intensity` and `tactile/field.s` plot by index and `motors/status`
shows as it is. `foxglove/scene` adds 3D scene entities (foxglove.SceneUpdate, frame `screen`):
the screen, a cube of edge 2 around the origin, and the hand, its sample points placed by the
latest `hand/pose` (or, while they drive, by `hand/joints`: every sample on its bone, and the
joints' skeleton drawn) and coloured by the latest `tactile/field` (grey: nothing felt, red: full);
in the scene's slice and both views, each object's cross-section at w = slice_w (`slice`: triangles in
its cells' colours, the renderer's own, `touch4d.render.section_mesh`).

Serves on loopback by default: the protocol has no authentication, so another `host` shows the bus
to anyone who reaches that address. Needs `pip install 'touch4d[foxglove]'`.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np

from touch4d.bus import Node, Param
from touch4d.bus.config import is_loopback
from touch4d.errors import Touch4dError, Unavailable
from touch4d.log.schema import message_schema, to_jsonable
from touch4d.messages import HandJoints, SceneState, decoder
from touch4d.messages.codec import CodecError, unpack
from touch4d.render.view import SceneView
from touch4d.tactile.glove import load_glove
from touch4d.tactile.pose import PoseError, place
from touch4d.tactile.skeleton import ViewHand

SCENE_TOPIC = "foxglove/scene"
FRAME = "screen"
FIELD_MAX_AGE_S = 0.5  # an older tactile/field no longer colours the hand
_CUBE_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]


@dataclass
class _Served:
    channel: object
    last_sent: float = 0.0


class FoxgloveNode(Node):
    """Serves the running topics to Foxglove (WebSocket), with the hand and the screen in 3D."""

    default_name = "foxglove"
    PARAMS = {
        "host": Param("127.0.0.1", "address to serve on (not loopback: the bus is visible, unauthenticated)"),
        "port": Param(8765, "WebSocket port (0 = any free port)", min=0, max=65535, port=True),
        "topics": Param([], "the topics to serve ([] = every topic)", items=str),
        "max_rate": Param(100.0, "at most this many messages per second per topic (0 = every one)", unit="Hz",
                          min=0),
        "glove": Param("config/glove.yaml", "the glove file, for the hand's sample points", path="glove file"),
    }

    def setup(self) -> None:
        try:
            import foxglove
            from foxglove.channels import SceneUpdateChannel
        except ImportError:
            raise Unavailable("the foxglove node needs the foxglove-sdk package: pip install 'touch4d[foxglove]'") \
                from None
        p = self.params
        self.fox = foxglove
        self.min_period = 1.0 / p["max_rate"] if p["max_rate"] else 0.0
        self.glove = load_glove(p["glove"] or None)
        self.context = foxglove.Context()  # this node's channels only
        try:
            self.server = foxglove.start_server(name="touch4d", host=p["host"], port=p["port"], context=self.context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error for a port in use or a bad host
            raise self.param_error("port", f"a free port on {p['host']} ({exc})") from None
        self.add_cleanup(self.server.stop)
        self.served: dict[str, _Served] = {}
        self.scene = _Served(SceneUpdateChannel(SCENE_TOPIC, context=self.context))
        self.field: tuple[float, np.ndarray] | None = None  # (when, s per sample) of the latest tactile/field
        self.joints = ViewHand(self.glove)                  # the articulated hand while hand/joints drives
        self._joints_decoder = decoder(HandJoints)
        self.view = SceneView()                             # the slice's triangles, cut once per scene
        self._scene_decoder = decoder(SceneState)
        self._pose: dict | None = None                      # the latest hand/pose, to redraw on a new scene
        for topic in p["topics"] or [""]:
            self.create_raw_subscription(topic, self.on_message)
        if not is_loopback(p["host"]):
            self.log.warning("serving on %s: anyone who reaches this address sees every topic (the Foxglove "
                             "protocol has no authentication)", p["host"])
        self.log.info("Foxglove: open ws://%s:%d (Open connection > Foxglove WebSocket)",
                      p["host"], self.server.port)

    def on_message(self, topic: str, payload: bytes) -> None:
        if self.params["topics"] and topic not in self.params["topics"]:
            return  # a subscription is a prefix: hand/pose also brings hand/pose_replayed
        served = self.served.get(topic)
        scene = topic in ("hand/pose", "hand/joints", "tactile/field", "scene/state") and \
            self.scene.channel.has_sinks()
        if served is not None and not scene and not served.channel.has_sinks():
            return  # nobody watches: no decoding, no JSON
        try:
            data = unpack(payload)
        except CodecError as exc:
            self.warn_once((topic, "undecodable"), f"{topic}: a message that does not decode is not served: {exc}")
            return
        if not isinstance(data, dict) or not isinstance(data.get("type"), str):
            self.warn_once((topic, "untyped"), f"{topic}: a message without a type is not served")
            return
        if served is None:
            served = self.served[topic] = self._open(topic, data)
        now = time.monotonic()
        if topic == "tactile/field":
            self._on_field(data, now)
        elif topic == "hand/joints":
            self._on_joints(payload)
        elif topic == "scene/state":
            self._on_scene(payload, now)
        elif topic == "hand/pose":
            self._pose = data
            if self._due(self.scene, now):
                self._send_scene(data, now)
        if served.channel.has_sinks() and self._due(served, now):
            served.channel.log(json.dumps(to_jsonable(data)).encode())

    def _open(self, topic: str, data: dict) -> _Served:
        schema = self.fox.Schema(name=data["type"], encoding="jsonschema",
                                 data=json.dumps(message_schema(data["type"], data)).encode())
        return _Served(self.fox.Channel(topic, schema=schema, message_encoding="json", context=self.context))

    def _due(self, served: _Served, now: float) -> bool:
        if now - served.last_sent < self.min_period:
            return False
        served.last_sent = now
        return True

    def _on_field(self, data: dict, now: float) -> None:
        s = np.asarray(data.get("s", ()), dtype=float)
        if s.shape == (len(self.glove.samples),):
            self.field = (now, s)

    def _on_joints(self, payload: bytes) -> None:
        try:
            self.joints.on_joints(self._joints_decoder(payload))
        except Touch4dError as exc:        # MessageError, JointsError: the rigid hand is drawn meanwhile
            self.warn_once(("hand/joints", str(exc)), f"hand/joints not drawn: {exc}")

    def _on_scene(self, payload: bytes, now: float) -> None:
        try:
            changed = self.view.set_scene(self._scene_decoder(payload))
        except Touch4dError as exc:        # MessageError, GeometryError: the last good scene stays
            self.warn_once(("scene/state", str(exc)), f"scene/state not drawn: {exc}")
            return
        if changed and self._pose is not None:
            self._send_scene(self._pose, now)

    def _send_scene(self, data: dict, now: float) -> None:
        self.joints.on_pose(float(data.get("stamp", 0.0)))
        articulated = self.joints.current() if data.get("valid", True) else None
        outline = None
        if articulated is not None:
            points, outline = articulated.samples, articulated.outline
        else:
            try:
                points = place(self.glove.samples, self.glove.units_per_metre, data.get("position"),
                               data.get("orientation"))
            except PoseError as exc:
                self.warn_once(("hand/pose", str(exc)), f"hand/pose not drawn: {exc}")
                return
        s = self.field[1] if self.field is not None and now - self.field[0] <= FIELD_MAX_AGE_S else None
        self.scene.channel.log(self._scene_update(points, s, bool(data.get("valid", True)), outline))

    def _scene_update(self, points: np.ndarray, s: np.ndarray | None, valid: bool, outline: np.ndarray | None = None):
        """The screen (a wire cube) and the hand (a sphere per sample point) as one SceneUpdate."""
        m = self.fox.messages
        corners = [np.array([(i >> 2) & 1, (i >> 1) & 1, i & 1]) * 2.0 - 1.0 for i in range(8)]
        edges = [m.Point3(x=float(c[0]), y=float(c[1]), z=float(c[2])) for a, b in _CUBE_EDGES for c in (corners[a],
                                                                                                       corners[b])]
        screen = m.SceneEntity(frame_id=FRAME, id="screen", lines=[m.LinePrimitive(
            type=m.LinePrimitiveLineType.LineList, thickness=2.0, scale_invariant=True, points=edges,
            color=m.Color(r=0.6, g=0.6, b=0.7, a=1.0))])
        felt = np.zeros(len(points)) if s is None else np.nan_to_num(np.clip(s, 0.0, 1.0))
        alpha = 1.0 if valid else 0.3
        size = m.Vector3(x=0.03, y=0.03, z=0.03)
        spheres = [m.SpherePrimitive(pose=m.Pose(position=m.Vector3(x=float(x), y=float(y), z=float(z)),
                                                 orientation=m.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                                     size=size, color=m.Color(r=0.5 + 0.5 * f, g=0.5 - 0.5 * f, b=0.5 - 0.5 * f,
                                                              a=alpha))
                   for (x, y, z), f in zip(points.tolist(), felt.tolist())]
        bones = []
        if outline is not None:
            bones = [m.LinePrimitive(type=m.LinePrimitiveLineType.LineList, thickness=2.0, scale_invariant=True,
                                     points=[m.Point3(x=float(x), y=float(y), z=float(z))
                                             for x, y, z in np.asarray(outline).reshape(-1, 3).tolist()],
                                     color=m.Color(r=0.95, g=0.85, b=0.75, a=alpha))]
        hand = m.SceneEntity(frame_id=FRAME, id="hand", spheres=spheres, lines=bones)
        entities = [screen, hand]
        section = self.view.section
        if section is not None and len(section):
            rows = section.astype(float).tolist()
            entities.append(m.SceneEntity(frame_id=FRAME, id="slice", triangles=[m.TriangleListPrimitive(
                points=[m.Point3(x=r[0], y=r[1], z=r[2]) for r in rows],
                colors=[m.Color(r=r[3], g=r[4], b=r[5], a=r[6]) for r in rows])]))
        return m.SceneUpdate(entities=entities)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

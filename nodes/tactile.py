"""Tactile node: `hand/joints` or `hand/pose`, + `scene/state` -> `tactile/field` and `tactile/motors` (paper §5).

Every subscription is latest-only. The articulated hand (`hand/joints`: each sample and motor on
its bone) drives the glove while its joint sets are valid and fresh; when they go stale (older
than `joints_timeout_s` against the poses) or are lost, the rigid hand (`hand/pose`) takes over
without a pause in `tactile/motors`; the heartbeat's `hand_joints` (1 joints, 0 pose) and counters
say which drives. Every new pose or joint set gives one field and one motor command carrying its
stamp as `source_stamp`. The RayCaster is rebuilt only when what can be touched changes;
a scene that fails to build, or a pose that cannot be used, is logged once (per cause) and the
node keeps the last good scene. Parameters: `glove` (file, default config/glove.yaml), `alpha`
and `beta` (override the glove's), `projection` ("scene": follow the scene; "orthographic" or
"perspective"), `motors` (false: tactile/field alone, another node publishes tactile/motors).
"""
from __future__ import annotations

import time

from touch4d.bus import Node, Param
from touch4d.errors import Touch4dError
from touch4d.messages import HandJoints, HandPose, MotorCommand, PhysicsContacts, SceneState, TactileField
from touch4d.tactile.engine import PROJECTION_CHOICES, HandSource, TactileEngine
from touch4d.tactile.glove import check_alpha, check_beta, load_glove
from touch4d.tactile.pose import PoseError
from touch4d.tactile.skeleton import JOINTS_TIMEOUT_S
from touch4d.tactile.transient import TransientBank


class TactileNode(Node):
    """Computes the stimulus for every new hand pose against the latest scene."""

    default_name = "tactile"
    PARAMS = {
        "glove": Param("config/glove.yaml", "the glove file", path="glove file"),
        "alpha": Param(None, "override the glove's alpha (eq. 2)", type=float),
        "beta": Param(None, "override the glove's beta (eq. 2)", type=float),
        "projection": Param("scene", "follow the scene's projection, or force one", choices=PROJECTION_CHOICES),
        "joints": Param(True, "follow the fingers: hand/joints drives while fresh (else the rigid hand/pose)"),
        "joints_timeout_s": Param(JOINTS_TIMEOUT_S, "joint sets older than this against the poses are stale: the rigid "
                                  "hand takes over", unit="s", above=0, max=1.0),
        "motors": Param(True, "publish tactile/motors (false: another node does, e.g. the WebXR page that computes "
                            "its own touch, webxr touch: page; tactile/field still goes out)"),
        "transients": Param(True, "a short burst on the motors touching objects that physics says collided"),
    }

    def setup(self) -> None:
        p = self.params
        self.counts = {"scenes_built": 0, "bad_scenes": 0, "bad_poses": 0}
        alpha = None if p["alpha"] is None else check_alpha(p["alpha"], *self.param_where("alpha"))
        beta = None if p["beta"] is None else check_beta(p["beta"], *self.param_where("beta"))
        self.engine = TactileEngine(load_glove(p["glove"] or None), alpha=alpha, beta=beta, projection=p["projection"],
                                    joints=p["joints"])
        self.hand = HandSource(self.engine, p["joints_timeout_s"], self.counts)
        # in every heartbeat: the counters, and which hand drives (1: the joints, 0: the pose)
        self.add_stats(lambda: {**self.counts, "hand_joints": int(self.hand.using == "joints")})
        self.field_pub = self.create_publisher("tactile/field", TactileField)
        self.motor_pub = self.create_publisher("tactile/motors", MotorCommand) if p["motors"] else None
        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        if p["joints"]:
            # optional: a tracker without hand tracking publishes poses only
            self.create_subscription("hand/joints", HandJoints, self.on_joints, latest_only=True, optional=True)
        self.create_subscription("hand/pose", HandPose, self.on_pose, latest_only=True)
        self.transients = TransientBank()
        if p["transients"]:
            self.create_subscription("physics/contacts", PhysicsContacts, self.on_contacts, optional=True)
        g = self.engine.glove
        self.log.info("%d samples, %d motors (%s); alpha %g, beta %g, gamma %g; projection: %s; hand: %s",
                      len(g.samples), len(g.motor_names), g.path, g.alpha, g.beta, g.gamma, p["projection"],
                      "joints when tracked, else the pose" if p["joints"] else "the pose (rigid)")

    def on_scene(self, msg: SceneState) -> None:
        try:
            rebuilt = self.engine.set_scene(msg)
        except Touch4dError as exc:   # MessageError, GeometryError: a scene that cannot be built
            self.counts["bad_scenes"] += 1
            self.warn_once(str(exc), f"scene/state revision {msg.revision} cannot be built, keeping the "
                                     f"last good scene: {exc}")
            return
        if rebuilt:
            self.counts["scenes_built"] += 1
            # A turning scene rebuilds at every revision: say so once, not at 30 Hz.
            log = self.log.info if self.counts["scenes_built"] == 1 else self.log.debug
            log("scene revision %d: %d object(s), ray caster rebuilt", msg.revision, len(msg.objects))

    def on_pose(self, msg: HandPose) -> None:
        using = self.hand.using
        try:
            out = self.hand.on_pose(msg)
        except PoseError as exc:
            self.counts["bad_poses"] += 1
            self.warn_once(str(exc), f"hand/pose ignored: {exc}")
            return
        self._publish(out, using)

    def on_joints(self, msg: HandJoints) -> None:
        using = self.hand.using
        try:
            out, error = self.hand.on_joints(msg)
        except PoseError as exc:
            self.counts["bad_poses"] += 1
            self.warn_once(str(exc), f"hand/pose ignored: {exc}")
            return
        if error is not None:
            self.warn_once(("joints", str(error)), f"hand/joints ignored, the rigid hand/pose drives: {error}")
        self._publish(out, using)

    def _publish(self, out, was: str) -> None:
        if was != self.hand.using:
            self.log.info("hand: %s", "the joints (articulated)" if self.hand.using == "joints"
                          else "the pose (rigid): hand/joints stale, lost or unusable")
        if out is None:
            return
        field, motors = out
        if self.transients.active:
            hits = self.engine.last_stimulus.hit[self.engine.glove.motor_sample]
            motors.intensity = self.transients.apply(motors.intensity, hits, time.monotonic())
        if field is not None:
            self.field_pub.publish(field)
        if self.motor_pub is not None:
            self.motor_pub.publish(motors)

    def on_contacts(self, msg: PhysicsContacts) -> None:
        self.transients.add(msg.a, msg.b, msg.speeds, time.monotonic())

    def on_shutdown(self) -> None:
        self.log.info("handled %d pose(s), %d joint set(s): %s", self.counts["poses"], self.counts["joints"],
                      self.counts)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

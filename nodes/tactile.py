"""Tactile node: `hand/pose` + `scene/state` -> `tactile/field` and `tactile/motors` (paper §5).

Both subscriptions are latest-only. Every new pose gives one field and one motor command carrying
the pose's stamp as `source_stamp`. The RayCaster is rebuilt only when what can be touched changes;
a scene that fails to build, or a pose that cannot be used, is logged once (per cause) and the
node keeps the last good scene. Parameters: `glove` (file, default config/glove.yaml), `alpha`
and `beta` (override the glove's), `projection` ("scene": follow the scene; "orthographic" or
"perspective").
"""
from __future__ import annotations

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.messages import HandPose, MotorCommand, SceneState, TactileField
from touch4d.tactile.engine import PROJECTION_CHOICES, TactileEngine
from touch4d.tactile.glove import check_alpha, check_beta, load_glove
from touch4d.tactile.pose import PoseError


class TactileNode(Node):
    """Computes the stimulus for every new hand pose against the latest scene."""

    def __init__(self, **kwargs):
        super().__init__("tactile", **kwargs)
        self.counts = {"poses": 0, "bad_poses": 0, "scenes_built": 0, "bad_scenes": 0}
        self._logged: set[str] = set()
        try:
            self._setup()
        except BaseException:
            self.shutdown()    # close the sockets opened by Node before reporting the bad parameter
            raise

    def _setup(self) -> None:
        glove_file = self.declare_path_parameter("glove", "config/glove.yaml", "glove file")
        alpha = self.declare_parameter("alpha", None)
        beta = self.declare_parameter("beta", None)
        projection = self.declare_parameter("projection", "scene")
        source = self._params_source or f"parameters of node '{self.name}'"
        # The key as declare_parameter names it: the launch file's path to the parameter when known.
        key = (lambda name: f"nodes.{self.name}.params.{name}") if self._params_source else (lambda name: name)
        if projection not in PROJECTION_CHOICES:
            raise ConfigError(source, key("projection"), f"one of {', '.join(PROJECTION_CHOICES)}", got=projection)
        alpha = None if alpha is None else check_alpha(alpha, source, key("alpha"))
        beta = None if beta is None else check_beta(beta, source, key("beta"))
        glove = load_glove(glove_file)
        self.engine = TactileEngine(glove, alpha=alpha, beta=beta, projection=projection)
        self.field_pub = self.create_publisher("tactile/field", TactileField)
        self.motor_pub = self.create_publisher("tactile/motors", MotorCommand)
        self.create_subscription("scene/state", SceneState, self.on_scene, latest_only=True)
        self.create_subscription("hand/pose", HandPose, self.on_pose, latest_only=True)
        g = self.engine.glove
        self.log.info("%d samples, %d motors (%s); alpha %g, beta %g, gamma %g; projection: %s",
                      len(g.samples), len(g.motor_names), g.path, g.alpha, g.beta, g.gamma, projection)

    def on_scene(self, msg: SceneState) -> None:
        try:
            rebuilt = self.engine.set_scene(msg)
        except (ValueError, TypeError, KeyError) as exc:   # MessageError, GeometryError, odd params
            self.counts["bad_scenes"] += 1
            self._warn_once(str(exc), f"scene/state revision {msg.revision} cannot be built, keeping the "
                                      f"last good scene: {exc}")
            return
        if rebuilt:
            self.counts["scenes_built"] += 1
            # A turning scene rebuilds at every revision: say so once, not at 30 Hz.
            log = self.log.info if self.counts["scenes_built"] == 1 else self.log.debug
            log("scene revision %d: %d object(s), ray caster rebuilt", msg.revision, len(msg.objects))

    def on_pose(self, msg: HandPose) -> None:
        try:
            field, motors = self.engine.messages(msg)
        except PoseError as exc:
            self.counts["bad_poses"] += 1
            self._warn_once(str(exc), f"hand/pose ignored: {exc}")
            return
        self.counts["poses"] += 1
        if field is not None:
            self.field_pub.publish(field)
        self.motor_pub.publish(motors)

    def _warn_once(self, cause: str, text: str) -> None:
        if cause not in self._logged and len(self._logged) < 100:
            self._logged.add(cause)
            self.log.warning("%s (further identical problems are only counted)", text)

    def on_shutdown(self) -> None:
        self.log.info("handled %d pose(s): %s", self.counts["poses"], self.counts)


def main(argv=None):
    return run_node(TactileNode, argv)

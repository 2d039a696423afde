"""The tactile loop without a bus: keeps the scene's RayCaster, turns hand poses into messages.

The tactile node wires this to topics; tests drive it directly.
"""
from __future__ import annotations

import numpy as np

from touch4d.geometry.scene import Scene, scene_digest
from touch4d.messages import HandPose, MotorCommand, SceneState, TactileField

from .glove import Glove
from .pose import PoseError, place
from .stimulus import Stimulus, compute_stimulus, no_stimulus

PROJECTION_CHOICES = ("scene", "orthographic", "perspective")


class TactileEngine:
    """Scene in, poses in, `tactile/field` and `tactile/motors` messages out.

    `projection`: "scene" follows the scene's projection; "orthographic" / "perspective" force one
    (perspective uses the scene's eye distance).
    """

    def __init__(self, glove: Glove, alpha: float | None = None, beta: float | None = None,
                 projection: str = "scene"):
        if projection not in PROJECTION_CHOICES:
            raise ValueError(f"projection: expected one of {', '.join(PROJECTION_CHOICES)}, got {projection!r}")
        self.glove = glove.with_constants(alpha=alpha, beta=beta)
        self.projection = projection
        self.caster = None
        self.scene_key: tuple | None = None   # (scene_digest, projection) of the adopted scene
        self.builds = 0

    def set_scene(self, msg: SceneState) -> bool:
        """Adopt a scene; rebuild the RayCaster only if what can be touched changed. True if rebuilt.

        Raises (MessageError, GeometryError: Touch4dErrors) for a scene that cannot be built; the
        previous scene is then kept.
        """
        key = (scene_digest(msg, touch_only=True), self.projection)
        if key == self.scene_key:
            return False
        scene = Scene.from_message(msg)
        if self.projection != "scene":
            scene.projection = self.projection
        caster = scene.ray_caster()
        self.caster, self.scene_key = caster, key
        self.builds += 1
        return True

    def stimulus(self, pose: HandPose) -> Stimulus:
        """The stimulus for a pose: zero when tracking is lost or there is no scene yet.

        Raises PoseError for a pose marked valid whose position or orientation cannot be used.
        """
        if not pose.valid:
            try:
                positions = place(self.glove.samples, self.glove.units_per_metre, pose.position, pose.orientation)
            except PoseError:
                positions = None
            return no_stimulus(self.glove, positions)
        if self.caster is None:
            return no_stimulus(self.glove, place(self.glove.samples, self.glove.units_per_metre,
                                                 pose.position, pose.orientation))
        return compute_stimulus(self.glove, self.caster, pose.position, pose.orientation)

    def messages(self, pose: HandPose) -> tuple[TactileField | None, MotorCommand]:
        """The field (None when the pose cannot place the samples) and the motor command for a pose."""
        st = self.stimulus(pose)
        self.last_stimulus = st                  # the hits, for contact transients (tactile.transient)
        source = pose.source_stamp or pose.stamp
        field = None
        if np.isfinite(st.positions).all():
            field = TactileField(positions=st.positions, l=st.l, s=st.s, h=st.h, alpha=st.alpha,
                                 beta=st.beta, gamma=st.gamma, source_stamp=source)
        motors = MotorCommand(names=list(self.glove.motor_names), intensity=st.V, source_stamp=source)
        return field, motors

"""The tactile loop without a bus: keeps the scene's RayCaster, turns hand poses and joint sets into messages.

The hand comes from `hand/joints` (the articulated hand: every sample on its bone) while those are
fresh and valid, else from `hand/pose` (the rigid hand). `HandSource` decides which, from the
messages' own stamps, so the choice does not depend on when a busy node gets to them. The tactile
node wires this to topics; tests drive it directly.
"""
from __future__ import annotations

import numpy as np

from touch4d.geometry.scene import Scene, scene_digest
from touch4d.messages import HandJoints, HandPose, MotorCommand, SceneState, TactileField

from .glove import Glove
from .pose import PoseError, place
from .skeleton import JOINTS_TIMEOUT_S, JointsError
from .stimulus import Stimulus, compute_joint_stimulus, compute_stimulus, no_stimulus

PROJECTION_CHOICES = ("scene", "orthographic", "perspective")


class TactileEngine:
    """Scene in, poses in, `tactile/field` and `tactile/motors` messages out.

    `projection`: "scene" follows the scene's projection; "orthographic" / "perspective" force one
    (perspective uses the scene's eye distance). `joints`: False for a hand without fingers (a held
    controller): the articulated hand's compiled kernels are then not loaded up front.
    """

    def __init__(self, glove: Glove, alpha: float | None = None, beta: float | None = None,
                 projection: str = "scene", joints: bool = True):
        if projection not in PROJECTION_CHOICES:
            raise ValueError(f"projection: expected one of {', '.join(PROJECTION_CHOICES)}, got {projection!r}")
        self.glove = glove.with_constants(alpha=alpha, beta=beta)
        if joints:   # the articulated hand ready before the loop, not at its first joints (numba: ~60 MB)
            self.glove.skeleton.warm_up()
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

    def joint_stimulus(self, joints: HandJoints) -> Stimulus:
        """The stimulus for a valid joint set (zero while there is no scene); raises JointsError for
        joints that cannot place the hand."""
        g = self.glove
        if self.caster is None:
            m = g.skeleton.transforms(joints.names, joints.positions, joints.orientations, joints.handedness,
                                      g.units_per_metre)
            return no_stimulus(g, g.skeleton.place("samples", m))
        return compute_joint_stimulus(g, self.caster, joints.names, joints.positions, joints.orientations,
                                      joints.handedness)

    def messages(self, pose: HandPose | HandJoints) -> tuple[TactileField | None, MotorCommand]:
        """The field (None when the hand cannot place the samples) and the motor command for a pose
        or a valid joint set."""
        st = self.joint_stimulus(pose) if isinstance(pose, HandJoints) else self.stimulus(pose)
        self.last_stimulus = st                  # the hits, for contact transients (tactile.transient)
        return self._messages(st, pose.source_stamp or pose.stamp)

    def _messages(self, st: Stimulus, source: float) -> tuple[TactileField | None, MotorCommand]:
        field = None
        if np.isfinite(st.positions).all():
            field = TactileField(positions=st.positions, l=st.l, s=st.s, h=st.h, alpha=st.alpha,
                                 beta=st.beta, gamma=st.gamma, source_stamp=source)
        motors = MotorCommand(names=list(self.glove.motor_names), intensity=st.V, source_stamp=source)
        return field, motors


class HandSource:
    """Which hand drives the glove: the joints ("joints") while the latest joint set is valid and no
    older than `timeout_s` against the poses' stamps, else the rigid pose ("pose").

    A tracker publishes a joint set before the pose of the same instant; the pose is then
    superseded (computed once per instant, from the joints). When joints go stale, the first pose
    more than `timeout_s` newer than them takes over; when they are lost (`valid` false) or
    unusable, the latest pose takes over at once: `tactile/motors` never pauses longer than the
    timeout plus one pose period.
    """

    def __init__(self, engine: TactileEngine, timeout_s: float = JOINTS_TIMEOUT_S, counts: dict | None = None):
        self.engine = engine
        self.timeout_s = float(timeout_s)
        self.using = "pose"
        self.joints_stamp = -np.inf          # stamp of the latest valid joint set (-inf: none or lost)
        self.last_pose: HandPose | None = None
        self.counts = counts if counts is not None else {}     # shared with the node's own counters
        self.counts.update(poses=0, poses_superseded=0, joints=0, joints_lost=0, bad_joints=0, switches=0)

    def on_pose(self, pose: HandPose):
        """(field, motors) for a pose, or None when fresh joints drive. Raises PoseError."""
        self.last_pose = pose
        if pose.stamp <= self.joints_stamp + self.timeout_s:
            self.counts["poses_superseded"] += 1
            return None
        out = self.engine.messages(pose)
        self.counts["poses"] += 1
        self._use("pose")
        return out

    def on_joints(self, joints: HandJoints):
        """((field, motors) or None, error or None) for a joint set: its own messages; for lost
        joints, or unusable ones (the JointsError is returned), the latest pose's (None without one).
        Raises PoseError only when the pose fallen back to cannot be used."""
        if not joints.valid:
            self.counts["joints_lost"] += 1
            return self._fall_back(), None
        try:
            out = self.engine.messages(joints)
        except JointsError as exc:
            self.counts["bad_joints"] += 1
            return self._fall_back(), exc
        self.counts["joints"] += 1
        self.joints_stamp = joints.stamp
        self._use("joints")
        return out, None

    def _fall_back(self):
        last_joints, self.joints_stamp = self.joints_stamp, -np.inf
        if self.using == "pose" or self.last_pose is None:
            return None
        if self.last_pose.stamp < last_joints - self.timeout_s:
            self._use("pose")           # no pose of late: the next one drives (nothing stale meanwhile)
            return None
        self._use("pose")
        return self.engine.messages(self.last_pose)

    def _use(self, source: str) -> None:
        if source != self.using:
            self.using = source
            self.counts["switches"] += 1


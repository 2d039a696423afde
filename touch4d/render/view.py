"""The renderer's picture of the world (last good scene, hand, tactile field, motors), turned into
GL-free frames that any backend draws."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from touch4d.geometry import quaternion
from touch4d.geometry.scene import Scene, scene_digest
from touch4d.glovefile import DEFAULT_TOUCH_THRESHOLD
from touch4d.messages import HandJoints, HandPose, MessageError, MotorCommand, SceneState, TactileField
from touch4d.tactile.glove import Glove
from touch4d.tactile.pose import check_pose, place
from touch4d.tactile.skeleton import ViewHand

from .frame import Frame, SceneLayer, Style
from .hud import TactileCube, hand_geometry, hand_skeleton, screen_frame, text_image, touched_motors
from .scene_geometry import SceneGeometry, object_transforms
from .section_mesh import section_mesh

BACKGROUND = (0.04, 0.04, 0.06, 1.0)


@dataclass
class Show:
    """Which extras are drawn besides the scene."""

    frame: bool = True
    hand: bool = True
    tactile: bool = True
    status: bool = True


def both_style(style: Style) -> Style:
    """The projection of the both view: fainter fills and edges, no centre copies, so the slice's solid
    shows inside it."""
    return replace(style, centres=False, fill_alpha=min(style.fill_alpha, 0.08), edge_alpha=min(style.edge_alpha, 0.4))


@dataclass
class _Hand:
    position: np.ndarray
    rotation: np.ndarray
    samples: np.ndarray | None
    skeleton: np.ndarray | None


class SceneView:
    """Holds the last good state of every input and turns it into a `Frame`. The scene's geometry is
    built once per revision of its shapes and colours; a scene that only moved gets new transforms.

    The view (projection, slice, both) and where the slice cuts are the scene's unless `view` or
    `slice_w` override them (a renderer parameter); the slice's solid is cut once per adopted scene.

    Setters raise (MessageError, GeometryError, PoseError) on input they cannot use and then keep the previous state,
    so a caller that catches keeps drawing the last good picture.
    """

    def __init__(self, glove: Glove | None = None, style: Style = Style(), show: Show | None = None,
                 cube: TactileCube = TactileCube(), view: str | None = None, slice_w: float | None = None):
        self.glove = glove
        self.style = style
        self.view_override, self.slice_w_override = view, slice_w
        self.view, self.slice_w = "projection", 0.0
        self.section: np.ndarray | None = None         # the slice's triangles, in slice and both views
        self.extent: tuple[float, float] | None = None  # the w the objects span
        self.show = show or Show()
        self.cube = cube
        self.scene: Scene | None = None
        self.layer: SceneLayer | None = None
        self.geometry_builds = 0
        self.hand: _Hand | None = None
        self.field: TactileField | None = None
        self.motors: MotorCommand | None = None
        self._scene_key: bytes | None = None
        self.joints = ViewHand(glove) if glove is not None else None   # the articulated hand, while it drives

    # ---- inputs -------------------------------------------------------------------------------------
    def set_scene(self, scene: Scene | SceneState) -> bool:
        """Adopt a scene: its geometry (only if its shapes or colours changed) and its transforms; True if
        adopted. A message equal to the last adopted one (the scene node repeats it for late joiners) is
        not adopted again."""
        key = None
        if isinstance(scene, SceneState):
            key = scene_digest(scene)
            if key == self._scene_key:
                return False
            scene = Scene.from_message(scene)
        geometry = self.layer.geometry if self.layer is not None else None
        if geometry is None or not geometry.fits(scene):
            geometry = SceneGeometry.build(scene)        # fails before adopting
            self.geometry_builds += 1
        view = self.view_override or scene.view
        layer = SceneLayer(geometry, object_transforms(scene), scene.projection, float(scene.eye_distance),
                           self.style if view != "both" else both_style(self.style))
        slice_w = float(scene.slice_w if self.slice_w_override is None else self.slice_w_override)
        self.section, self.extent = section_mesh(layer, slice_w) if view != "projection" else (None, None)
        self.layer, self.view, self.slice_w = layer, view, slice_w
        self.scene, self._scene_key = scene, key
        return True

    @property
    def touches_section(self) -> bool:
        """Whether the glove touches the cross-section at slice_w, as drawn here: a slice view (this
        view's own, when overridden) of a scene whose slice view touches its section."""
        return self.scene is not None and self.view == "slice" and self.scene.slice_touch == "section"

    def set_hand(self, pose: HandPose) -> None:
        if not pose.valid:
            self.hand = None
            return
        position, q = check_pose(pose.position, pose.orientation)
        samples = skeleton = None
        if self.glove is not None:
            upm = self.glove.units_per_metre
            samples = place(self.glove.samples, upm, position, q)
            skeleton = place(hand_skeleton(self.glove.hand).reshape(-1, 3), upm, position, q)
        self.hand = _Hand(position, quaternion.to_matrix(q), samples, skeleton)
        if self.joints is not None:
            self.joints.on_pose(pose.stamp)

    def set_joints(self, msg: HandJoints) -> None:
        """Adopt a joint set: while it is fresh against the poses, the hand is drawn with its fingers
        where the joints put them. Raises JointsError (a ValueError) for joints it cannot place."""
        if self.joints is not None:
            self.joints.on_joints(msg)

    def set_field(self, msg: TactileField) -> None:
        if len(msg.positions) == 0:
            raise MessageError("TactileField.positions: expected at least one sample to draw")
        self.field = msg

    def set_motors(self, msg: MotorCommand) -> None:
        self.motors = msg

    # ---- output -------------------------------------------------------------------------------------
    def frame(self, status: list[str] | None = None) -> Frame:
        """The frame to draw now: the scene layer (the same object until the scene changes) and the
        flat layers around it."""
        out = Frame(scene=None if self.view == "slice" else self.layer)
        if self.section is not None and len(self.section):
            out.solids.append(self.section)
        if self.show.frame:
            out.lines.append(screen_frame())
        articulated = self.joints.current() if self.joints is not None else None
        if self.show.hand and articulated is not None:
            h = self.field.h if self.field is not None else None
            wrist = articulated.joints[0]
            lines, pts = hand_geometry(articulated.samples, wrist, self._wrist_rotation(), h, articulated.outline)
            out.lines.append(lines)
            out.points.append(pts)
        elif self.show.hand and self.hand is not None:
            h = self.field.h if self.field is not None else None
            samples = self.hand.samples if self.hand.samples is not None else np.zeros((0, 3))
            lines, pts = hand_geometry(samples, self.hand.position, self.hand.rotation, h, self.hand.skeleton)
            out.lines.append(lines)
            out.points.append(pts)
        if self.show.tactile:
            self._tactile(out)
        if self.show.status:
            out.overlay = text_image(self.status_lines(status))
        return out

    def _wrist_rotation(self) -> np.ndarray:
        """The axes drawn at the wrist of the articulated hand: the hand frame (the wrist joint's
        turned -90 degrees about x), or the pose's when the joints carry no orientation."""
        q = self.joints.wrist_orientation
        if q is None:
            return self.hand.rotation if self.hand is not None else np.eye(3)
        return quaternion.to_matrix(q) @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

    def _tactile(self, out: Frame) -> None:
        f = self.field
        glove = self.glove
        motor_sample = None
        if f is not None:
            if glove is not None and len(glove.samples) == len(f.h):
                local, motor_sample = glove.samples, glove.motor_sample
            else:
                local = f.positions
            lines, pts = self.cube.geometry(local, f.h, f.l, motor_sample)
        elif glove is not None:
            lines, pts = self.cube.geometry(glove.samples, np.zeros(len(glove.samples)), None, glove.motor_sample)
        else:
            return
        out.lines.append(lines)
        out.points.append(pts)

    def status_lines(self, extra: list[str] | None = None) -> list[str]:
        lines = list(extra or [])
        if self.scene is not None:
            names = ", ".join(o.name for o in self.scene.objects[:4]) + (" ..." if len(self.scene.objects) > 4 else "")
            lines.append(f"scene: {names or 'empty'} ({self.scene.projection})")
            if self.view != "projection":
                span = "nothing to cut" if self.extent is None else \
                    f"objects span w {self.extent[0]:.2f} .. {self.extent[1]:.2f}"
                lines.append(f"{self.view} view: slice at w = {self.slice_w:.2f} ({span})")
        if self.motors is not None:
            threshold = self.glove.touch_threshold if self.glove is not None else DEFAULT_TOUCH_THRESHOLD
            touched = touched_motors(self.motors.names, self.motors.intensity, threshold)
            shown = ", ".join(touched[:6]) + (f" +{len(touched) - 6}" if len(touched) > 6 else "")
            lines.append(f"touched motors: {len(touched)} {shown}".rstrip())
        return lines or ["waiting for scene/state"]

"""The renderer's picture of the world (last good scene, hand, tactile field, motors) and offscreen rendering."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from touch4d.geometry.scene import Scene
from touch4d.messages import HandPose, MotorCommand, SceneState, TactileField
from touch4d.tactile.glove import Glove
from touch4d.tactile.pose import check_pose, place, quaternion_matrix

from .camera import OrbitCamera
from .context import OffscreenTarget, create_headless_context
from .draw import Layers, Painter
from .hud import TactileCube, hand_geometry, hand_skeleton, screen_frame, text_image, touched_motors
from .scene_mesh import Body, MeshBuilder, SceneMesh, Style


BACKGROUND = (0.04, 0.04, 0.06, 1.0)


def bodies_from_scene(scene: Scene) -> list[Body]:
    """Every convex part of every object, with its placement and colour."""
    return [Body(part, obj.orientation, obj.position, obj.size, np.asarray(obj.color, dtype=float), index)
            for index, obj in enumerate(scene.objects) for part in obj.local_parts()]


def scene_digest(msg: SceneState) -> bytes:
    """A digest of everything in a scene message that is drawn (all but `selected` and `revision`)."""
    digest = hashlib.blake2b(digest_size=16)
    digest.update(f"{msg.projection}|{float(msg.eye_distance)!r}".encode())

    def add(value) -> None:
        if isinstance(value, dict):
            for k in sorted(value, key=str):
                digest.update(f"<{k}>".encode())
                add(value[k])
        elif isinstance(value, (list, tuple)):
            digest.update(f"[{len(value)}".encode())
            for item in value:
                add(item)
        elif isinstance(value, np.ndarray):
            digest.update(f"{value.dtype}{value.shape}".encode() + np.ascontiguousarray(value).tobytes())
        else:
            digest.update(repr(value).encode())

    add(msg.objects)
    return digest.digest()


@dataclass
class Show:
    """Which extras are drawn besides the scene."""

    frame: bool = True
    hand: bool = True
    tactile: bool = True
    status: bool = True


@dataclass
class _Hand:
    position: np.ndarray
    rotation: np.ndarray
    samples: np.ndarray | None
    skeleton: np.ndarray | None


class SceneView:
    """Holds the last good state of every input and turns it into the `Layers` of a frame.

    Setters raise (ValueError subclasses) on input they cannot use and then keep the previous state,
    so a caller that catches keeps drawing the last good picture.
    """

    def __init__(self, glove: Glove | None = None, style: Style = Style(), show: Show | None = None,
                 cube: TactileCube = TactileCube()):
        self.glove = glove
        self.style = style
        self.show = show or Show()
        self.cube = cube
        self.builder = MeshBuilder()
        self.scene: Scene | None = None
        self.bodies: list[Body] = []
        self.hand: _Hand | None = None
        self.field: TactileField | None = None
        self.motors: MotorCommand | None = None
        self._mesh: SceneMesh | None = None
        self._scene_key: bytes | None = None

    # ---- inputs -------------------------------------------------------------------------------------
    def set_scene(self, scene: Scene | SceneState) -> bool:
        """Adopt a scene and build its vertex arrays; True if it was built. A message equal to the
        last adopted one (the scene node repeats it for late joiners) is not built again."""
        key = None
        if isinstance(scene, SceneState):
            key = scene_digest(scene)
            if key == self._scene_key:
                return False
            scene = Scene.from_message(scene)
        bodies = bodies_from_scene(scene)
        mesh = self.builder.build(bodies, scene.projection, scene.eye_distance, self.style)  # fails before adopting
        self.scene, self.bodies, self._mesh, self._scene_key = scene, bodies, mesh, key
        return True

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
        self.hand = _Hand(position, quaternion_matrix(q), samples, skeleton)

    def set_field(self, msg: TactileField) -> None:
        if len(msg.positions) == 0:
            raise ValueError("tactile/field: expected at least one sample")
        self.field = msg

    def set_motors(self, msg: MotorCommand) -> None:
        self.motors = msg

    # ---- output -------------------------------------------------------------------------------------
    def mesh(self) -> SceneMesh | None:
        """The scene's vertex arrays, rebuilt only after the scene changed."""
        if self._mesh is None and self.scene is not None:
            self._mesh = self.builder.build(self.bodies, self.scene.projection, self.scene.eye_distance, self.style)
        return self._mesh

    def layers(self, status: list[str] | None = None) -> Layers:
        out = Layers()
        mesh = self.mesh()
        if mesh is not None:
            out.triangles += [mesh.fills, mesh.centres]
            out.lines.append(mesh.edges)
        if self.show.frame:
            out.lines.append(screen_frame())
        if self.show.hand and self.hand is not None:
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

    def _tactile(self, out: Layers) -> None:
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
        if self.motors is not None:
            touched = touched_motors(self.motors.names, self.motors.intensity)
            shown = ", ".join(touched[:6]) + (f" +{len(touched) - 6}" if len(touched) > 6 else "")
            lines.append(f"touched motors: {len(touched)} {shown}".rstrip())
        return lines or ["waiting for scene/state"]


@dataclass
class OffscreenRenderer:
    """Renders a `SceneView` through a camera into an image, on a headless EGL context."""

    size: tuple[int, int]
    samples: int = 0
    background: tuple = BACKGROUND
    line_width: float = 2.0
    ctx: object = None
    _target: OffscreenTarget = field(init=False, repr=False)
    _painter: Painter = field(init=False, repr=False)

    def __post_init__(self):
        self._own_ctx = self.ctx is None
        if self._own_ctx:
            self.ctx = create_headless_context()
        self._target = OffscreenTarget(self.ctx, self.size, self.samples)
        self._painter = Painter(self.ctx, self.line_width)

    def render(self, view: SceneView, camera: OrbitCamera, status: list[str] | None = None) -> np.ndarray:
        """The frame as (height, width, 4) uint8, row 0 at the top."""
        return self.render_layers(view.layers(status), camera)

    def render_layers(self, layers: Layers, camera: OrbitCamera) -> np.ndarray:
        self.draw_layers(layers, camera)
        return self.read()

    def draw_layers(self, layers: Layers, camera: OrbitCamera) -> None:
        """Draw without reading back (reading waits for the GPU)."""
        self._target.use()
        self._painter.paint(layers, camera.matrix(self.size), self.size, self.background)

    def read(self) -> np.ndarray:
        """The last drawn frame as (height, width, 4) uint8, row 0 at the top."""
        return self._target.read_rgba()

    @property
    def painter(self) -> Painter:
        return self._painter

    def release(self) -> None:
        """Free the GL objects, and the context if this renderer made it (each EGL context holds
        llvmpipe's threads until released)."""
        self._painter.release()
        self._target.release()
        if self._own_ctx:
            self.ctx.release()

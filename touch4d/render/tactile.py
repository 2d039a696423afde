"""The tactile model's rays on the GPU (paper eq. 4-7): the glove's samples placed by a hand pose and
cast along +w by the renderer's own ray test (shaders/tactile.frag: halfspace.glsl's ray_span), so
that what the hand feels and what the picture shows come from one kernel; in a slice view that
touches its cross-section, the samples' points of the cut tested against the same cells. The WebXR page runs the
same pass (touch4d/web/static/touch.js); this desktop one, on moderngl, is what tests hold against
the CPU tactile engine (touch4d.tactile.compute_stimulus).

    gpu = GpuTactile()
    gpu.set_scene(scene_state)
    st = gpu.stimulus(glove, position, quaternion_xyzw)      # a touch4d.tactile.Stimulus
"""
from __future__ import annotations

import moderngl
import numpy as np

from touch4d.geometry import quaternion
from touch4d.geometry.scene import Scene
from touch4d.messages import SceneState
from touch4d.tactile.glove import Glove
from touch4d.tactile.pose import check_pose, place
from touch4d.tactile.stimulus import Stimulus, stimulus_of_distances

from .backends.gpu import UNITS, GpuBackend
from .context import RenderError, create_headless_context
from .draw import program, set_uniforms
from .frame import Frame
from .scene_geometry import data_texture
from .view import SceneView

SAMPLES_UNIT = 16     # t_samples: after the renderer's 16 units (WebGL2 has at least 32 in all)


class GpuTactile:
    """Per-sample touch distances of one scene on the GPU. `ctx`: a moderngl context (default: a
    headless one of its own, released with `release`)."""

    def __init__(self, ctx: moderngl.Context | None = None):
        self._own_ctx = ctx is None
        self.ctx = create_headless_context() if ctx is None else ctx
        self.backend = GpuBackend(self.ctx)
        if self.ctx.fbo is None:   # a bare headless context: the passes return to a framebuffer of ours
            self._home = self.ctx.simple_framebuffer((1, 1))
            self._home.use()
        self.prog = program(self.ctx, "fullscreen.vert", "tactile.frag")
        set_uniforms(self.prog, **UNITS, t_samples=SAMPLES_UNIT)
        self._vao = self.ctx.vertex_array(self.prog, [])
        self._samples: tuple | None = None        # (the hand-frame points given, their texture, target, fbo)
        self.view = SceneView()

    def set_scene(self, scene: Scene | SceneState) -> None:
        """Adopt a scene (its geometry uploaded once per change of its shapes, its transforms each
        time). A slice view that touches its cross-section is touched there (as SectionCaster)."""
        self.view.set_scene(scene)
        self.backend.prepare(Frame(scene=self.view.layer))

    def depths(self, points: np.ndarray, rotation: np.ndarray, position) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hand-frame points (N, 3, screen units) placed by `rotation` (3, 3) and `position` (3,): per
        point (l, NaN where nothing is touched; the object hit, -1; inside the screen cube)."""
        if self.view.layer is None:
            raise RenderError("no scene: set_scene first")
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        texture, target, fbo = self._targets(points)
        backend = self.backend
        backend._per_frame_passes()
        previous, viewport = self.ctx.fbo, self.ctx.viewport
        self.ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        backend._bind()
        texture.use(SAMPLES_UNIT)
        g = backend.geometry
        set_uniforms(self.prog, u_hand=tuple(np.asarray(rotation, np.float64).T.ravel()),
                     u_hand_at=tuple(float(v) for v in position), u_samples=len(points), u_bodies=g.n_bodies,
                     u_eye=float(self.view.layer.perspective_eye or 0.0),
                     u_section=self.view.touches_section, u_cut=float(self.view.slice_w))
        fbo.use()
        self.ctx.viewport = (0, 0, *fbo.size)
        self._vao.render(moderngl.TRIANGLES, vertices=3)
        out = np.frombuffer(fbo.read(components=4, dtype="f4", alignment=1), np.float32).reshape(-1, 4)[:len(points)]
        previous.use()
        self.ctx.viewport = viewport
        touched = out[:, 0] >= 0
        return (np.where(touched, out[:, 0].astype(np.float64), np.nan),
                np.where(touched, np.rint(out[:, 1]).astype(np.int64), -1), out[:, 2] > 0.5)

    def stimulus(self, glove: Glove, position, orientation) -> Stimulus:
        """The stimulus of eq. 1-7 for a hand pose, its rays cast here (as compute_stimulus on the CPU)."""
        p, q = check_pose(position, orientation)
        l, hit, inside = self.depths(glove.samples * glove.units_per_metre, quaternion.to_matrix(q), p)
        return stimulus_of_distances(glove, place(glove.samples, glove.units_per_metre, p, q), inside, l, hit)

    def _targets(self, points: np.ndarray):
        """The samples' texture and the pass's target, made again only for other points."""
        if self._samples is not None and np.array_equal(self._samples[0], points):
            return self._samples[1:]
        self._release_samples()
        records = np.zeros((len(points), 4), np.float32)
        records[:, :3] = points
        data = data_texture(records)
        size = (data.shape[1], data.shape[0])
        texture = self.ctx.texture(size, 4, data.tobytes(), dtype="f4")
        target = self.ctx.texture(size, 4, dtype="f4")
        for t in (texture, target):
            t.filter = moderngl.NEAREST, moderngl.NEAREST
        self._samples = (points.copy(), texture, target, self.ctx.framebuffer(color_attachments=[target]))
        return self._samples[1:]

    def _release_samples(self) -> None:
        if self._samples is not None:
            for obj in self._samples[1:]:
                obj.release()
            self._samples = None

    def release(self) -> None:
        self._release_samples()
        self._vao.release()
        self.prog.release()
        self.backend.release()
        if getattr(self, "_home", None) is not None:
            self._home.release()
        if self._own_ctx:
            self.ctx.release()

"""Offscreen rendering of a `SceneView` through a backend, on a headless EGL context: pictures, and
identity images (which object is seen at which 3D screen point) for checking what is drawn."""
from __future__ import annotations

import moderngl
import numpy as np

from .backends import DEFAULT_BACKEND, Backend, open_backend
from .camera import OrbitCamera
from .context import OffscreenTarget, create_headless_context
from .frame import Frame
from .view import BACKGROUND, SceneView


class OffscreenRenderer:
    """Renders frames of `size` (width, height) pixels with the backend `backend` ("gpu", "clip", "auto")."""

    def __init__(self, size: tuple[int, int], samples: int = 0, background: tuple = BACKGROUND,
                 line_width: float = 2.0, ctx: moderngl.Context | None = None, backend: str = DEFAULT_BACKEND,
                 log=None):
        self.size = (int(size[0]), int(size[1]))
        self.samples = samples
        self.background = background
        self._own_ctx = ctx is None
        self.ctx = create_headless_context() if ctx is None else ctx
        self._target = OffscreenTarget(self.ctx, self.size, samples)
        self.backend: Backend = open_backend(backend, self.ctx, line_width, log)
        self._ids = None

    def render(self, view: SceneView, camera: OrbitCamera, status: list[str] | None = None) -> np.ndarray:
        """The frame as (height, width, 4) uint8, row 0 at the top."""
        return self.render_frame(view.frame(status), camera)

    def render_frame(self, frame: Frame, camera: OrbitCamera) -> np.ndarray:
        self.draw_frame(frame, camera)
        return self.read()

    def draw_frame(self, frame: Frame, camera: OrbitCamera) -> None:
        """Draw without reading back (reading waits for the GPU)."""
        self._target.use()
        self.backend.paint(frame, camera.matrix(self.size), self.size, self.background)

    def read(self) -> np.ndarray:
        """The last drawn frame as (height, width, 4) uint8, row 0 at the top."""
        return self._target.read_rgba()

    def identities(self, frame: Frame, camera: OrbitCamera, what: str = "faces",
                   section=None) -> tuple[np.ndarray, np.ndarray]:
        """What is seen where: (height, width, 4) float32, row 0 at the top, per pixel the 3D screen
        point of the nearest visible 2-face ("faces") or edge ("edges") and its object index + 1 (0
        where nothing is); and (height, width) the 4D depth w of that point, NaN where nothing is or
        the backend does not know it (clip). `section` (a, b, c, d) keeps only the screen points u
        with (a, b, c).u <= d, so that faces inside the picture come to the front."""
        ids, w = self._identity_targets(frame, camera, what, False, section)
        return ids, np.where(w[..., 3] > 0, w[..., 0], np.nan)

    def layer_counts(self, frame: Frame, camera: OrbitCamera, what: str = "faces") -> np.ndarray:
        """(height, width, 4) float32, row 0 at the top: per pixel how many visible layers of 2-faces
        ("faces") or edges ("edges") of object k it shows, in channel k mod 4."""
        return self._identity_targets(frame, camera, what, True)[0]

    def _identity_targets(self, frame: Frame, camera: OrbitCamera, what: str, layers: bool, section=None):
        if self._ids is None:
            targets = [self.ctx.texture(self.size, 4, dtype="f4") for _ in range(2)]
            depth = self.ctx.depth_renderbuffer(self.size)
            self._ids = (self.ctx.framebuffer(targets, depth), *targets, depth)
        fbo = self._ids[0]
        fbo.use()
        self.ctx.viewport = (0, 0, *self.size)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.backend.draw_identities(frame, camera.matrix(self.size), self.size, what, layers, section)
        return [np.frombuffer(fbo.read(components=4, attachment=k, dtype="f4", alignment=1), np.float32)
                .reshape(self.size[1], self.size[0], 4)[::-1].copy() for k in (0, 1)]

    def release(self) -> None:
        """Free the GL objects, and the context if this renderer made it (each EGL context holds
        llvmpipe's threads until released)."""
        self.backend.release()
        self._target.release()
        if self._ids is not None:
            for obj in self._ids:
                obj.release()
        if self._own_ctx:
            self.ctx.release()

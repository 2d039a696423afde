"""Backends draw the GL-free `Frame` with moderngl: one abstract `Backend`, one module per backend, a
registry by name (as python-can does for bus interfaces).

- `gpu`: geometry uploaded once per scene revision, 4D projection in the vertex shaders, hidden
  hypersurfaces removed per fragment by the tactile ray test (`shaders/halfspace.glsl`).
- `clip`: the paper's reference (§4.3): back-cell culling and clip units on the CPU, vertex arrays
  uploaded every time the scene moves; also the fallback for GL contexts without float targets.
- `auto` (the default): `gpu` on a GPU, `clip` on a software rasteriser (Mesa's llvmpipe, SwiftShader),
  where per-fragment ray tests cost 10-50x the clip-unit build (bench/bench_render.py).
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import moderngl
import numpy as np

from touch4d.render.context import RenderError
from touch4d.targets import load_target
from touch4d.render.draw import Painter
from touch4d.render.frame import Frame

BACKENDS = {
    "gpu": "touch4d.render.backends.gpu:GpuBackend",       # imported when picked (touch4d.targets)
    "clip": "touch4d.render.backends.clip:ClipBackend",
}
DEFAULT_BACKEND = "auto"
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "swiftshader")


class BackendUnavailable(RenderError):
    """The GL context lacks what a backend needs (the caller may fall back to another one)."""


class Backend(ABC):
    """Draws frames into whatever framebuffer is bound: `prepare` does all the CPU work and uploads of
    a frame, `draw` issues the draw calls. The flat layers around the scene go through `painter`."""

    name = ""

    def __init__(self, ctx: moderngl.Context, line_width: float = 2.0):
        self.ctx = ctx
        self.painter = Painter(ctx, line_width)

    @abstractmethod
    def prepare(self, frame: Frame) -> None:
        """Everything before the draw calls: scene work on the CPU, buffer and texture writes."""

    @abstractmethod
    def draw_scene(self, mvp: np.ndarray, viewport: tuple[int, int]) -> None:
        """Draw the prepared scene, blended over what the framebuffer holds."""

    @abstractmethod
    def draw_identities(self, frame: Frame, mvp: np.ndarray, viewport: tuple[int, int], what: str = "faces",
                        layers: bool = False, section=None) -> None:
        """Draw the scene's visible "faces" (2-faces) or "edges" into the bound float framebuffer: depth
        tested, per pixel the 3D screen point and the object index + 1 (0 is the background); or, with
        `layers`, blended additively without a depth test, per pixel how many layers of object k are
        seen, in channel k mod 4. `section` (a, b, c, d): only screen points with (a, b, c).u <= d,
        to look inside the picture."""

    def draw(self, mvp: np.ndarray, viewport: tuple[int, int], background=(0.0, 0.0, 0.0, 1.0)) -> None:
        """Clear, then draw the prepared frame seen through `mvp` (3D screen -> clip, row-major): the
        opaque solids (a slice), the scene's projection over them, the flat layers."""
        self.ctx.clear(*background)
        self.painter.draw_solids(mvp)
        self.draw_scene(mvp, viewport)
        self.painter.draw(mvp, viewport)

    def paint(self, frame: Frame, mvp: np.ndarray, viewport: tuple[int, int], background=(0.0, 0.0, 0.0, 1.0)) -> None:
        self.prepare(frame)
        self.draw(mvp, viewport, background)

    def release(self) -> None:
        self.painter.release()


NO_SECTION = (0.0, 0.0, 0.0, 1.0)     # every screen point u: 0.u <= 1


def identity_state(ctx: moderngl.Context, layers: bool, section) -> tuple[float, ...]:
    """GL state for `Backend.draw_identities`: additive blending for layer counts, a depth test for
    the nearest; returns the section plane as the uniform u_section takes it."""
    if layers:
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE
    else:
        ctx.disable(moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
    return tuple(float(v) for v in (NO_SECTION if section is None else section))


def backend_names() -> list[str]:
    return [*BACKENDS, "auto"]


def software_renderer(ctx: moderngl.Context) -> bool:
    """Whether the context rasterises on the CPU."""
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return any(name in renderer for name in SOFTWARE_RENDERERS)


def create_backend(name: str, ctx: moderngl.Context, line_width: float = 2.0) -> Backend:
    """The backend `name` ("auto" resolved for this context) on `ctx`; raises ValueError for an unknown
    name and BackendUnavailable when the context cannot run it."""
    if name == "auto":
        name = "clip" if software_renderer(ctx) else "gpu"
    if name not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(backend_names())}, got {name!r}")
    return load_target(BACKENDS[name])(ctx, line_width)


def open_backend(name: str, ctx: moderngl.Context, line_width: float = 2.0, log=None) -> Backend:
    """`create_backend`, falling back to the clip-unit backend (with a warning on `log`) when the
    context cannot run the one asked for (or chosen by "auto")."""
    try:
        return create_backend(name, ctx, line_width)
    except BackendUnavailable as exc:
        if name == "clip":
            raise
        if log is not None:
            log.warning("backend %s unavailable (%s); drawing with the clip-unit backend", name, exc)
        return create_backend("clip", ctx, line_width)

"""moderngl programs and drawing: triangles, wide lines, round points and a text overlay, alpha-blended.

The scene is drawn without a depth buffer: hidden parts are already cut away on the CPU (clip
units), and the semi-transparent fills must all show through each other.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources

import moderngl
import numpy as np

from .scene_mesh import FLOATS_PER_VERTEX

POINT_FLOATS = 8          # x, y, z, r, g, b, a, size (pixels)


def _shader(name: str) -> str:
    return resources.files("touch4d.render").joinpath("shaders", name).read_text()


@dataclass
class Layers:
    """Everything one frame draws, in screen coordinates: (N, 7) triangle and line vertices,
    (N, 8) points, and an optional RGBA overlay image at the top-left corner."""

    triangles: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    points: list = field(default_factory=list)
    overlay: np.ndarray | None = None


class _Stream:
    """A vertex buffer reused across frames (grown when needed) and its vertex array."""

    def __init__(self, ctx: moderngl.Context, program: moderngl.Program, layout: str, attributes: tuple):
        self.ctx, self.program, self.layout, self.attributes = ctx, program, layout, attributes
        self.buffer = None
        self.vao = None

    def upload(self, data: np.ndarray) -> int:
        """Write the vertices; returns how many there are."""
        data = np.ascontiguousarray(data, dtype=np.float32)
        if len(data) == 0:
            return 0
        if self.buffer is None or self.buffer.size < data.nbytes:
            if self.buffer is not None:
                self.vao.release()
                self.buffer.release()
            self.buffer = self.ctx.buffer(reserve=max(data.nbytes, 1 << 16) * 2, dynamic=True)
            self.vao = self.ctx.vertex_array(self.program, [(self.buffer, self.layout, *self.attributes)])
        self.buffer.write(data)
        return len(data)

    def release(self) -> None:
        if self.buffer is not None:
            self.vao.release()
            self.buffer.release()


class Painter:
    """Draws `Layers` with a camera matrix into whatever framebuffer is bound."""

    def __init__(self, ctx: moderngl.Context, line_width: float = 2.0):
        self.ctx = ctx
        self.line_width = line_width
        self.flat = ctx.program(vertex_shader=_shader("flat.vert.glsl"), fragment_shader=_shader("flat.frag.glsl"))
        self.line = ctx.program(vertex_shader=_shader("flat.vert.glsl"), geometry_shader=_shader("line.geom.glsl"),
                                fragment_shader=_shader("line.frag.glsl"))
        self.point = ctx.program(vertex_shader=_shader("point.vert.glsl"), fragment_shader=_shader("point.frag.glsl"))
        self.overlay = ctx.program(vertex_shader=_shader("overlay.vert.glsl"), fragment_shader=_shader("overlay.frag.glsl"))
        self._tris = _Stream(ctx, self.flat, "3f 4f", ("in_position", "in_color"))
        self._lines = _Stream(ctx, self.line, "3f 4f", ("in_position", "in_color"))
        self._points = _Stream(ctx, self.point, "3f 4f 1f", ("in_position", "in_color", "in_size"))
        self._quad = _Stream(ctx, self.overlay, "2f 2f", ("in_position", "in_uv"))
        self._texture = None

    def upload(self, layers: Layers) -> tuple[int, int, int]:
        """Send the frame's vertices to the GPU; returns (triangle, line, point) vertex counts."""
        return (self._tris.upload(_join(layers.triangles, FLOATS_PER_VERTEX)),
                self._lines.upload(_join(layers.lines, FLOATS_PER_VERTEX)),
                self._points.upload(_join(layers.points, POINT_FLOATS)))

    def draw(self, counts: tuple[int, int, int], mvp: np.ndarray, viewport: tuple[int, int],
             background=(0.0, 0.0, 0.0, 1.0), overlay: np.ndarray | None = None) -> None:
        """Clear and draw what `upload` sent, seen through `mvp` (world -> clip, row-major numpy)."""
        ctx = self.ctx
        ctx.clear(*background)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
        ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        m = np.ascontiguousarray(mvp.T, dtype=np.float32).tobytes()   # GL wants column-major
        n_tri, n_line, n_point = counts
        if n_tri:
            self.flat["u_mvp"].write(m)
            self._tris.vao.render(moderngl.TRIANGLES, vertices=n_tri)
        if n_line:
            self.line["u_mvp"].write(m)
            self.line["u_viewport"].value = tuple(float(v) for v in viewport)
            self.line["u_width"].value = float(self.line_width)
            self._lines.vao.render(moderngl.LINES, vertices=n_line)
        if n_point:
            self.point["u_mvp"].write(m)
            self._points.vao.render(moderngl.POINTS, vertices=n_point)
        if overlay is not None:
            self._draw_overlay(overlay, viewport)

    def paint(self, layers: Layers, mvp: np.ndarray, viewport: tuple[int, int], background=(0, 0, 0, 1)) -> None:
        self.draw(self.upload(layers), mvp, viewport, background, layers.overlay)

    def _draw_overlay(self, image: np.ndarray, viewport: tuple[int, int]) -> None:
        """Blit an RGBA image (row 0 at the top) to the top-left corner, pixel for pixel."""
        h, w = image.shape[:2]
        if self._texture is None or self._texture.size != (w, h):
            if self._texture is not None:
                self._texture.release()
            self._texture = self.ctx.texture((w, h), 4)
            self._texture.filter = moderngl.NEAREST, moderngl.NEAREST
        self._texture.write(np.ascontiguousarray(image[::-1]).tobytes())
        x1 = -1 + 2 * w / viewport[0]
        y0 = 1 - 2 * h / viewport[1]
        quad = np.array([[-1, y0, 0, 0], [x1, y0, 1, 0], [-1, 1, 0, 1], [x1, 1, 1, 1]], np.float32)
        self._quad.upload(quad)
        self._texture.use(0)
        self.overlay["u_texture"].value = 0
        self._quad.vao.render(moderngl.TRIANGLE_STRIP, vertices=4)

    def release(self) -> None:
        for s in (self._tris, self._lines, self._points, self._quad):
            s.release()
        for p in (self.flat, self.line, self.point, self.overlay):
            p.release()
        if self._texture is not None:
            self._texture.release()


def _join(parts: list, width: int) -> np.ndarray:
    parts = [np.asarray(p, dtype=np.float32).reshape(-1, width) for p in parts if p is not None and len(p)]
    return np.concatenate(parts) if parts else np.zeros((0, width), np.float32)

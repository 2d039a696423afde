"""moderngl drawing of a frame's flat layers (triangles, wide lines, round points, the text overlay),
alpha-blended, shared by every backend. The shaders are the GLSL ES-compatible ones of `glsl`.

The flat layers are drawn without a depth buffer: what is hidden is already removed, and the
semi-transparent fills must all show through each other. The opaque solids (the slice view's
cross-sections) come first and write depth; the scene's translucent projection after them is tested
against it without writing it (`translucent_over_solids`): a projection surface in front of a solid
tints it, one behind it is hidden by it.
"""
from __future__ import annotations

from contextlib import contextmanager

import moderngl
import numpy as np

from .frame import FLOATS_PER_VERTEX, POINT_FLOATS, Frame
from .glsl import shader_source

QUAD_CORNERS = np.arange(4, dtype=np.float32)      # a wide line's quad, as a triangle strip


def program(ctx: moderngl.Context, vertex: str, fragment: str) -> moderngl.Program:
    """A program from two shaders of `glsl`, for desktop GLSL 3.30."""
    return ctx.program(vertex_shader=shader_source(vertex), fragment_shader=shader_source(fragment))


def set_uniforms(prog: moderngl.Program, **values) -> None:
    """Set the uniforms the program has (the compiler drops unused ones); 4x4 matrices are row-major
    numpy (GL wants them column-major), other arrays are written as they are (e.g. a vec3 array)."""
    for name, value in values.items():
        if name not in prog:
            continue
        if isinstance(value, np.ndarray):
            data = np.ascontiguousarray(value.T if value.shape == (4, 4) else value, dtype=np.float32)
            prog[name].write(data.tobytes())
        else:
            prog[name].value = value


SOLID_OFFSET = (1.0, 1.0)      # glPolygonOffset of the solids: a projection face where a solid's lies tints it


@contextmanager
def translucent_over_solids(ctx: moderngl.Context, fbo: moderngl.Framebuffer | None = None):
    """The depth rule of the translucent projection drawn into `fbo` (the bound one by default): tested
    against the solids' depth (a surface behind a solid is hidden), not written (every translucent
    surface in front shows through every other)."""
    fbo = ctx.fbo if fbo is None else fbo
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.depth_func = "<="
    fbo.depth_mask = False
    try:
        yield
    finally:
        fbo.depth_mask = True
        ctx.depth_func = "<"
        ctx.disable(moderngl.DEPTH_TEST)


ACCUM_UNIT, WEIGHT_UNIT = 11, 12    # texture units of the transparency targets in the resolve (oit.frag)
OIT_DTYPE = "f2"


class Transparency:
    """Weighted blended order-independent transparency, the one way every backend draws the scene's
    translucent layers (fills, centre copies): a layer's fragments are summed into two float targets
    (scene.frag's u_mode 1, flat_oit.frag), under the depth rule of the translucent projection (the
    targets' depth holds the solids', drawn again there), then resolved over the framebuffer (oit.frag)."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.resolve = program(ctx, "fullscreen.vert", "oit.frag")
        set_uniforms(self.resolve, t_accum=ACCUM_UNIT, t_weight=WEIGHT_UNIT)
        self._vao = ctx.vertex_array(self.resolve, [])
        self._targets = None                   # (size, framebuffer, its depth alone, accum, weight, depth)

    def layer(self, draw, painter: "Painter", mvp: np.ndarray, viewport: tuple[int, int]) -> None:
        """One translucent layer: `draw()` issues its draw calls into the targets (the programs' OIT
        mode set), then it is resolved over the framebuffer bound before."""
        ctx = self.ctx
        previous, saved_viewport = ctx.fbo, ctx.viewport
        fbo, depth_only, accum, weight = self._of_size(tuple(viewport))
        fbo.use()
        ctx.viewport = (0, 0, *viewport)
        fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        if painter.has_solids:
            depth_only.use()
            painter.draw_solids(mvp)
            fbo.use()
        ctx.disable(moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE, moderngl.ZERO, moderngl.ONE_MINUS_SRC_ALPHA
        with translucent_over_solids(ctx, fbo):
            draw()
        previous.use()
        ctx.viewport = saved_viewport
        ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        accum.use(ACCUM_UNIT)
        weight.use(WEIGHT_UNIT)
        self._vao.render(moderngl.TRIANGLES, vertices=3)

    def _of_size(self, size: tuple[int, int]):
        if self._targets is None or self._targets[0] != size:
            self._release_targets()
            accum = self.ctx.texture(size, 4, dtype=OIT_DTYPE)
            weight = self.ctx.texture(size, 4, dtype=OIT_DTYPE)
            for t in (accum, weight):
                t.filter = moderngl.NEAREST, moderngl.NEAREST
            depth = self.ctx.depth_renderbuffer(size)
            self._targets = (size, self.ctx.framebuffer([accum, weight], depth),
                             self.ctx.framebuffer(depth_attachment=depth), accum, weight, depth)
        return self._targets[1:5]

    def _release_targets(self) -> None:
        if self._targets is not None:
            for obj in self._targets[1:]:
                obj.release()
            self._targets = None

    def release(self) -> None:
        self._release_targets()
        self._vao.release()
        self.resolve.release()


class Stream:
    """A vertex buffer reused across frames (grown when needed) and its vertex array."""

    def __init__(self, ctx: moderngl.Context, prog: moderngl.Program, layout: str, attributes: tuple,
                 corners: moderngl.Buffer | None = None):
        self.ctx, self.program, self.layout, self.attributes = ctx, prog, layout, attributes
        self.corners = corners
        self.buffer = None
        self.vao = None

    def upload(self, data: np.ndarray) -> int:
        """Write the items; returns how many there are."""
        data = np.ascontiguousarray(data, dtype=np.float32)
        if len(data) == 0:
            return 0
        if self.buffer is None or self.buffer.size < data.nbytes:
            self.release()
            self.buffer = self.ctx.buffer(reserve=max(data.nbytes, 1 << 16) * 2, dynamic=True)
            content = [(self.buffer, self.layout, *self.attributes)]
            if self.corners is not None:
                content.insert(0, (self.corners, "1f", "in_corner"))
            self.vao = self.ctx.vertex_array(self.program, content)
        self.buffer.write(data)
        return len(data)

    def release(self) -> None:
        if self.buffer is not None:
            self.vao.release()
            self.buffer.release()
            self.buffer = self.vao = None


class Painter:
    """Draws a frame's flat layers with a camera matrix into whatever framebuffer is bound."""

    def __init__(self, ctx: moderngl.Context, line_width: float = 2.0):
        self.ctx = ctx
        self.line_width = line_width
        self.flat = program(ctx, "flat.vert", "flat.frag")
        self.flat_oit = program(ctx, "flat.vert", "flat_oit.frag")
        self.transparency = Transparency(ctx)
        self.line = program(ctx, "line.vert", "flat.frag")
        self.point = program(ctx, "point.vert", "point.frag")
        self.overlay = program(ctx, "overlay.vert", "overlay.frag")
        self.corners = ctx.buffer(QUAD_CORNERS.tobytes())
        self._tris = Stream(ctx, self.flat, "3f 4f", ("in_position", "in_color"))
        self._solids = Stream(ctx, self.flat, "3f 4f", ("in_position", "in_color"))
        self._scene_layers: list[Stream] = []     # the scene's translucent layers, one stream each
        self._scene_lines = Stream(ctx, self.line, "3f 4f 3f 4f/i", ("in_a", "in_color_a", "in_b", "in_color_b"),
                                   self.corners)
        self._lines = Stream(ctx, self.line, "3f 4f 3f 4f/i", ("in_a", "in_color_a", "in_b", "in_color_b"),
                             self.corners)
        self._points = Stream(ctx, self.point, "3f 4f 1f", ("in_position", "in_color", "in_size"))
        self._quad = Stream(ctx, self.overlay, "2f 2f", ("in_position", "in_uv"))
        self._texture = None
        self._counts = (0, 0, 0)
        self._scene_counts: tuple[list[int], int] = ([], 0)
        self._n_solid = 0
        self._overlay = None

    def upload(self, frame: Frame, layers=(), lines=()) -> tuple[int, int, int]:
        """Send the frame's flat layers, and a translucent scene's triangle `layers` (each drawn as one
        order-independent layer) and `lines` (the clip-unit mesh: fills, centre copies, edges; drawn by
        `draw_scene`), to the GPU; returns the (triangle vertex, line segment, point) counts of them all."""
        while len(self._scene_layers) < len(layers):
            self._scene_layers.append(Stream(self.ctx, self.flat_oit, "3f 4f", ("in_position", "in_color")))
        self._scene_counts = ([s.upload(join([t], FLOATS_PER_VERTEX)) for s, t in zip(self._scene_layers, layers)],
                              self._scene_lines.upload(join(lines, FLOATS_PER_VERTEX).reshape(-1, 14)))
        self._counts = (self._tris.upload(join(frame.triangles, FLOATS_PER_VERTEX)),
                        self._lines.upload(join(frame.lines, FLOATS_PER_VERTEX).reshape(-1, 14)),
                        self._points.upload(join(frame.points, POINT_FLOATS)))
        self._overlay = frame.overlay
        self._n_solid = self._solids.upload(join(frame.solids, FLOATS_PER_VERTEX))
        return (self._counts[0] + sum(self._scene_counts[0]), self._counts[1] + self._scene_counts[1], self._counts[2])

    def draw_scene(self, mvp: np.ndarray, viewport: tuple[int, int]) -> None:
        """The scene's translucent layers, each order-independent, then its lines alpha-blended in
        their order, with the depth rule of the translucent projection (as the gpu backend draws it)."""
        ctx = self.ctx
        counts, n_line = self._scene_counts
        set_uniforms(self.flat_oit, u_mvp=mvp)
        for stream, n in zip(self._scene_layers, counts):
            if n:
                self.transparency.layer(lambda s=stream, k=n: s.vao.render(moderngl.TRIANGLES, vertices=k), self, mvp,
                                        viewport)
        ctx.disable(moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        with translucent_over_solids(ctx):
            if n_line:
                set_uniforms(self.line, u_mvp=mvp, u_viewport=tuple(float(v) for v in viewport),
                             u_width=float(self.line_width))
                self._scene_lines.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n_line)

    def draw(self, mvp: np.ndarray, viewport: tuple[int, int]) -> None:
        """Draw what `upload` sent, seen through `mvp` (3D screen -> clip, row-major numpy), blended
        over what the framebuffer holds."""
        ctx = self.ctx
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND | moderngl.PROGRAM_POINT_SIZE)
        ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        n_tri, n_line, n_point = self._counts
        if n_tri:
            set_uniforms(self.flat, u_mvp=mvp)
            self._tris.vao.render(moderngl.TRIANGLES, vertices=n_tri)
        if n_line:
            set_uniforms(self.line, u_mvp=mvp, u_viewport=tuple(float(v) for v in viewport),
                         u_width=float(self.line_width))
            self._lines.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n_line)
        if n_point:
            set_uniforms(self.point, u_mvp=mvp)
            self._points.vao.render(moderngl.POINTS, vertices=n_point)
        if self._overlay is not None:
            self._draw_overlay(self._overlay, viewport)

    @property
    def has_solids(self) -> bool:
        return self._n_solid > 0

    def draw_solids(self, mvp: np.ndarray) -> None:
        """The opaque solids uploaded, nearest in front, writing depth (pushed back by SOLID_OFFSET):
        drawn first, so that the translucent projection drawn after shows them inside it. Also the
        depth-only pass of a framebuffer without colour (the GPU backend's transparency targets)."""
        if not self._n_solid:
            return
        ctx = self.ctx
        ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.polygon_offset = SOLID_OFFSET
        set_uniforms(self.flat, u_mvp=mvp)
        self._solids.vao.render(moderngl.TRIANGLES, vertices=self._n_solid)
        ctx.polygon_offset = 0.0, 0.0
        ctx.disable(moderngl.DEPTH_TEST)

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
        for s in (self._tris, self._solids, *self._scene_layers, self._scene_lines, self._lines, self._points,
                  self._quad):
            s.release()
        self.transparency.release()
        for p in (self.flat, self.flat_oit, self.line, self.point, self.overlay):
            p.release()
        self.corners.release()
        if self._texture is not None:
            self._texture.release()


def join(parts, width: int) -> np.ndarray:
    """Concatenate vertex arrays of `width` floats (None and empty ones skipped) as float32."""
    parts = [np.asarray(p, dtype=np.float32).reshape(-1, width) for p in parts if p is not None and len(p)]
    return np.concatenate(parts) if parts else np.zeros((0, width), np.float32)

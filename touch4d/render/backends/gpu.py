"""The GPU backend: the scene's geometry lives in GPU buffers and data textures, uploaded once per scene
revision; per frame only the object transforms (a texture of 6 texels per object) and uniforms change.

Per frame, on the GPU: every body's screen bounds and view-space centre (bounds.frag), every cell in
view space (view.frag), a grid of the bodies each screen cell can hold (grid.frag), then the fills
and centre copies into order-independent transparency targets, resolved over the picture
(oit.frag), then the edges. Every scene fragment passes the tactile ray test of halfspace.glsl. docs/contracts.md lists the passes, textures and uniforms, for WebGL2 too.
"""
from __future__ import annotations

import moderngl
import numpy as np

from touch4d.render.draw import ACCUM_UNIT, WEIGHT_UNIT, program, set_uniforms, translucent_over_solids
from touch4d.render.frame import CELL_PALETTE, Frame, SceneLayer
from touch4d.render.scene_geometry import SceneGeometry, data_rows, data_texture

from . import Backend, BackendUnavailable, identity_state

GRID_LO, GRID_HI = -1.0, 1.0          # the body grid spans the 3D screen; outside, border cells take over
UNITS = {"t_objects": 0, "t_bodies": 1, "t_halfspaces": 2, "t_colors": 3, "t_lo": 4, "t_hi": 5,
         "t_cells0": 6, "t_cells1": 7, "t_cells2": 8, "t_cells3": 9, "t_vertices": 10,
         "t_accum": ACCUM_UNIT, "t_weight": WEIGHT_UNIT, "t_centres": 13, "t_view": 14, "t_halfspace_body": 15}
MODE_BLEND, MODE_OIT, MODE_IDS, MODE_LAYERS = 0, 1, 2, 3


class GpuBackend(Backend):
    name = "gpu"

    def __init__(self, ctx: moderngl.Context, line_width: float = 2.0):
        if ctx.version_code < 330:
            raise BackendUnavailable(f"needs OpenGL 3.3, the context has {ctx.version_code}")
        super().__init__(ctx, line_width)
        try:
            self.faces_prog = program(ctx, "scene_face.vert", "scene.frag")
            self.centres_prog = program(ctx, "scene_centre.vert", "scene.frag")
            self.edges_prog = program(ctx, "scene_edge.vert", "scene.frag")
            self.bounds_prog = program(ctx, "fullscreen.vert", "bounds.frag")
            self.view_prog = program(ctx, "fullscreen.vert", "view.frag")
            self.grid_prog = program(ctx, "fullscreen.vert", "grid.frag")
        except moderngl.Error as exc:
            raise BackendUnavailable(f"shaders do not build: {exc}") from exc
        self.programs = [self.faces_prog, self.centres_prog, self.edges_prog, self.bounds_prog, self.view_prog,
                         self.grid_prog]
        for prog in self.programs:
            set_uniforms(prog, **{name: unit for name, unit in UNITS.items()})
        self._fullscreen = {id(p): ctx.vertex_array(p, [])
                            for p in (self.bounds_prog, self.view_prog, self.grid_prog)}
        self.geometry: SceneGeometry | None = None
        self.layer: SceneLayer | None = None
        self._gpu: dict = {}                # per geometry: buffers, vertex arrays, textures, targets
        self._dirty = False                 # transforms written, bounds and grid not yet rebuilt
        self._empty = ctx.texture((1, 1), 4, np.zeros(4, np.float32).tobytes(), dtype="f4")

    # ---- uploads ------------------------------------------------------------------------------------
    def prepare(self, frame: Frame) -> None:
        layer = frame.scene
        if layer is not None and layer.geometry is not self.geometry:
            self._upload_geometry(layer.geometry)
        if layer is not None and layer is not self.layer:
            rows, width = data_rows(layer.transforms)          # only the texels in use
            self._gpu["t_objects"].write(rows.tobytes(), viewport=(0, 0, width, rows.shape[0]))
            self._dirty = True
        self.layer = layer
        self.painter.upload(frame)

    def _upload_geometry(self, g: SceneGeometry) -> None:
        self._release_geometry()
        ctx = self.ctx
        gpu = {name: _data_texture(ctx, array) for name, array in g.textures().items()}
        gpu["t_objects"] = _data_texture(ctx, np.zeros((g.n_objects, 6, 4), np.float32))
        bounds = [_target(ctx, g.n_bodies) for _ in range(3)]
        cells = [_target(ctx, g.grid_size ** 3) for _ in range(4)]
        gpu["t_lo"], gpu["t_hi"], gpu["t_centres"] = bounds
        gpu["t_view"] = _target(ctx, g.n_halfspaces)
        gpu.update({f"t_cells{k}": t for k, t in enumerate(cells)})
        gpu["bounds_fbo"] = ctx.framebuffer(color_attachments=bounds)
        gpu["view_fbo"] = ctx.framebuffer(color_attachments=[gpu["t_view"]])
        gpu["grid_fbo"] = ctx.framebuffer(color_attachments=cells)
        gpu["fills"] = ctx.buffer(g.fills.tobytes()) if len(g.fills) else None
        gpu["centres"] = ctx.buffer(g.centres.tobytes()) if len(g.centres) else None
        gpu["edges"] = ctx.buffer(g.edges.tobytes()) if len(g.edges) else None
        gpu["vao_fills"] = gpu["fills"] and ctx.vertex_array(
            self.faces_prog, [(gpu["fills"], "4f 1f 2f", "in_local", "in_body", "in_cells")])
        gpu["vao_centres"] = gpu["centres"] and ctx.vertex_array(
            self.centres_prog, [(gpu["centres"], "4f 4f 1f 1f", "in_local", "in_centroid", "in_body", "in_cell")])
        gpu["vao_edges"] = gpu["edges"] and ctx.vertex_array(
            self.edges_prog, [(self.painter.corners, "1f", "in_corner"),
                              (gpu["edges"], "4f 4f 1f 4f 4f/i", "in_a", "in_b", "in_body",
                               "in_cells0", "in_cells1")])
        self._gpu = gpu
        self.geometry = g
        self.layer = None

    # ---- drawing ------------------------------------------------------------------------------------
    def _bind(self) -> None:
        for name, unit in UNITS.items():
            self._gpu.get(name, self._empty).use(unit)

    def _scene_uniforms(self, mvp, viewport, layer: SceneLayer) -> None:
        g = self.geometry
        style = layer.style
        n = g.grid_size
        common = dict(u_mvp=np.asarray(mvp, dtype=np.float64), u_eye=float(layer.perspective_eye or 0.0),
                      u_grid=(GRID_LO, (GRID_HI - GRID_LO) / n, float(n), 0.0), u_bodies=g.n_bodies,
                      u_clip=1 if style.clip else 0, u_viewport=tuple(float(v) for v in viewport),
                      u_width=float(self.painter.line_width))
        set_uniforms(self.faces_prog, **common, u_alpha=float(style.fill_alpha))
        set_uniforms(self.centres_prog, **common, u_alpha=float(style.centre_alpha),
                     u_centre_scale=float(style.centre_scale), u_cell_colors=1 if style.cell_colors else 0,
                     u_palette=CELL_PALETTE)
        set_uniforms(self.edges_prog, **common, u_alpha=float(style.edge_alpha))

    def _per_frame_passes(self) -> None:
        """Bodies' screen bounds and centres, their cells in view space, the body grid (only after the
        transforms changed)."""
        if not self._dirty:
            return
        ctx, g, gpu = self.ctx, self.geometry, self._gpu
        previous, viewport = ctx.fbo, ctx.viewport
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        self._bind()
        eye = float(self.layer.perspective_eye or 0.0)
        n = g.grid_size
        for fbo, prog in ((gpu["bounds_fbo"], self.bounds_prog), (gpu["view_fbo"], self.view_prog),
                          (gpu["grid_fbo"], self.grid_prog)):
            fbo.use()
            ctx.viewport = (0, 0, *fbo.size)
            set_uniforms(prog, u_bodies=g.n_bodies, u_halfspaces=g.n_halfspaces, u_eye=eye,
                         u_grid=(GRID_LO, (GRID_HI - GRID_LO) / n, float(n), 0.0))
            self._fullscreen[id(prog)].render(moderngl.TRIANGLES, vertices=3)
        previous.use()
        ctx.viewport = viewport
        self._dirty = False

    def draw_scene(self, mvp, viewport) -> None:
        layer = self.layer
        if layer is None or self.geometry.n_bodies == 0:
            return
        ctx = self.ctx
        self._per_frame_passes()
        self._bind()
        self._scene_uniforms(mvp, viewport, layer)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        # Fills, then centre copies, each layer order-independent within itself and resolved over
        # what is drawn, then the edges (the clip-unit backend draws them the same way).
        self._transparent(["fills"], mvp, viewport)
        if layer.style.centres:
            self._transparent(["centres"], mvp, viewport)
        with translucent_over_solids(ctx):
            self._draw("edges", MODE_BLEND)

    def _transparent(self, layers: list[str], mvp, viewport) -> None:
        """Draw `layers` as one order-independent layer (`draw.Transparency`, as every backend does)."""
        self.painter.transparency.layer(lambda: [self._draw(what, MODE_OIT) for what in layers], self.painter, mvp,
                                        viewport)

    def _draw(self, what: str, mode: int) -> None:
        vao = self._gpu[f"vao_{what}"]
        if not vao:
            return
        set_uniforms(vao.program, u_mode=mode)
        if what == "edges":
            vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=len(self.geometry.edges))
        else:
            vao.render(moderngl.TRIANGLES)

    def draw_identities(self, frame: Frame, mvp, viewport, what: str = "faces", layers: bool = False,
                        section=None) -> None:
        self.prepare(frame)
        if self.layer is None or self.geometry.n_bodies == 0:
            return
        self._per_frame_passes()
        self._bind()
        self._scene_uniforms(mvp, viewport, self.layer)
        plane = identity_state(self.ctx, layers, section)
        for prog in (self.faces_prog, self.edges_prog):
            set_uniforms(prog, u_section=plane)
        self._draw("fills" if what == "faces" else "edges", MODE_LAYERS if layers else MODE_IDS)
        self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)

    # ---- resources ----------------------------------------------------------------------------------
    def _release_geometry(self) -> None:
        for value in self._gpu.values():
            if value:
                value.release()
        self._gpu = {}
        self.geometry = None

    def release(self) -> None:
        self._release_geometry()
        for vao in self._fullscreen.values():
            vao.release()
        for prog in self.programs:
            prog.release()
        self._empty.release()
        super().release()


def _data_texture(ctx: moderngl.Context, records: np.ndarray) -> moderngl.Texture:
    data = data_texture(records)
    t = ctx.texture((data.shape[1], data.shape[0]), 4, data.tobytes(), dtype="f4")
    t.filter = moderngl.NEAREST, moderngl.NEAREST
    return t


def _target(ctx: moderngl.Context, texels: int) -> moderngl.Texture:
    """A float render target for `texels` records in data-texture order."""
    shape = data_texture(np.zeros((max(texels, 1), 4), np.float32)).shape
    t = ctx.texture((shape[1], shape[0]), 4, dtype="f4")
    t.filter = moderngl.NEAREST, moderngl.NEAREST
    return t


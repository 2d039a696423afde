"""The clip-unit backend (paper §4.3): the CPU builds the visible, cut pieces of every body
(`touch4d.render.clip`) whenever the scene moves, and they are drawn as flat triangles and lines."""
from __future__ import annotations

from dataclasses import replace

import moderngl
import numpy as np

from touch4d.render.clip import Body, MeshBuilder, SceneMesh
from touch4d.render.draw import Stream, program, set_uniforms
from touch4d.render.frame import Frame, SceneLayer

from . import Backend, identity_state


def layer_bodies(layer: SceneLayer, colors: np.ndarray | None = None) -> list[Body]:
    """The bodies of a scene layer, placed by its transforms, in their objects' colours (or `colors`,
    one row per object)."""
    g = layer.geometry
    t = np.asarray(layer.transforms, dtype=np.float64)
    rotation = t[:, :4].transpose(0, 2, 1)
    colors = g.object_color.astype(np.float64) if colors is None else colors
    return [Body(part, rotation[o], t[o, 4], float(t[o, 5, 0]), colors[o], int(o))
            for part, o in zip(g.parts, g.body_object)]


class ClipBackend(Backend):
    name = "clip"

    def __init__(self, ctx: moderngl.Context, line_width: float = 2.0):
        super().__init__(ctx, line_width)
        self.builder = MeshBuilder()
        self.mesh: SceneMesh | None = None
        self._layer: SceneLayer | None = None
        self._ids = {"faces": program(ctx, "flat.vert", "id.frag"), "edges": program(ctx, "line.vert", "id.frag")}

    def build(self, layer: SceneLayer, colors: np.ndarray | None = None, style=None) -> SceneMesh:
        return self.builder.build(layer_bodies(layer, colors), layer.projection, layer.eye_distance,
                                  layer.style if style is None else style)

    def prepare(self, frame: Frame) -> None:
        if frame.scene is not self._layer:          # a new scene layer: the scene moved
            self.mesh = None if frame.scene is None else self.build(frame.scene)
            self._layer = frame.scene
        mesh = self.mesh
        self.painter.upload(frame, [mesh.fills, mesh.centres] if mesh else [], [mesh.edges] if mesh else [])

    def draw_scene(self, mvp, viewport) -> None:
        self.painter.draw_scene(mvp, viewport)      # fills, centre copies, edges: uploaded by prepare

    def draw_identities(self, frame: Frame, mvp, viewport, what: str = "faces", layers: bool = False,
                        section=None) -> None:
        layer = frame.scene
        if layer is None:
            return
        ids = np.zeros((layer.geometry.n_objects, 4))
        ids[:, 0] = np.arange(1, len(ids) + 1)
        ids[:, 3] = 1.0
        mesh = self.build(layer, ids, replace(layer.style, centres=False, fill_alpha=1.0, edge_alpha=1.0))
        self._layer = None                          # the builder now holds the identity frame
        prog = self._ids[what]
        if what == "faces":
            stream, data, mode = Stream(self.ctx, prog, "3f 4f", ("in_position", "in_color")), mesh.fills, moderngl.TRIANGLES
        else:
            stream = Stream(self.ctx, prog, "3f 4f 3f 4f/i", ("in_a", "in_color_a", "in_b", "in_color_b"),
                            self.painter.corners)
            data, mode = mesh.edges.reshape(-1, 14), moderngl.TRIANGLE_STRIP
        try:
            n = stream.upload(data)
            if n:
                set_uniforms(prog, u_mvp=mvp, u_viewport=tuple(float(v) for v in viewport),
                             u_width=float(self.painter.line_width), u_mode=3 if layers else 2,
                             u_section=identity_state(self.ctx, layers, section))
                if what == "faces":
                    stream.vao.render(mode, vertices=n)
                else:
                    stream.vao.render(mode, vertices=4, instances=n)
        finally:
            self.ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            stream.release()

    def release(self) -> None:
        for p in self._ids.values():
            p.release()
        super().release()

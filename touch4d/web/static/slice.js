// The slice view on the page: every object's cross-section at w = slice_w, a solid in its cells'
// colours. The node cuts it (touch4d.render.section_mesh, the desktop renderer's own triangles) and
// sends it with each frame; here it is drawn with the renderer's flat shaders, opaque, writing depth,
// before the projection (which the slice view leaves out and the both view draws fainter, tested
// against that depth: hidden behind the solid, tinting it in front), as
// touch4d.render.backends.Backend.draw does.

import { program, Vertices } from './gl.js';

export class SliceRenderer {
  // shaders: the renderer's GLSL ES sources from the node's setup frame.
  constructor(gl, shaders) {
    this.gl = gl;
    this.flat = program(gl, shaders['flat.vert'], shaders['flat.frag'], 'slice');
    const at = (name) => gl.getAttribLocation(this.flat.program, name);
    this.triangles = new Vertices(gl, [[at('in_position'), 3], [at('in_color'), 4]]);
    this.view = 'projection';
    this.label = '';
  }

  // From a frame: the view, where it cuts, the section's triangles [x, y, z, r, g, b, a] per vertex.
  update(frame) {
    const { header: f, arrays: a } = frame;
    this.view = f.view || 'projection';
    this.triangles.upload(a.section || new Float32Array(0));
    const span = f.w_extent ? `objects span w ${f.w_extent[0].toFixed(2)} .. ${f.w_extent[1].toFixed(2)}`
                            : 'nothing to cut';
    this.label = this.view === 'projection' ? '' : `${this.view} view: slice at w = ${f.slice_w.toFixed(2)} (${span})`;
  }

  // What the text panel above the screen shows while no study runs (the panel takes a study's lines):
  // the view and where it cuts, or nothing in the projection view.
  panel() {
    return this.label ? { lines: [this.label] } : null;
  }

  // Whether the projection is drawn too (projection and both views).
  get projection() {
    return this.view !== 'slice';
  }

  // The solid, nearest in front, writing depth, pushed back by touch4d.render.draw.SOLID_OFFSET (a
  // projection face where a solid's lies tints it); `depthOnly`: its depth alone (the projection's
  // transparency targets).
  draw(framebuffer, viewport, mvp, depthOnly = false) {
    if (!this.triangles.count) return;
    const gl = this.gl;
    gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
    gl.viewport(...viewport);
    gl.disable(gl.BLEND);
    gl.enable(gl.DEPTH_TEST);
    gl.depthMask(true);
    gl.depthFunc(gl.LESS);
    gl.enable(gl.POLYGON_OFFSET_FILL);
    gl.polygonOffset(1, 1);
    if (depthOnly) gl.colorMask(false, false, false, false);
    gl.useProgram(this.flat.program);
    gl.uniformMatrix4fv(this.flat.uniforms.u_mvp, false, mvp);
    gl.bindVertexArray(this.triangles.vao);
    gl.drawArrays(gl.TRIANGLES, 0, this.triangles.count);
    gl.bindVertexArray(null);
    gl.colorMask(true, true, true, true);
    gl.disable(gl.POLYGON_OFFSET_FILL);
    gl.disable(gl.DEPTH_TEST);
  }
}

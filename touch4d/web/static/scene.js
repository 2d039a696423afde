// The 4D scene drawn by the GPU renderer's own shaders (touch4d/render/shaders, sent by the node as
// GLSL ES 3.00) from the same arrays as its desktop backend (touch4d/render/backends/gpu.py): the
// geometry's data textures and vertex arrays once per geometry, per frame only the objects'
// transforms texture. The passes, textures and uniforms are those of docs/contracts.md; nothing of
// the 4D mathematics (projection, visibility) lives here.

import { attributes, program } from './gl.js';

export const UNITS = {
  t_objects: 0, t_bodies: 1, t_halfspaces: 2, t_colors: 3, t_lo: 4, t_hi: 5,
  t_cells0: 6, t_cells1: 7, t_cells2: 8, t_cells3: 9, t_vertices: 10, t_accum: 11, t_weight: 12,
  t_centres: 13, t_view: 14, t_halfspace_body: 15,
};
const MODE_BLEND = 0, MODE_OIT = 1;
const DATA_WIDTH = 1024;

// A data texture's size for `texels` texels (touch4d.render.scene_geometry.data_texture): always
// DATA_WIDTH wide, as the shaders address it.
function dataSize(texels) {
  return [DATA_WIDTH, Math.ceil(Math.max(texels, 1) / DATA_WIDTH)];
}

export class SceneRenderer {
  // shaders: {name: GLSL ES source}; style: touch4d.render.frame.Style; palette: CELL_PALETTE (12 x 3).
  constructor(gl, shaders, style, palette) {
    if (!gl.getExtension('EXT_color_buffer_float')) {
      throw new Error('this browser cannot render to float textures (EXT_color_buffer_float)');
    }
    this.gl = gl;
    this.style = style;
    this.palette = palette;
    const make = (vs, fs) => program(gl, shaders[vs], shaders[fs], `${vs} + ${fs}`);
    this.faces = make('scene_face.vert', 'scene.frag');
    this.centres = make('scene_centre.vert', 'scene.frag');
    this.edges = make('scene_edge.vert', 'scene.frag');
    this.bounds = make('fullscreen.vert', 'bounds.frag');
    this.view = make('fullscreen.vert', 'view.frag');
    this.grid = make('fullscreen.vert', 'grid.frag');
    this.oit = make('fullscreen.vert', 'oit.frag');
    this.programs = [this.faces, this.centres, this.edges, this.bounds, this.view, this.grid, this.oit];
    for (const p of this.programs) {
      gl.useProgram(p.program);
      for (const [name, unit] of Object.entries(UNITS)) if (p.uniforms[name]) gl.uniform1i(p.uniforms[name], unit);
    }
    this.corners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.corners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 1, 2, 3]), gl.STATIC_DRAW);
    this.empty = this.texture(1, 1, new Float32Array(4));
    this.vao = gl.createVertexArray();      // for the full-screen passes (no attributes)
    this.geometry = null;
    this.res = {};
    this.frame = null;
    this.dirty = false;
    this.oitTargets = null;
  }

  texture(width, height, data) {
    const gl = this.gl;
    const t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, width, height, 0, gl.RGBA, gl.FLOAT, data);
    for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
    for (const p of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T]) gl.texParameteri(gl.TEXTURE_2D, p, gl.CLAMP_TO_EDGE);
    return t;
  }

  // A data texture from an array shaped (rows, width, 4) by the node.
  dataTexture(array, shape) {
    return this.texture(shape[1], shape[0], array);
  }

  // A float render target holding `texels` records in data-texture order.
  target(texels) {
    const [w, h] = dataSize(texels);
    return { texture: this.texture(w, h, null), width: w, height: h };
  }

  framebuffer(targets) {
    const gl = this.gl;
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    targets.forEach((t, k) => gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + k, gl.TEXTURE_2D, t.texture, 0));
    gl.drawBuffers(targets.map((_, k) => gl.COLOR_ATTACHMENT0 + k));
    return fbo;
  }

  // The node's "geometry" frame: SceneGeometry's textures and vertex arrays (docs/contracts.md).
  setGeometry({ header, arrays }) {
    const gl = this.gl;
    this.release();
    const shapes = Object.fromEntries(Object.entries(header.arrays).map(([name, [, shape]]) => [name, shape]));
    const res = {};
    for (const name of Object.keys(arrays).filter((n) => n.startsWith('t_'))) {
      res[name] = this.dataTexture(arrays[name], shapes[name]);     // the geometry's data textures
    }
    const [ow, oh] = dataSize(6 * header.objects);
    res.t_objects = this.texture(ow, oh, null);
    const bounds = [0, 1, 2].map(() => this.target(header.bodies));     // t_lo, t_hi, t_centres
    const view = this.target(header.halfspaces);
    const cells = [0, 1, 2, 3].map(() => this.target(header.grid_size ** 3));
    [res.t_lo, res.t_hi, res.t_centres] = bounds.map((t) => t.texture);
    res.t_view = view.texture;
    cells.forEach((c, k) => { res[`t_cells${k}`] = c.texture; });
    res.passes = [[this.framebuffer(bounds), bounds[0], this.bounds], [this.framebuffer([view]), view, this.view],
                  [this.framebuffer(cells), cells[0], this.grid]];
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    res.fills = this.vertexArray(this.faces, arrays.fills, [['in_local', 4], ['in_body', 1], ['in_cells', 2]]);
    res.centres = this.vertexArray(this.centres, arrays.centres,
                                   [['in_local', 4], ['in_centroid', 4], ['in_body', 1], ['in_cell', 1]]);
    res.edges = this.vertexArray(this.edges, arrays.edges,
                                 [['in_a', 4], ['in_b', 4], ['in_body', 1], ['in_cells0', 4], ['in_cells1', 4]], true);
    res.counts = { fills: arrays.fills.length / 7, centres: arrays.centres.length / 10, edges: arrays.edges.length / 17 };
    this.res = res;
    this.geometry = header;
    this.dirty = true;
  }

  vertexArray(prog, data, layout, instanced = false) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    if (instanced) {
      const loc = gl.getAttribLocation(prog.program, 'in_corner');
      gl.bindBuffer(gl.ARRAY_BUFFER, this.corners);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, 1, gl.FLOAT, false, 4, 0);
    }
    const buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    attributes(gl, layout.map(([name, size]) => [gl.getAttribLocation(prog.program, name), size]), instanced ? 1 : 0);
    gl.bindVertexArray(null);
    return { vao, buffer };
  }

  // The node's per-tick frame: the objects' transforms (the texels of t_objects in use, the GPU
  // backend's bytes: scene_geometry.data_rows), the projection.
  setFrame(frame) {
    const { header, arrays } = frame;
    if (!this.geometry || header.geometry !== this.geometry.key || !arrays.t_objects) return;
    const gl = this.gl;
    const [rows, width] = header.arrays.t_objects[1];
    gl.bindTexture(gl.TEXTURE_2D, this.res.t_objects);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, width, rows, gl.RGBA, gl.FLOAT, arrays.t_objects);
    this.frame = header;
    this.dirty = true;
  }

  bind() {
    const gl = this.gl;
    for (const [name, unit] of Object.entries(UNITS)) {
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, this.res[name] || this.empty);
    }
  }

  // Bodies' bounds and centres, their cells in view space, the body grid: once per change of the
  // transforms (not per eye). Each pass's targets are bound as framebuffer, not as textures.
  perFramePasses() {
    if (!this.dirty) return;
    const gl = this.gl, g = this.geometry, n = g.grid_size;
    gl.disable(gl.BLEND);
    gl.bindVertexArray(this.vao);
    for (const [fbo, target, prog] of this.res.passes) {
      this.bind();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
      gl.viewport(0, 0, target.width, target.height);
      gl.useProgram(prog.program);
      const u = prog.uniforms;
      if (u.u_bodies) gl.uniform1i(u.u_bodies, g.bodies);
      if (u.u_halfspaces) gl.uniform1i(u.u_halfspaces, g.halfspaces);
      if (u.u_eye) gl.uniform1f(u.u_eye, this.frame.eye);
      if (u.u_grid) gl.uniform4f(u.u_grid, -1, 2 / n, n, 0);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
    this.dirty = false;
  }

  uniforms(prog, mvp, viewport, alpha, mode) {
    const gl = this.gl, u = prog.uniforms, g = this.geometry, n = g.grid_size, s = this.style;
    gl.useProgram(prog.program);
    gl.uniformMatrix4fv(u.u_mvp, false, mvp);
    gl.uniform1f(u.u_eye, this.frame.eye);
    gl.uniform4f(u.u_grid, -1, 2 / n, n, 0);
    gl.uniform1i(u.u_bodies, g.bodies);
    gl.uniform1i(u.u_clip, s.clip ? 1 : 0);
    gl.uniform1i(u.u_mode, mode);
    gl.uniform1f(u.u_alpha, alpha);
    if (u.u_viewport) gl.uniform2f(u.u_viewport, viewport[2], viewport[3]);
    if (u.u_width) gl.uniform1f(u.u_width, 2.0);
    if (u.u_centre_scale) gl.uniform1f(u.u_centre_scale, s.centre_scale);
    if (u.u_cell_colors) gl.uniform1i(u.u_cell_colors, s.cell_colors ? 1 : 0);
    if (u.u_palette) gl.uniform3fv(u.u_palette, this.palette);
  }

  // Draw into `framebuffer` (null: the canvas; an XR layer's otherwise) at `viewport` [x, y, w, h]
  // of a framebuffer `size` [w, h]: fills and centre copies (order-independent transparency), edges,
  // each tested against the depth of the solids drawn before (touch4d.render.draw.translucent_over_solids:
  // hidden behind a solid, tinting it in front). `solids(fbo)` draws their depth alone into another
  // framebuffer (the transparency targets).
  draw(framebuffer, size, viewport, mvp, solids = null) {
    if (!this.geometry || !this.frame || !this.geometry.bodies) return;
    const gl = this.gl, s = this.style;
    this.perFramePasses();
    this.bind();
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.enable(gl.BLEND);
    this.transparent(this.faces, 'fills', s.fill_alpha, framebuffer, size, viewport, mvp, solids);
    if (s.centres) this.transparent(this.centres, 'centres', s.centre_alpha, framebuffer, size, viewport, mvp, solids);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    this.uniforms(this.edges, mvp, viewport, s.edge_alpha, MODE_BLEND);
    this.overSolids(() => {
      gl.bindVertexArray(this.res.edges.vao);
      gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, this.res.counts.edges);
      gl.bindVertexArray(null);
    });
  }

  // The depth rule of the translucent projection: tested against the solids' depth, not written.
  overSolids(drawing) {
    const gl = this.gl;
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LEQUAL);
    gl.depthMask(false);
    drawing();
    gl.depthMask(true);
    gl.depthFunc(gl.LESS);
    gl.disable(gl.DEPTH_TEST);
  }

  // One layer into the weighted blended OIT targets (the size of the whole framebuffer, drawn at the
  // same viewport, so the resolve's gl_FragCoord finds its texels), then resolved over the picture.
  transparent(prog, what, alpha, framebuffer, size, viewport, mvp, solids) {
    const gl = this.gl;
    const [fbo, accum, weight] = this.oitTargets_(size);
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.viewport(...viewport);
    gl.enable(gl.SCISSOR_TEST);
    gl.scissor(...viewport);
    gl.clearBufferfv(gl.COLOR, 0, [0, 0, 0, 1]);
    gl.clearBufferfv(gl.COLOR, 1, [0, 0, 0, 0]);
    gl.depthMask(true);
    gl.clearBufferfv(gl.DEPTH, 0, [1]);
    gl.disable(gl.SCISSOR_TEST);
    if (solids) {
      solids(fbo);
      this.bind();
    }
    gl.enable(gl.BLEND);
    gl.blendFuncSeparate(gl.ONE, gl.ONE, gl.ZERO, gl.ONE_MINUS_SRC_ALPHA);
    this.uniforms(prog, mvp, viewport, alpha, MODE_OIT);
    gl.bindVertexArray(this.res[what].vao);
    this.overSolids(() => gl.drawArrays(gl.TRIANGLES, 0, this.res.counts[what]));
    gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
    gl.viewport(...viewport);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    gl.activeTexture(gl.TEXTURE0 + UNITS.t_accum);
    gl.bindTexture(gl.TEXTURE_2D, accum);
    gl.activeTexture(gl.TEXTURE0 + UNITS.t_weight);
    gl.bindTexture(gl.TEXTURE_2D, weight);
    gl.useProgram(this.oit.program);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
  }

  oitTargets_(size) {
    const gl = this.gl;
    if (this.oitTargets && this.oitTargets.size[0] === size[0] && this.oitTargets.size[1] === size[1]) {
      return this.oitTargets.objects;
    }
    if (this.oitTargets) {
      const [fbo, a, w, depth] = this.oitTargets.objects;
      gl.deleteFramebuffer(fbo); gl.deleteTexture(a); gl.deleteTexture(w); gl.deleteRenderbuffer(depth);
    }
    const half = () => {
      const t = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, t);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA16F, size[0], size[1]);
      for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
      return t;
    };
    const accum = half(), weight = half();
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, accum, 0);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT1, gl.TEXTURE_2D, weight, 0);
    const depth = gl.createRenderbuffer();        // the solids' depth, drawn again here
    gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, size[0], size[1]);
    gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
    gl.drawBuffers([gl.COLOR_ATTACHMENT0, gl.COLOR_ATTACHMENT1]);
    this.oitTargets = { size: [...size], objects: [fbo, accum, weight, depth] };
    return this.oitTargets.objects;
  }

  release() {
    const gl = this.gl;
    for (const [fbo] of this.res.passes || []) gl.deleteFramebuffer(fbo);
    for (const value of Object.values(this.res)) {
      if (value instanceof WebGLTexture) gl.deleteTexture(value);
      else if (value instanceof WebGLFramebuffer) gl.deleteFramebuffer(value);
      else if (value && value.vao) { gl.deleteVertexArray(value.vao); gl.deleteBuffer(value.buffer); }
    }
    this.res = {};
    this.geometry = null;
  }
}

// The 4D scene. TEMPORARY: edges only, until the GPU renderer's shaders are served to the page.

import { program } from './gl.js';

const MAX_OBJECTS = 32;

const VS = `#version 300 es
layout(location = 0) in vec4 a_local;
layout(location = 1) in float a_object;
uniform mat4 u_mvp;
uniform mat4 u_orientation[${MAX_OBJECTS}];
uniform vec4 u_position[${MAX_OBJECTS}];
uniform float u_size[${MAX_OBJECTS}];
uniform vec4 u_color[${MAX_OBJECTS}];
uniform float u_eye;   // 0: orthographic
out vec4 v_color;
void main() {
  int k = int(a_object);
  vec4 world = u_orientation[k] * (u_size[k] * a_local) + u_position[k];
  vec3 p = u_eye > 0.0 ? world.xyz * (u_eye / (world.w + u_eye)) : world.xyz;
  v_color = vec4(u_color[k].rgb, 1.0);
  gl_Position = u_mvp * vec4(p, 1.0);
}`;

const FS = `#version 300 es
precision mediump float;
in vec4 v_color;
out vec4 color;
void main() { color = v_color; }`;

export class SceneView {
  constructor(gl) {
    this.gl = gl;
    this.prog = program(gl, VS, FS, 'scene');
    this.vao = gl.createVertexArray();
    this.vbuf = gl.createBuffer();
    this.ibuf = gl.createBuffer();
    this.count = 0;
    this.key = null;
    this.frame = null;
  }

  setGeometry({ header, arrays }) {
    const gl = this.gl;
    const v = arrays.vertices, owner = arrays.object;
    const n = owner.length;
    const data = new Float32Array(n * 5);
    for (let i = 0; i < n; i++) {
      data.set(v.subarray(4 * i, 4 * i + 4), 5 * i);
      data[5 * i + 4] = owner[i];
    }
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.vbuf);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 4, gl.FLOAT, false, 20, 0);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 1, gl.FLOAT, false, 20, 16);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, this.ibuf);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, arrays.edges, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    this.count = arrays.edges.length;
    this.key = header.key;
  }

  update(frame) {
    this.frame = frame;
  }

  draw(mvp) {
    const f = this.frame;
    if (!f || !this.count || f.header.geometry !== this.key || !f.arrays.orientation) return;
    const gl = this.gl, u = this.prog.uniforms;
    const k = Math.min(f.arrays.size.length, MAX_OBJECTS);
    gl.useProgram(this.prog.program);
    gl.uniformMatrix4fv(u.u_mvp, false, mvp);
    // orientation arrives row-major (numpy): transpose into GL's column-major
    gl.uniformMatrix4fv(u.u_orientation, true, f.arrays.orientation.subarray(0, 16 * k));
    gl.uniform4fv(u.u_position, f.arrays.position.subarray(0, 4 * k));
    gl.uniform1fv(u.u_size, f.arrays.size.subarray(0, k));
    gl.uniform4fv(u.u_color, f.arrays.color.subarray(0, 4 * k));
    gl.uniform1f(u.u_eye, f.header.projection === 'perspective' ? f.header.eye_distance : 0);
    gl.bindVertexArray(this.vao);
    gl.drawElements(gl.LINES, this.count, gl.UNSIGNED_INT, 0);
  }
}

// What is drawn around the 4D scene, in screen units: the screen's frame, the hand with its sample
// points coloured by the stimulus, and the tactile cube beside the screen (the paper's Fig. 17).
// Layout and colours come from the node's setup frame (touch4d/render/hud.py), not from here.

import { program, Vertices } from './gl.js';

const LINE_VS = `#version 300 es
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec4 a_color;
uniform mat4 u_mvp;
out vec4 v_color;
void main() { v_color = a_color; gl_Position = u_mvp * vec4(a_position, 1.0); }`;

const LINE_FS = `#version 300 es
precision mediump float;
in vec4 v_color;
out vec4 color;
void main() { color = v_color; }`;

// Points sized in screen units (a sample's diameter), so they keep their size in the room.
const POINT_VS = `#version 300 es
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec4 a_color;
layout(location = 2) in float a_size;
uniform mat4 u_mvp;
uniform float u_pixels;   // pixels per unit at clip w = 1
out vec4 v_color;
void main() {
  v_color = a_color;
  gl_Position = u_mvp * vec4(a_position, 1.0);
  gl_PointSize = max(1.5, a_size * u_pixels / gl_Position.w);
}`;

const POINT_FS = `#version 300 es
precision mediump float;
in vec4 v_color;
out vec4 color;
void main() {
  vec2 d = gl_PointCoord - 0.5;
  if (dot(d, d) > 0.25) discard;   // round points
  color = v_color;
}`;

const FRAME_COLOR = [0.75, 0.75, 0.8, 0.9];
const HAND_COLOR = [0.95, 0.85, 0.75, 0.9];
const MOTOR_COLOR = [0.0, 1.0, 1.0, 1.0];
const MISS_COLOR = [0.45, 0.45, 0.5, 0.6];
const SAMPLE_SIZE = 0.035;          // screen units
const CUBE_SIZE = [0.03, 0.09];     // screen units, h = 0 .. 1

const CUBE_EDGES = (() => {
  const out = [];
  for (let i = 0; i < 8; i++) {
    for (let j = i + 1; j < 8; j++) {
      const d = i ^ j;
      if (d === 1 || d === 2 || d === 4) out.push([i, j]);
    }
  }
  return out.map(([i, j]) => [i, j].map((k) => [k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1]));
})();

function wireCube(out, center, half, color) {
  for (const [a, b] of CUBE_EDGES) {
    for (const p of [a, b]) out.push(center[0] + half * p[0], center[1] + half * p[1], center[2] + half * p[2], ...color);
  }
}

export class Hud {
  constructor(gl) {
    this.gl = gl;
    this.lines = program(gl, LINE_VS, LINE_FS, 'hud lines');
    this.points = program(gl, POINT_VS, POINT_FS, 'hud points');
    this.lineVerts = new Vertices(gl, [[0, 3], [1, 4]]);
    this.pointVerts = new Vertices(gl, [[0, 3], [1, 4], [2, 1]]);
    this.setup = null;
  }

  // From the node's setup frame: the glove's samples, outline and motors, the cube, the colours.
  configure(setup) {
    this.setup = setup;
  }

  amplitude(h) {
    const stops = this.setup.arrays.amplitude_stops, rgb = this.setup.arrays.amplitude_rgb;
    h = Math.min(Math.max(h, 0), 1);
    let k = 0;
    while (k < stops.length - 2 && h > stops[k + 1]) k++;
    const u = (h - stops[k]) / (stops[k + 1] - stops[k]);
    return [0, 1, 2].map((c) => rgb[3 * k + c] + u * (rgb[3 * (k + 1) + c] - rgb[3 * k + c]));
  }

  // Rebuild the vertices from the latest frame: hand pose, h per sample, which samples touch.
  update(frame) {
    if (!this.setup) return;
    const { header: s, arrays: a } = this.setup;
    const lines = [], points = [];
    wireCube(lines, [0, 0, 0], 1, FRAME_COLOR);
    wireCube(lines, s.cube_center, s.cube_half, FRAME_COLOR);
    const n = a.samples.length / 3;
    const h = frame ? frame.arrays.h : new Float32Array(n);
    const touched = frame ? frame.arrays.touched : new Uint8Array(n);
    // the tactile cube: every sample at its place in the hand, coloured and sized by h; motors ringed
    const cube = a.cube_points;
    for (const k of a.motor_sample) {
      points.push(cube[3 * k], cube[3 * k + 1], cube[3 * k + 2], ...MOTOR_COLOR,
                  CUBE_SIZE[0] + (CUBE_SIZE[1] - CUBE_SIZE[0]) * h[k] + 0.025);
    }
    for (let k = 0; k < n; k++) {
      const color = touched[k] ? [...this.amplitude(h[k]), 1] : MISS_COLOR;
      points.push(cube[3 * k], cube[3 * k + 1], cube[3 * k + 2], ...color,
                  CUBE_SIZE[0] + (CUBE_SIZE[1] - CUBE_SIZE[0]) * Math.min(Math.max(h[k], 0), 1));
    }
    // the hand where the bus says it is
    if (frame && frame.header.hand_valid) {
      const place = handTransform(frame.arrays.hand);
      const sk = a.skeleton;
      for (let i = 0; i < sk.length; i += 3) lines.push(...place(sk[i], sk[i + 1], sk[i + 2]), ...HAND_COLOR);
      for (let k = 0; k < n; k++) {
        const color = touched[k] ? [...this.amplitude(h[k]), 0.95] : HAND_COLOR;
        points.push(...place(a.samples[3 * k], a.samples[3 * k + 1], a.samples[3 * k + 2]), ...color, SAMPLE_SIZE);
      }
    }
    this.lineVerts.upload(new Float32Array(lines));
    this.pointVerts.upload(new Float32Array(points));
  }

  draw(mvp, pixels) {
    const gl = this.gl;
    gl.useProgram(this.lines.program);
    gl.uniformMatrix4fv(this.lines.uniforms.u_mvp, false, mvp);
    this.lineVerts.draw(gl.LINES);
    gl.useProgram(this.points.program);
    gl.uniformMatrix4fv(this.points.uniforms.u_mvp, false, mvp);
    gl.uniform1f(this.points.uniforms.u_pixels, pixels);
    this.pointVerts.draw(gl.POINTS);
  }
}

// The hand frame -> screen map of a pose [x, y, z, qx, qy, qz, qw] (hand samples are in screen units).
function handTransform(pose) {
  const [tx, ty, tz, x, y, z, w] = pose;
  const r = [
    1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
    2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
    2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
  ];
  return (px, py, pz) => [
    tx + r[0] * px + r[1] * py + r[2] * pz,
    ty + r[3] * px + r[4] * py + r[5] * pz,
    tz + r[6] * px + r[7] * py + r[8] * pz,
  ];
}

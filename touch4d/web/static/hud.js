// What is drawn around the 4D scene, in screen units: the screen's frame, the hand with its sample
// points coloured by the stimulus, and the tactile cube beside the screen (the paper's Fig. 17).
// Layout and colours come from the node's setup frame (touch4d/render/hud.py), not from here. Lines
// are the renderer's wide lines (line.vert + flat.frag); points are sized in screen units here, not
// in pixels as on the desktop, so that they keep their size in the room.

import { Lines, program, Vertices } from './gl.js';
import { fromPose } from './mat.js';

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

// A segment is one instance of line.vert: [a (3), colour at a (4), b (3), colour at b (4)].
function segment(out, a, b, color) {
  out.push(a[0], a[1], a[2], ...color, b[0], b[1], b[2], ...color);
}

function wireCube(out, center, half, color) {
  const at = (p) => [center[0] + half * p[0], center[1] + half * p[1], center[2] + half * p[2]];
  for (const [a, b] of CUBE_EDGES) segment(out, at(a), at(b), color);
}

export class Hud {
  // shaders: the renderer's GLSL ES sources from the node's setup frame.
  constructor(gl, shaders) {
    this.gl = gl;
    this.lines = program(gl, shaders['line.vert'], shaders['flat.frag'], 'hud lines');
    this.points = program(gl, POINT_VS, POINT_FS, 'hud points');
    this.lineVerts = new Lines(gl, this.lines.program);
    this.pointVerts = new Vertices(gl, [[0, 3], [1, 4], [2, 1]]);
    this.setup = null;
  }

  // From the node's setup frame: the glove's samples, outline and motors, the cube, the colours.
  configure(setup) {
    this.setup = setup;
    this.update(null);
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
    // the hand where the bus says it is: with its fingers where the joints put them while hand/joints
    // drives (the node sends the samples and joints placed), else the rigid glove at the pose
    if (frame && frame.header.hand_valid && frame.arrays.hand_samples) {
      const p = frame.arrays.hand_samples, j = frame.arrays.hand_joints, pairs = a.outline_pairs;
      for (let i = 0; i < pairs.length; i += 2) {
        const u = 3 * pairs[i], v = 3 * pairs[i + 1];
        segment(lines, [j[u], j[u + 1], j[u + 2]], [j[v], j[v + 1], j[v + 2]], HAND_COLOR);
      }
      for (let k = 0; k < n; k++) {
        const color = touched[k] ? [...this.amplitude(h[k]), 0.95] : HAND_COLOR;
        points.push(p[3 * k], p[3 * k + 1], p[3 * k + 2], ...color, SAMPLE_SIZE);
      }
    } else if (frame && frame.header.hand_valid) {
      const place = handTransform(frame.arrays.hand);
      const sk = a.skeleton;
      for (let i = 0; i < sk.length; i += 6) {
        segment(lines, place(sk[i], sk[i + 1], sk[i + 2]), place(sk[i + 3], sk[i + 4], sk[i + 5]), HAND_COLOR);
      }
      for (let k = 0; k < n; k++) {
        const color = touched[k] ? [...this.amplitude(h[k]), 0.95] : HAND_COLOR;
        points.push(...place(a.samples[3 * k], a.samples[3 * k + 1], a.samples[3 * k + 2]), ...color, SAMPLE_SIZE);
      }
    }
    this.lineVerts.upload(new Float32Array(lines));
    this.pointVerts.upload(new Float32Array(points));
  }

  draw(mvp, pixels, viewport) {
    const gl = this.gl;
    gl.useProgram(this.lines.program);
    gl.uniformMatrix4fv(this.lines.uniforms.u_mvp, false, mvp);
    gl.uniform2f(this.lines.uniforms.u_viewport, viewport[2], viewport[3]);
    gl.uniform1f(this.lines.uniforms.u_width, 2.0);
    this.lineVerts.draw();
    gl.useProgram(this.points.program);
    gl.uniformMatrix4fv(this.points.uniforms.u_mvp, false, mvp);
    gl.uniform1f(this.points.uniforms.u_pixels, pixels);
    this.pointVerts.draw(gl.POINTS);
  }
}

// The hand frame -> screen map of a pose [x, y, z, qx, qy, qz, qw] (hand samples are in screen units).
function handTransform(pose) {
  const m = fromPose([pose[0], pose[1], pose[2]], [pose[3], pose[4], pose[5], pose[6]]);
  return (x, y, z) => [m[0] * x + m[4] * y + m[8] * z + m[12], m[1] * x + m[5] * y + m[9] * z + m[13],
                       m[2] * x + m[6] * y + m[10] * z + m[14]];
}

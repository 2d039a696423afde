// The glove hand's touch computed on the headset (the node's `touch: page`), so that it is felt in the
// frame the hand was tracked, not a network round trip later. Per XR frame: the glove file's samples
// placed by the controller's grip pose exactly as the node places the pose it is sent
// (touch4d.tracking.calibration.hand_from_controller, touch4d.tactile.pose.place); their rays along
// +w cast by the renderer's own ray test (shaders/tactile.frag, halfspace.glsl's ray_span: the test
// every drawn fragment passes) into a float texture, read back asynchronously (a pixel buffer and a
// fence, polled the next frame: never a stall; in a slice view touching its cross-section, the
// samples' points of the cut, tested against the same cells); then eq. 1-3 and the motors' mix
// (`stimulus`, as touch4d.tactile.stimulus) and the controller's one actuator's intensity (`level`,
// the strongest motor, as touch4d.web.haptics). tests/test_web_touch.py holds these functions to the Python model.

const SAMPLES_UNIT = 16;        // t_samples, after the renderer's 16 units (touch4d.render.tactile)
const DATA_WIDTH = 1024;        // data textures' width (touch4d.render.scene_geometry)

// Quaternions [x, y, z, w] (touch4d.geometry.quaternion's convention).
export function qmul(a, b) {
  const [x1, y1, z1, w1] = a, [x2, y2, z2, w2] = b;
  return [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
          w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2];
}

function unit(q) {
  const n = Math.hypot(...q);
  return q.map((v) => v / n);
}

const conj = (q) => [-q[0], -q[1], -q[2], q[3]];

function rotate(q, v) {
  const r = qmul(qmul(q, [v[0], v[1], v[2], 0]), conj(q));
  return [r[0], r[1], r[2]];
}

// The rotation matrix of a unit quaternion, column-major (a GLSL mat3).
export function matrix3(q) {
  const [x, y, z, w] = q;
  return [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),
          2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w),
          2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)];
}

// The glove hand's pose on the screen from the controller's grip [x, y, z, qx, qy, qz, qw] (room,
// metres), given the setup's calibration fields: {position (screen units), orientation}.
export function handFromGrip(grip, cal) {
  const controller = unit(grip.slice(3, 7));
  const turned = rotate(controller, cal.hand_offset);
  const d = [0, 1, 2].map((k) => grip[k] + turned[k] - cal.screen_center[k]);
  const screenConj = conj(unit(cal.screen_rotation));
  const upm = 2 / cal.screen_edge;
  const position = rotate(screenConj, d).map((v) => v * upm);
  const orientation = unit(qmul(qmul(screenConj, controller), unit(cal.hand_rotation)));
  return { position, orientation };
}

// Eq. 1-3 and the motors' mix for distances `l` (one per sample, NaN or < 0 where nothing is
// touched): {s, h, V}, V one intensity per motor. model: {alpha, beta, gamma, weights (motors x
// samples, row-major), motors}.
export function stimulus(l, model) {
  const n = l.length, s = new Float64Array(n), h = new Float64Array(n);
  let lMin = Infinity;
  for (let i = 0; i < n; i++) if (l[i] >= 0 && l[i] < lMin) lMin = l[i];
  const V = new Float64Array(model.motors);
  if (lMin === Infinity) return { s, h, V };
  let sum = 0, active = 0;
  for (let i = 0; i < n; i++) {
    s[i] = l[i] >= 0 ? Math.max(model.alpha * (lMin - l[i]) + 1, 0) : 0;   // eq. 1
    sum += s[i];
    if (s[i] > 0) active++;
  }
  const factor = active ? 1 - (model.beta * sum) / active : 0;           // eq. 2
  for (let i = 0; i < n; i++) h[i] = factor * s[i];
  for (let m = 0; m < model.motors; m++) {
    let mixed = 0;
    for (let i = 0, row = m * n; i < n; i++) mixed += model.weights[row + i] * h[i];
    V[m] = model.gamma * mixed;                                         // eq. 3
  }
  return { s, h, V };
}

// The held controller's one actuator: the strongest motor, clipped to 0..1 (touch4d.web.haptics).
export function level(V) {
  let top = -Infinity;
  for (const v of V) top = Math.max(top, v);
  return Number.isFinite(top) ? Math.min(Math.max(top, 0), 1) : 0;
}

// The tactile pass on this page's WebGL2 context, over the scene renderer's per-frame textures.
export class PageTouch {
  // program: gl.js's program(fullscreen.vert, tactile.frag); setup: the node's setup message.
  constructor(gl, prog, setup, units) {
    const { header, arrays } = setup;
    this.gl = gl;
    this.prog = prog;
    this.units = units;
    this.n = arrays.samples.length / 3;
    this.model = { alpha: header.alpha, beta: header.beta, gamma: header.gamma, weights: arrays.motor_weights,
                   motors: header.motor_names.length };
    const rows = Math.ceil(this.n / DATA_WIDTH), width = Math.min(this.n, DATA_WIDTH);
    this.size = [rows > 1 ? DATA_WIDTH : width, rows];
    const texels = new Float32Array(DATA_WIDTH * rows * 4);
    for (let i = 0; i < this.n; i++) texels.set(arrays.samples.subarray(3 * i, 3 * i + 3), 4 * i);
    this.samples = this.texture(DATA_WIDTH, rows, texels);
    this.target = this.texture(DATA_WIDTH, rows, null);
    this.fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, this.target, 0);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    this.pbo = gl.createBuffer();
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, this.pbo);
    gl.bufferData(gl.PIXEL_PACK_BUFFER, this.size[0] * this.size[1] * 16, gl.STREAM_READ);
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
    this.read = new Float32Array(this.size[0] * this.size[1] * 4);
    this.vao = gl.createVertexArray();
    gl.useProgram(prog.program);
    for (const [name, u] of Object.entries(units)) if (prog.uniforms[name]) gl.uniform1i(prog.uniforms[name], u);
    gl.uniform1i(prog.uniforms.t_samples, SAMPLES_UNIT);
    this.pending = null;       // {fence, time, at, grip, hand}: a pass whose result is not read yet
    this.passes = 0;
    this.skipped = 0;          // frames whose pass waited for the last one to be read
  }

  texture(width, height, data) {
    const gl = this.gl, t = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, t);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, width, height, 0, gl.RGBA, gl.FLOAT, data);
    for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
    return t;
  }

  // Cast the samples of the hand held at `grip` through the scene now; the result comes from `poll`.
  // False (nothing cast) without a scene, or while the last pass is still on its way.
  submit(scene, grip, calibration, time, now) {
    if (!scene || !scene.geometry || !scene.frame || !scene.geometry.bodies) return false;
    if (this.pending) {
      this.skipped++;
      return false;
    }
    const gl = this.gl, u = this.prog.uniforms;
    const hand = handFromGrip(grip, calibration);
    scene.perFramePasses();
    scene.bind();
    gl.activeTexture(gl.TEXTURE0 + SAMPLES_UNIT);
    gl.bindTexture(gl.TEXTURE_2D, this.samples);
    gl.disable(gl.BLEND);
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.SCISSOR_TEST);
    gl.bindFramebuffer(gl.FRAMEBUFFER, this.fbo);
    gl.viewport(0, 0, this.size[0], this.size[1]);
    gl.useProgram(this.prog.program);
    gl.uniformMatrix3fv(u.u_hand, false, matrix3(hand.orientation));
    gl.uniform3fv(u.u_hand_at, hand.position);
    gl.uniform1i(u.u_samples, this.n);
    gl.uniform1i(u.u_bodies, scene.geometry.bodies);
    gl.uniform1f(u.u_eye, scene.frame.eye || 0);
    // a slice view touching its cross-section: the samples' points of the cut at w = touch_w
    gl.uniform1i(u.u_section, scene.frame.touch_section ? 1 : 0);
    gl.uniform1f(u.u_cut, scene.frame.touch_w || 0);
    gl.bindVertexArray(this.vao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.bindVertexArray(null);
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, this.pbo);
    gl.readPixels(0, 0, this.size[0], this.size[1], gl.RGBA, gl.FLOAT, 0);
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    const fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
    gl.flush();
    this.pending = { fence, time, at: now, grip, hand };
    this.passes++;
    return true;
  }

  // The last pass's result once the GPU has it ({time, at, grip, hand, l, s, h, V}), else null;
  // never waits. One pass is in flight at most, so a result is always the latest pose's; the page
  // drops it when the hand leaves (`drop`).
  poll() {
    const gl = this.gl, p = this.pending;
    if (!p || gl.getSyncParameter(p.fence, gl.SYNC_STATUS) !== gl.SIGNALED) return null;
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, this.pbo);
    gl.getBufferSubData(gl.PIXEL_PACK_BUFFER, 0, this.read);
    gl.bindBuffer(gl.PIXEL_PACK_BUFFER, null);
    gl.deleteSync(p.fence);
    this.pending = null;
    const l = new Float64Array(this.n);
    for (let i = 0; i < this.n; i++) l[i] = this.read[4 * i];
    return { ...p, fence: undefined, l, ...stimulus(l, this.model) };
  }

  // Forget a pass in flight (the hand left, the page hid): its result is never played.
  drop() {
    if (this.pending) this.gl.deleteSync(this.pending.fence);
    this.pending = null;
  }
}

// 4x4 matrices as column-major Float32Arrays (WebGL's layout), for the 3D views only.

export function identity() {
  const m = new Float32Array(16);
  m[0] = m[5] = m[10] = m[15] = 1;
  return m;
}

export function multiply(a, b) {
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      out[c * 4 + r] = s;
    }
  }
  return out;
}

// Translation t, rotation quaternion q = [x, y, z, w], uniform scale s: x -> t + s R(q) x.
export function fromPose(t, q, s = 1) {
  const [x, y, z, w] = q;
  const m = new Float32Array(16);
  m[0] = s * (1 - 2 * (y * y + z * z)); m[1] = s * 2 * (x * y + z * w); m[2] = s * 2 * (x * z - y * w);
  m[4] = s * 2 * (x * y - z * w); m[5] = s * (1 - 2 * (x * x + z * z)); m[6] = s * 2 * (y * z + x * w);
  m[8] = s * 2 * (x * z + y * w); m[9] = s * 2 * (y * z - x * w); m[10] = s * (1 - 2 * (x * x + y * y));
  m[12] = t[0]; m[13] = t[1]; m[14] = t[2]; m[15] = 1;
  return m;
}

export function perspective(fovYDeg, aspect, near, far) {
  const f = 1 / Math.tan((fovYDeg * Math.PI) / 360);
  const m = new Float32Array(16);
  m[0] = f / aspect; m[5] = f;
  m[10] = (far + near) / (near - far); m[11] = -1;
  m[14] = (2 * far * near) / (near - far);
  return m;
}

// World -> camera, the camera at `eye` looking at `target` (right-handed, looking along -z).
export function lookAt(eye, target, up = [0, 1, 0]) {
  const f = norm(sub(target, eye));
  let s = cross(f, up);
  if (Math.hypot(...s) < 1e-9) s = cross(f, [0, 0, 1]);
  s = norm(s);
  const u = cross(s, f);
  const m = identity();
  m[0] = s[0]; m[4] = s[1]; m[8] = s[2];
  m[1] = u[0]; m[5] = u[1]; m[9] = u[2];
  m[2] = -f[0]; m[6] = -f[1]; m[10] = -f[2];
  m[12] = -(s[0] * eye[0] + s[1] * eye[1] + s[2] * eye[2]);
  m[13] = -(u[0] * eye[0] + u[1] * eye[1] + u[2] * eye[2]);
  m[14] = f[0] * eye[0] + f[1] * eye[1] + f[2] * eye[2];
  return m;
}

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const n = Math.hypot(...a); return [a[0] / n, a[1] / n, a[2] / n]; };

// Small WebGL2 helpers: programs with readable errors, and dynamic vertex buffers.

export function program(gl, vertexSource, fragmentSource, name) {
  const shader = (type, source) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, source);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
      throw new Error(`${name}: ${type === gl.VERTEX_SHADER ? 'vertex' : 'fragment'} shader: ${gl.getShaderInfoLog(s)}`);
    }
    return s;
  };
  const p = gl.createProgram();
  gl.attachShader(p, shader(gl.VERTEX_SHADER, vertexSource));
  gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fragmentSource));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`${name}: link: ${gl.getProgramInfoLog(p)}`);
  const uniforms = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const info = gl.getActiveUniform(p, i);
    uniforms[info.name.replace(/\[0\]$/, '')] = gl.getUniformLocation(p, info.name);
  }
  return { program: p, uniforms };
}

// Interleaved float attributes [[location, components], ...] of the bound buffer (-1: unused, skipped).
export function attributes(gl, layout, divisor) {
  const stride = layout.reduce((n, [, c]) => n + c, 0);
  let offset = 0;
  for (const [location, components] of layout) {
    if (location >= 0) {
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, components, gl.FLOAT, false, stride * 4, offset * 4);
      gl.vertexAttribDivisor(location, divisor);
    }
    offset += components;
  }
}

// A vertex array with one interleaved float buffer: layout = [[location, components], ...].
export class Vertices {
  constructor(gl, layout) {
    this.gl = gl;
    this.vao = gl.createVertexArray();
    this.buffer = gl.createBuffer();
    this.stride = layout.reduce((n, [, c]) => n + c, 0);
    this.count = 0;
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffer);
    attributes(gl, layout, 0);
    gl.bindVertexArray(null);
  }

  upload(data) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffer);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.DYNAMIC_DRAW);
    this.count = data.length / this.stride;
  }

  draw(mode) {
    if (!this.count) return;
    this.gl.bindVertexArray(this.vao);
    this.gl.drawArrays(mode, 0, this.count);
  }
}

// Wide lines for the renderer's line.vert: one instance per segment, a quad of 4 corners.
export class Lines {
  constructor(gl, prog) {
    this.gl = gl;
    this.vao = gl.createVertexArray();
    this.buffer = gl.createBuffer();
    this.count = 0;
    gl.bindVertexArray(this.vao);
    const corners = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, corners);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([0, 1, 2, 3]), gl.STATIC_DRAW);
    const corner = gl.getAttribLocation(prog, 'in_corner');
    gl.enableVertexAttribArray(corner);
    gl.vertexAttribPointer(corner, 1, gl.FLOAT, false, 4, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffer);
    attributes(gl, [['in_a', 3], ['in_color_a', 4], ['in_b', 3], ['in_color_b', 4]]
      .map(([name, size]) => [gl.getAttribLocation(prog, name), size]), 1);
    gl.bindVertexArray(null);
  }

  upload(data) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffer);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.DYNAMIC_DRAW);
    this.count = data.length / 14;
  }

  draw() {
    if (!this.count) return;
    this.gl.bindVertexArray(this.vao);
    this.gl.drawArraysInstanced(this.gl.TRIANGLE_STRIP, 0, 4, this.count);
    this.gl.bindVertexArray(null);
  }
}

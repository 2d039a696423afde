// A running study in the page (the node's frames carry it: touch4d/web/bridge.py): the question and
// the buttons that answer it, as a text panel standing above the screen in the headset (drawn from a
// 2D canvas), and as page buttons that a tap or click answers (any browser). The node sends the
// lines, the desktop renderer's (touch4d/render/hud.py, study_lines).

import { program, Vertices } from './gl.js';

const PANEL_VS = `#version 300 es
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec2 a_uv;
uniform mat4 u_mvp;
out vec2 v_uv;
void main() {
  v_uv = a_uv;
  gl_Position = u_mvp * vec4(a_position, 1.0);
}`;

const PANEL_FS = `#version 300 es
precision mediump float;
in vec2 v_uv;
uniform sampler2D u_text;
out vec4 color;
void main() {
  color = texture(u_text, v_uv);
}`;

// The panel, screen units: above the screen cube ([-1, 1]^3), facing the viewer.
const PANEL = { left: -1.2, right: 1.2, bottom: 1.12, top: 1.72 };
const TEXTURE = [1024, 256];

// The lines the node made (touch4d/render/hud.py study_lines, with the controller's button names).
export function studyLines(study) {
  return study ? study.lines : [];
}

export class StudyPanel {
  constructor(gl) {
    this.gl = gl;
    this.program = program(gl, PANEL_VS, PANEL_FS, 'study panel');
    this.quad = new Vertices(gl, [[0, 3], [1, 2]]);
    const { left, right, bottom, top } = PANEL;
    this.quad.upload(new Float32Array([left, bottom, 0, 0, 1, right, bottom, 0, 1, 1,
                                       left, top, 0, 0, 0, right, top, 0, 1, 0]));
    this.canvas = document.createElement('canvas');
    [this.canvas.width, this.canvas.height] = TEXTURE;
    this.texture = gl.createTexture();
    this.text = '';
    this.lines = [];
  }

  // Draw the lines into the canvas and the texture when they changed.
  update(study) {
    const lines = studyLines(study);
    const text = lines.join('\n');
    if (text === this.text) return;
    this.text = text;
    this.lines = lines;
    const ctx = this.canvas.getContext('2d');
    const [w, h] = TEXTURE;
    ctx.clearRect(0, 0, w, h);
    if (!lines.length) return;
    ctx.fillStyle = 'rgba(0, 0, 0, 0.75)';
    ctx.fillRect(0, 0, w, h);
    ctx.fillStyle = '#e6e6eb';
    ctx.textAlign = 'center';
    ctx.textBaseline = 'middle';
    const step = h / (lines.length + 1);
    lines.forEach((line, k) => {
      ctx.font = `${k === 1 && lines.length > 1 ? 'bold ' : ''}${Math.round(step * 0.55)}px system-ui, sans-serif`;
      ctx.fillText(line, w / 2, step * (k + 1), w - 40);
    });
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, this.canvas);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  }

  draw(mvp) {
    if (!this.lines.length) return;
    const gl = this.gl;
    gl.useProgram(this.program.program);
    gl.uniformMatrix4fv(this.program.uniforms.u_mvp, false, mvp);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.uniform1i(this.program.uniforms.u_text, 0);
    this.quad.draw(gl.TRIANGLE_STRIP);
    gl.bindVertexArray(null);
  }
}

// The page's own answer buttons (#study), for a tap in the headset's browser or a click on a desktop.
export class StudyButtons {
  constructor(element, answer) {
    this.element = element;
    this.answer = answer;       // (index, option) => void
    this.key = '';
    this.finish = null;         // where a served study's page goes when every trial is done
  }

  update(study) {
    const key = study ? JSON.stringify([study.phase, study.index, study.options, study.message]) : '';
    if (key === this.key) return;
    this.key = key;
    this.element.replaceChildren();
    const finish = Boolean(study && study.phase === 'done' && this.finish);
    this.element.hidden = !finish && (!study || !studyLines(study).length);
    if (this.element.hidden) return;
    if (finish) {   // a served study: on to its end (a platform's completion page)
      const finish = document.createElement('a');
      finish.id = 'finish';
      finish.href = this.finish;
      finish.textContent = 'Finish';
      this.element.append(finish);
    }
    const lines = studyLines(study);
    const text = document.createElement('div');
    text.className = 'study-text';
    text.textContent = study.phase === 'stimulus' ? lines.slice(0, 2).join(' · ') : lines[0];
    this.element.append(text);
    const options = study.phase === 'stimulus' ? study.options : study.phase === 'break' ? [''] : [];
    for (const option of options) {
      const button = document.createElement('button');
      button.textContent = option || 'Go on';
      button.dataset.option = option;
      button.addEventListener('click', () => this.answer(study.index, option));
      this.element.append(button);
    }
  }
}

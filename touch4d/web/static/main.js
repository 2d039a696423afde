// touch4d's WebXR page: the 4D scene, the hand and its tactile field, in a headset (stereo, the
// screen placed in the room) or inline in a desktop browser (mouse orbit). In a headset it is also
// the tracker when the node says so: each XR frame first sends what is tracked, then draws.

import { Link } from './net.js';
import { InputReader } from './input.js';
import { Hud } from './hud.js';
import { SceneView } from './scene.js';
import { Orbit } from './orbit.js';
import { fromPose, multiply, perspective } from './mat.js';

const BACKGROUND = [0.04, 0.04, 0.06, 1];
const canvas = document.getElementById('view');
const statusLine = document.getElementById('status');
const enterButton = document.getElementById('enter-vr');
const gl = canvas.getContext('webgl2', { xrCompatible: true, antialias: true });

// What tests and benchmarks read (window.touch4d); nothing here steers the page.
const state = (window.touch4d = {
  connected: false, setup: null, frame: null, geometry: null, frames: 0, fps: 0, xrFrames: 0,
  session: null, sent: 0, input: null, leaving: false, error: null,
});

let hud = null, scene = null, orbit = null;
let screenModel = fromPose([0, 1.2, -0.45], [0, 0, 0, 1], 0.25);   // replaced by the setup frame

if (!gl) {
  statusLine.textContent = 'This browser has no WebGL2: touch4d cannot draw here.';
  state.error = 'no WebGL2';
} else {
  hud = new Hud(gl);
  scene = new SceneView(gl);
}

function place(header) {
  // screen units -> room metres: the screen cube [-1, 1]^3 is edge metres wide
  screenModel = fromPose(header.screen_center, header.screen_rotation, header.screen_edge / 2);
}

const link = new Link((message) => {
  const { header } = message;
  if (header.kind === 'setup') {
    state.setup = header;
    hud.configure(message);
    place(header);
    if (!orbit) orbit = new Orbit(canvas, header.camera);
  } else if (header.kind === 'calibration') {
    place(header);
  } else if (header.kind === 'geometry') {
    state.geometry = header.key;
    scene.setGeometry(message);
  } else if (header.kind === 'frame') {
    state.frame = header;
    scene.update(message);
    hud.update(message);
  }
}, (connected) => { state.connected = connected; });

// ---- drawing --------------------------------------------------------------------------------------

function drawWorld(projection, view, model, height) {
  const mvp = multiply(projection, multiply(view, model));
  const scale = Math.hypot(model[0], model[1], model[2]);   // room metres per screen unit
  scene.draw(mvp);
  hud.draw(mvp, (scale * projection[5] * height) / 2);
}

function beginFrame(framebuffer, width, height) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
  gl.viewport(0, 0, width, height);
  gl.clearColor(...BACKGROUND);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
}

// Frame rate over the last second, whichever loop runs.
let counted = 0, since = performance.now();
function countFrame(now) {
  state.frames++;
  counted++;
  if (now - since >= 1000) {
    state.fps = (1000 * counted) / (now - since);
    counted = 0;
    since = now;
    link.send({ type: 'stats', fps: Math.min(state.fps, 1000) });
    showStatus();
  }
}

function showStatus() {
  const f = state.frame;
  const touched = f ? 'touching' : '';
  const role = state.setup && state.setup.tracker ? 'tracker' : 'view';
  statusLine.textContent = state.connected
    ? `touch4d ${role} · ${state.fps.toFixed(0)} fps${f && f.hand_valid ? ' · hand tracked' : ''} ${touched ? '' : ''}`
    : 'touch4d: connecting to the node…';
}

function inlineLoop(now) {
  requestAnimationFrame(inlineLoop);
  if (state.session || !gl || !orbit) return;
  const width = (canvas.width = canvas.clientWidth * devicePixelRatio);
  const height = (canvas.height = canvas.clientHeight * devicePixelRatio);
  beginFrame(null, width, height);
  const projection = perspective(orbit.fov, width / height, 0.05, orbit.distance + 20);
  drawWorld(projection, orbit.view(), fromPose([0, 0, 0], [0, 0, 0, 1], 1), height);
  countFrame(now);
}
requestAnimationFrame(inlineLoop);

// ---- the headset ----------------------------------------------------------------------------------

// The hand is absent from now on (hidden page, lost session): the node publishes it invalid.
function handGone() {
  if (state.setup && state.setup.tracker) {
    link.send({ type: 'input', time: performance.timeOrigin + performance.now(), tracking: false, head: null, sources: [] });
  }
}

async function enterVR() {
  const session = await navigator.xr.requestSession('immersive-vr', {
    requiredFeatures: ['local-floor'], optionalFeatures: ['hand-tracking'],
  });
  await gl.makeXRCompatible();
  const layer = new XRWebGLLayer(session, gl);
  session.updateRenderState({ baseLayer: layer, depthNear: 0.05, depthFar: 50 });
  const space = await session.requestReferenceSpace('local-floor');
  const reader = new InputReader(session);
  state.session = session;
  link.send({ type: 'session', mode: 'immersive', active: true });
  session.addEventListener('visibilitychange', () => { if (session.visibilityState !== 'visible') handGone(); });
  session.addEventListener('end', () => {
    state.session = null;
    handGone();
    link.send({ type: 'session', mode: 'immersive', active: false });
    enterButton.hidden = false;
  });
  enterButton.hidden = true;

  const onFrame = (time, frame) => {
    session.requestAnimationFrame(onFrame);
    const viewer = frame.getViewerPose(space);
    // Input first: the pose leaves before this frame's drawing.
    if (state.setup && state.setup.tracker && session.visibilityState === 'visible' && !state.leaving) {
      state.input = reader.read(frame, space, session, viewer || null, time);
      link.send(state.input);
      state.sent++;
    }
    if (!viewer) return;
    const base = session.renderState.baseLayer;
    gl.bindFramebuffer(gl.FRAMEBUFFER, base.framebuffer);
    gl.clearColor(...BACKGROUND);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    for (const view of viewer.views) {
      const vp = base.getViewport(view);
      gl.viewport(vp.x, vp.y, vp.width, vp.height);
      drawWorld(view.projectionMatrix, view.transform.inverse.matrix, screenModel, vp.height);
    }
    state.xrFrames++;
    countFrame(performance.now());
  };
  session.requestAnimationFrame(onFrame);
  return session;
}

document.addEventListener('visibilitychange', () => { if (document.visibilityState !== 'visible') handGone(); });
// Leaving the page: the hand is gone now, and no frame that may still run sends it back.
window.addEventListener('pagehide', () => { handGone(); state.leaving = true; link.close(); });

if (navigator.xr && gl) {
  navigator.xr.isSessionSupported('immersive-vr').then((ok) => {
    enterButton.hidden = !ok;
  }).catch(() => {});
  enterButton.addEventListener('click', () => {
    enterVR().catch((error) => { state.error = String(error); statusLine.textContent = `WebXR: ${error}`; });
  });
}
showStatus();

// touch4d's WebXR page: the 4D scene, the hand and its tactile field, in a headset (stereo, the
// screen placed in the room) or inline in a desktop browser (mouse orbit). In a headset it is also
// the tracker when the node says so: each XR frame first sends what is tracked, then draws.

import { Link, forgetToken } from './net.js';
import { InputReader } from './input.js';
import { Hud } from './hud.js';
import { SceneRenderer, UNITS } from './scene.js';
import { SliceRenderer } from './slice.js';
import { Orbit } from './orbit.js';
import { StudyButtons, StudyPanel } from './study.js';
import { Haptics } from './haptics.js';
import { fromPose, multiply, perspective } from './mat.js';
import { program } from './gl.js';
import { PageTouch, handFromGrip, level } from './touch.js';
import { Batch, buttonActions } from './batch.js';
import { Pacing } from './pacing.js';

const BACKGROUND = [0.04, 0.04, 0.06, 1];
const canvas = document.getElementById('view');
const statusLine = document.getElementById('status');
const enterButton = document.getElementById('enter-vr');
const gl = canvas.getContext('webgl2', { xrCompatible: true, antialias: true });

// What tests and benchmarks read (window.touch4d); nothing here steers the page.
const state = (window.touch4d = {
  connected: false, setup: null, frame: null, geometry: null, frames: 0, fps: 0, xrFrames: 0,
  session: null, sent: 0, input: null, leaving: false, error: null, gpu: null, motorsOn: 0,
  study: null, drawObjects: true, answers: 0, panel: [], view: 'projection', haptics: null, touch: null,
  touchCost: { frames: 0, ms: 0 },   // the page's own touch: frames it ran in, and its time on this thread
  pacing: null,                      // in a headset: the layer's scale and foveation, lowered while frames run late
});

// A page built on this one (static/lesson.js) hears every frame first and may send; nothing else.
export const hooks = { frames: [], send: (message) => link.send(message) };

// made when the node's setup frame (with the shaders) arrives
let hud = null, scene = null, orbit = null, panel = null, slice = null;
let screenModel = null;   // screen units -> the room, from the setup frame
let calibration = null;   // the screen's placement and the hand on the grip (setup, calibration frames)
// The node's `touch: page`: the page computes the glove hand's touch itself (touch.js)
let touch = null;
let touchLevel = 0;       // what the controller plays now from the page's own touch
let played = null;        // what it played since the last input went out: {time, intensity}
// A served page (touch4d.web.served): its frames go out in batches, its buttons' answers at once (batch.js)
let batch = null;
let buttonsHeld = new Set();
// The study's gate comes with the node's frames: none for this long (the setup's gate_stale_s), touch 0.
const gateStaleMs = () => (state.setup && state.setup.gate_stale_s ? 1000 * state.setup.gate_stale_s : 250);

if (!gl) {
  statusLine.textContent = 'This browser has no WebGL2: touch4d cannot draw here.';
  state.error = 'no WebGL2';
} else {
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  state.gpu = info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
}

function place(header) {
  // screen units -> room metres: the screen cube [-1, 1]^3 is edge metres wide
  screenModel = fromPose(header.screen_center, header.screen_rotation, header.screen_edge / 2);
  calibration = header;
}

// The page's own answer buttons; the controller's go with the input messages.
const buttons = new StudyButtons(document.getElementById('study'), (index, option) => {
  link.send({ type: 'response', index, option, time: performance.timeOrigin + performance.now() });
  state.answers++;
});

forgetToken();
// The controller (or a desktop gamepad) as the glove: what it plays, and what the node is told.
const haptics = (state.haptics = new Haptics((output) => { link.send({ type: 'haptics', output }); showStatus(); }));

const link = new Link((message) => {
  for (const hook of hooks.frames) hook(message);
  const { header } = message;
  if (header.kind === 'setup') {
    state.setup = header;
    place(header);
    if (!orbit) orbit = new Orbit(canvas, header.camera);
    if (gl && !scene) {
      try {
        // the GPU renderer's shaders, compiled here as GLSL ES 3.00
        scene = new SceneRenderer(gl, header.shaders, header.style, message.arrays.cell_palette);
        hud = new Hud(gl, header.shaders);
        panel = new StudyPanel(gl);
        slice = new SliceRenderer(gl, header.shaders);
        if (header.tracker && header.touch === 'page') {
          touch = new PageTouch(gl, program(gl, header.shaders['fullscreen.vert'], header.shaders['tactile.frag'],
                                            'fullscreen.vert + tactile.frag'), message, UNITS);
        }
        if (header.batch_s > 0) batch = new Batch(1000 * header.batch_s, header.motor_names.length);
        if (header.batch_s > 0) buttons.finish = '/done';   // a served study's page
      } catch (error) {
        state.error = String(error);
        statusLine.textContent = `touch4d cannot draw here: ${error.message}`;
      }
    }
    if (hud) hud.configure(message);
  } else if (header.kind === 'calibration') {
    place(header);
  } else if (header.kind === 'geometry') {
    state.geometry = header.key;
    if (scene) scene.setGeometry(message);
  } else if (header.kind === 'driver') {
    state.otherDriver = !header.driver;   // another page drives the hand: say so
    showStatus();
  } else if (header.kind === 'frame') {
    state.frame = header;
    haptics.frame(header);
    const threshold = state.setup ? state.setup.touch_threshold : 0;   // the glove file's, sent once in setup
    state.motorsOn = message.arrays.intensity.filter((v) => v > threshold).length;
    if (scene) scene.setFrame(message);
    if (scene && header.scene_style) scene.style = header.scene_style;   // the both view's is fainter
    if (slice) {
      slice.update(message);
      state.view = slice.view;
    }
    if (hud && !touch) hud.update(message);   // the page's own touch draws its own hand (pageTouchLevel)
    // a running study: its question, and whether its condition lets objects be drawn
    state.study = header.study || null;
    state.drawObjects = header.draw_objects !== false;
    if (panel) {
      panel.update(state.study || (slice && slice.panel()));   // no study: the slice's c, in the headset too
      state.panel = panel.lines;
    }
    buttons.update(state.study);
  }
}, (connected) => {
  state.connected = connected;
  // a new connection's server knows nothing of this page yet: what it can vibrate is told again
  if (connected && haptics.output) haptics.tell(haptics.output, true);
});

// ---- drawing --------------------------------------------------------------------------------------

// One view of the world: the slice's solid (slice and both views), the scene's projection (projection
// and both views) tested against the solid's depth, then the flat layers over it, alpha-blended
// without a depth test (as every touch4d renderer draws a frame).
function drawWorld(framebuffer, size, viewport, projection, view, model) {
  if (!scene || !hud) return;
  const mvp = multiply(projection, multiply(view, model));
  const scale = Math.hypot(model[0], model[1], model[2]);   // room metres per screen unit
  if (state.drawObjects && slice) slice.draw(framebuffer, viewport, mvp);
  if (state.drawObjects && (!slice || slice.projection)) {
    scene.draw(framebuffer, size, viewport, mvp, slice && ((fbo) => slice.draw(fbo, viewport, mvp, true)));
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
  gl.viewport(...viewport);
  gl.disable(gl.DEPTH_TEST);
  gl.enable(gl.BLEND);
  gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
  hud.draw(mvp, (scale * projection[5] * viewport[3]) / 2, viewport);
  if (panel) panel.draw(mvp);
}

function clear(framebuffer, width, height) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
  gl.viewport(0, 0, width, height);
  gl.clearColor(...BACKGROUND);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
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
    const paced = state.session && state.pacing ? { scale: state.pacing.scale, foveation: state.pacing.foveation } : {};
    link.send({ type: 'stats', fps: Math.min(state.fps, 1000), ...paced });
    showStatus();
  }
}

function showStatus() {
  if (state.error) return;
  const f = state.frame;
  const role = state.setup && state.setup.tracker ? 'tracker' : 'view';
  const fingers = f && f.hand_source === 'joints' ? ' (fingers tracked)' : '';
  const hand = state.otherDriver ? ' · another page drives the hand'
    : f && f.hand_valid ? ` · hand in${fingers} · ${state.motorsOn} motors on` : ' · no hand';
  const cut = slice && slice.label ? ` · ${slice.label}` : '';
  const felt = haptics.output === 'none' ? ' · no vibration here: touch cannot be felt' : '';
  statusLine.textContent = state.connected ? `touch4d ${role} · ${state.fps.toFixed(0)} fps${hand}${cut}${felt}`
                                           : 'touch4d: connecting to the node…';
}

function inlineLoop(now) {
  requestAnimationFrame(inlineLoop);
  if (state.session || !gl || !orbit) return;
  const width = (canvas.width = canvas.clientWidth * devicePixelRatio);
  const height = (canvas.height = canvas.clientHeight * devicePixelRatio);
  clear(null, width, height);
  const projection = perspective(orbit.fov, width / height, 0.05, orbit.distance + 20);
  drawWorld(null, [width, height], [0, 0, width, height], projection, orbit.view(), fromPose([0, 0, 0], [0, 0, 0, 1], 1));
  if (document.visibilityState === 'visible') haptics.desktopFrame(now);
  countFrame(now);
}
requestAnimationFrame(inlineLoop);

// ---- the headset ----------------------------------------------------------------------------------

// Whether the page's own touch may be felt: the study's condition allows it, the node is heard.
function touchAllowed(now) {
  const f = state.frame;
  return Boolean(f) && f.touch_on !== false && now - haptics.at <= gateStaleMs();
}

// The page's own touch, each XR frame before the input goes out: the last pass's result if it has
// landed (played now), then this frame's pass for the grip just read.
function pageTouch(input, now) {
  const value = pageTouchLevel(input, now);
  state.touchCost.frames++;
  state.touchCost.ms += performance.now() - now;
  return value;
}

function pageTouchLevel(input, now) {
  const result = touch.poll();
  const allowed = touchAllowed(now);
  if (result) {
    const intensity = allowed ? Array.from(result.V) : new Array(result.V.length).fill(0);
    touchLevel = level(intensity);
    played = { time: result.time, intensity };
    state.touch = { time: result.time, grip: result.grip, hand: result.hand, l: Array.from(result.l),
                    V: Array.from(result.V), played: intensity, level: touchLevel, passes: touch.passes,
                    skipped: touch.skipped };
    // the hand and its samples drawn where this frame's pass put them, not where a frame from the node says
    if (hud) {
      hud.update({ header: { hand_valid: true },
                   arrays: { hand: [...result.hand.position, ...result.hand.orientation], h: result.h,
                             touched: Array.from(result.l, (v) => (v >= 0 ? 1 : 0)) } });
    }
  }
  if (!allowed || !scene || !scene.geometry || !scene.geometry.bodies) touchLevel = 0;
  if (played) {
    input.played = played;
    played = null;
  }
  const hand = input.sources.find((s) => s.handedness === state.setup.hand);
  if (hand && hand.grip && calibration) {
    touch.submit(scene, hand.grip, calibration, input.time, now);
  } else {
    touch.drop();
    touchLevel = 0;
    if (hud) hud.update(null);
  }
  return touchLevel;
}

// The hand is absent from now on (hidden page, lost session): the node publishes it invalid.
function handGone() {
  haptics.stop();
  if (touch) touch.drop();
  touchLevel = 0;
  const time = performance.timeOrigin + performance.now();
  if (batch) {   // a served page: its last frames, the hand gone, go now
    batch.pose(time, null, performance.now());
    link.send(batch.take());
  } else if (state.setup && state.setup.tracker) {
    link.send({ type: 'input', time, tracking: false, head: null, sources: [] });
  }
}

// A served page's frame: its pose and what it played into the batch (sent every batch_s); an
// answer or a re-centre from the controller's buttons at once.
function served(input, now) {
  const glove = input.sources.find((s) => s.handedness === state.setup.hand);
  const hand = input.tracking && glove && glove.grip && calibration ? handFromGrip(glove.grip, calibration) : null;
  batch.pose(input.time, hand, now);
  if (input.played) batch.touch(input.played.time, input.played.intensity, now);
  const acts = buttonActions(input.sources, buttonsHeld, state.study, state.setup);
  buttonsHeld = acts.held;
  if (acts.answer) {
    link.send({ type: 'response', index: acts.answer.index, option: acts.answer.option, time: input.time });
    state.answers++;
  }
  if (acts.recenter && input.head) link.send({ type: 'recenter', head: input.head });
  if (acts.buttons) link.send({ type: 'buttons', held: acts.buttons });
  if (batch.due(now)) link.send(batch.take());
}

// The session's layer at `scale` (framebufferScaleFactor) and `foveation` (where the browser has
// fixed foveation: the Quest's; elsewhere the property is absent or null).
function makeLayer(session, { scale, foveation }) {
  const layer = new XRWebGLLayer(session, gl, { framebufferScaleFactor: scale });
  if ('fixedFoveation' in layer && layer.fixedFoveation !== null) layer.fixedFoveation = foveation;
  return layer;
}

async function enterVR() {
  const session = await navigator.xr.requestSession('immersive-vr', {
    requiredFeatures: ['local-floor'], optionalFeatures: ['hand-tracking'],
  });
  await gl.makeXRCompatible();
  // the node's framebuffer_scale and foveation, then lowered while frames run late (pacing.js)
  const setup = state.setup || {};
  const pacing = new Pacing(setup.framebuffer_scale ?? 1, setup.foveation ?? 0, setup.pacing !== false);
  session.updateRenderState({ baseLayer: makeLayer(session, pacing), depthNear: 0.05, depthFar: 50 });
  state.pacing = pacing.state;   // updated in place each frame
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
    const step = pacing.frame(time, session.frameRate);
    if (step) session.updateRenderState({ baseLayer: makeLayer(session, step) });   // from the next frame on
    const viewer = frame.getViewerPose(space);
    // Input first: the pose leaves before this frame's drawing.
    if (state.setup && state.setup.tracker && session.visibilityState === 'visible' && !state.leaving) {
      state.input = reader.read(frame, space, session, viewer || null, time);
      const now = performance.now();
      const own = touch ? pageTouch(state.input, now) : null;
      if (batch) served(state.input, now);
      else link.send(state.input);
      state.sent++;
      // the controller plays while this page drives the hand and both it and the head are tracked
      const hand = state.input.sources.find((s) => s.handedness === state.setup.hand);
      if (state.otherDriver) haptics.stop();
      else haptics.xrFrame(session, state.setup.hand, Boolean(viewer && hand && (hand.grip || hand.joints)),
                           now, own);
    }
    if (!viewer) return;
    const base = session.renderState.baseLayer;
    const size = [base.framebufferWidth, base.framebufferHeight];
    clear(base.framebuffer, size[0], size[1]);
    for (const view of viewer.views) {
      const vp = base.getViewport(view);
      drawWorld(base.framebuffer, size, [vp.x, vp.y, vp.width, vp.height], view.projectionMatrix,
                view.transform.inverse.matrix, screenModel);
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

// The welcome page of a served study: the link's token out of the address bar and the history (the
// cookie carries on); then, before consent, the device check: what this browser can vibrate, its frame
// rate, the round trip to the server and the clocks' offset, told to the server, which answers what the
// participant reads, whether Join stays open, and (the study file's device_check) a vibration test to run:
// vibrations at random moments and catch trials without one, each answered felt or not felt.
"use strict";
history.replaceState(null, "", "/");

const $ = (id) => document.getElementById(id);
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const PULSE_MS = 300;

// Frames counted for `ms` by a requestAnimationFrame (a window's, or an XR session's): frames per second.
function frameRate(request, ms) {
  return new Promise((resolve) => {
    let first = null, frames = 0;
    const step = (t) => {
      if (first === null) first = t;
      frames++;
      if (t - first >= ms) resolve(Math.round((1000 * (frames - 1)) / (t - first)));
      else request(step);
    };
    request(step);
  });
}

// The round trip to the server and its clock's offset from this one (the fastest of three).
async function clock() {
  let best = null;
  for (let i = 0; i < 3; i++) {
    const sent = Date.now();
    const response = await fetch("/clock", { cache: "no-store", credentials: "same-origin" });
    const received = Date.now();
    if (!response.ok) return {};
    const server = (await response.json()).time_ms;
    if (best === null || received - sent < best.round_trip_ms) {
      best = { round_trip_ms: received - sent, clock_offset_ms: server - (sent + received) / 2 };
    }
  }
  return best || {};
}

// An immersive session's controllers carry the actuator (`pulse`); a desktop gamepad rumbles with
// `playEffect` (it shows only after one of its buttons is pressed).
async function capabilities() {
  let immersive = false;
  try {
    immersive = Boolean(navigator.xr) && await navigator.xr.isSessionSupported("immersive-vr");
  } catch (err) {
    immersive = false;   // no WebXR here (or not allowed): not a headset
  }
  const rumble = Boolean(gamepad());
  const fps = await frameRate((f) => requestAnimationFrame(f), 500);
  const haptics = immersive ? "xr-pulse" : rumble ? "gamepad-rumble" : "none";
  return { immersive, rumble, fps, haptics, ...await clock() };
}

function gamepad() {
  const pads = navigator.getGamepads ? Array.from(navigator.getGamepads()).filter(Boolean) : [];
  return pads.find((pad) => pad.vibrationActuator && typeof pad.vibrationActuator.playEffect === "function");
}

async function tell(report) {
  const response = await fetch("/device", {
    method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(report),
  });
  if (!response.ok) return null;
  const said = await response.json();
  const note = $("vibration");
  note.textContent = said.text;
  note.hidden = !said.text;
  $("join").disabled = said.refused;
  document.body.dataset.vibration = said.vibration;   // what was found: headset, gamepad or none
  if (said.passed === true || said.passed === false) document.body.dataset.check = said.passed ? "passed" : "failed";
  if (said.passed === false) {
    $("check").hidden = true;
    $("join").hidden = true;
    if (said.leave) {
      const back = document.createElement("a");
      back.href = said.leave;
      back.textContent = "Back to where you came from";
      note.append(" ", back);
      setTimeout(() => location.assign(said.leave), 5000);
    }
  }
  return said;
}

// The actuator the test plays: the right (else any) controller of a short immersive session, or the gamepad.
async function actuator(immersive) {
  if (!immersive) {
    const pad = gamepad();
    return pad && { pulse: () => pad.vibrationActuator.playEffect("dual-rumble", {
      duration: PULSE_MS, strongMagnitude: 1, weakMagnitude: 1 }), end: () => {} };
  }
  const session = await navigator.xr.requestSession("immersive-vr");
  const gl = document.createElement("canvas").getContext("webgl2", { xrCompatible: true });
  const layer = new XRWebGLLayer(session, gl);
  session.updateRenderState({ baseLayer: layer });
  const fps = await frameRate((f) => session.requestAnimationFrame((t) => f(t)), 1000);
  let open = true;
  session.addEventListener("end", () => { open = false; });
  const draw = () => {              // frames go on (a grey room) while the participant answers
    if (!open) return;
    gl.bindFramebuffer(gl.FRAMEBUFFER, layer.framebuffer);
    gl.clearColor(0.2, 0.2, 0.2, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    session.requestAnimationFrame(draw);
  };
  session.requestAnimationFrame(draw);
  const sources = Array.from(session.inputSources);
  const source = sources.find((s) => s.handedness === "right" && s.gamepad && s.gamepad.hapticActuators
    && s.gamepad.hapticActuators.length) || sources.find((s) => s.gamepad && s.gamepad.hapticActuators
    && s.gamepad.hapticActuators.length);
  if (!source) {
    await session.end();
    return null;
  }
  return { session, fps, pulse: () => source.gamepad.hapticActuators[0].pulse(1.0, PULSE_MS),
           end: () => session.end().catch(() => {}) };
}

// One answer: a page button, or on a headset the trigger (felt) or the grip (not felt).
function answer(session) {
  $("check-answer").hidden = false;
  return new Promise((resolve) => {
    const done = (felt) => {
      $("felt").onclick = $("not-felt").onclick = null;
      if (session) session.onselect = session.onsqueeze = null;
      $("check-answer").hidden = true;
      resolve(felt);
    };
    $("felt").onclick = () => done(true);
    $("not-felt").onclick = () => done(false);
    if (session) {
      session.onselect = () => done(true);
      session.onsqueeze = () => done(false);
    }
  });
}

async function vibrationTest(first, check) {
  $("check-start").hidden = true;
  const device = await actuator(first.immersive);
  if (!device) return tell({ ...first, haptics: "none", immersive: false, rumble: false });
  const order = [...Array(check.trials).fill(true), ...Array(check.catch).fill(false)];
  for (let i = order.length - 1; i > 0; i--) {           // shuffled: catch trials anywhere
    const j = Math.floor(Math.random() * (i + 1));
    [order[i], order[j]] = [order[j], order[i]];
  }
  let hits = 0, falseAlarms = 0;
  for (const [k, vibrate] of order.entries()) {
    $("check-step").textContent = `${k + 1} of ${order.length}: wait…`;
    await sleep(500 + Math.random() * 1500);              // a random moment: the answer cannot be timed
    if (vibrate) device.pulse();
    await sleep(PULSE_MS + 200);
    $("check-step").textContent = `${k + 1} of ${order.length}: did you feel a vibration?`;
    const felt = await answer(device.session);
    if (felt && vibrate) hits++;
    if (felt && !vibrate) falseAlarms++;
  }
  device.end();
  $("check-step").textContent = "Thank you.";
  return tell({ ...first, fps: device.fps || first.fps, trials: check.trials, catch: check.catch, hits,
                false_alarms: falseAlarms });
}

async function check() {
  const first = await capabilities();
  const said = await tell(first);
  if (said && said.check) {
    $("check").hidden = false;
    $("check-start").onclick = () => vibrationTest(first, said.check);
  }
}

check();
window.addEventListener("gamepadconnected", check);

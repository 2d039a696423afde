// The page as the glove's output: the node's frames carry `haptic`, the intensity 0..1 the held
// controller plays (touch4d/web/haptics.py: the strongest motor of tactile/motors, 0 while the
// study holds the motors off, the hand is invalid or tactile/motors is stale). In a headset the
// glove hand's controller gets `pulse(intensity, ms)` every XR frame; in a desktop browser a gamepad
// gets `playEffect('dual-rumble', ...)`. Fail safe here too: hidden, closed, session ended, tracking
// lost or the node's frames stale -> one pulse of 0 at once, and nothing more.

export const STALE_MS = 80;         // frames older than this: the node is gone or behind (0 within 100 ms)
const PULSE_FRAMES = 1.5;           // each pulse lasts this many frame intervals: continuous, self-ending
const MIN_MS = 10, MAX_MS = 50;     // a pulse's duration bounds (a 120 Hz headset .. a stalled frame)

// The glove hand's controller's actuator with `pulse`, or null (no controller, no actuator).
function controllerActuator(session, hand) {
  for (const source of session.inputSources) {
    if (source.handedness !== hand || !source.gamepad) continue;
    const actuator = (source.gamepad.hapticActuators || [])[0];
    if (actuator && typeof actuator.pulse === 'function') return actuator;
  }
  return null;
}

// A desktop gamepad that can play 'dual-rumble', or null.
function rumbleGamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const pad of pads) {
    if (pad && pad.vibrationActuator && typeof pad.vibrationActuator.playEffect === 'function') return pad;
  }
  return null;
}

export class Haptics {
  // report(output) tells the node what this page can vibrate: 'pulse', 'dual-rumble' or 'none'.
  constructor(report) {
    this.report = report;
    this.output = '';        // as last reported
    this.level = 0;          // the node's latest intensity
    this.at = -Infinity;     // when it arrived (performance.now())
    this.playing = 0;        // what the actuator was last told
    this.lastFrame = null;   // the previous frame's time, for the pulse's duration
    this.actuator = null;    // the one last played (to stop it)
    this.pulses = 0;
  }

  // A node frame arrived.
  frame(header) {
    this.level = typeof header.haptic === 'number' ? header.haptic : 0;
    this.at = performance.now();
  }

  // Say what this page can vibrate, when it changes.
  // `again`: told even if unchanged (a reconnected page's new server has not heard it)
  tell(output, again = false) {
    if (output === this.output && !again) return;
    this.output = output;
    this.report(output);
  }

  // The intensity to play now: the node's, while it is fresh.
  target(now) {
    return now - this.at <= STALE_MS ? Math.min(Math.max(this.level, 0), 1) : 0;
  }

  duration(now) {
    const interval = this.lastFrame === null ? 1000 / 72 : now - this.lastFrame;
    this.lastFrame = now;
    return Math.min(Math.max(PULSE_FRAMES * interval, MIN_MS), MAX_MS);
  }

  // One XR frame while this page drives the hand; `tracked`: the headset and the controller have poses.
  // `own`: the intensity the page computed itself (touch: page, touch.js), else the node's is played.
  xrFrame(session, hand, tracked, now, own = null) {
    const actuator = controllerActuator(session, hand);
    this.tell(actuator ? 'pulse' : 'none');
    const ms = this.duration(now);
    if (!actuator) {
      if (this.actuator) this.stop();     // the controller went away (lost, disconnected): 0 on it now
      return;
    }
    if (this.actuator && this.actuator !== actuator) this.stop();
    const value = !tracked ? 0 : own === null ? this.target(now) : Math.min(Math.max(own, 0), 1);
    if (value > 0 || this.playing > 0) {
      this.actuator = actuator;
      this.play(value, ms);
    }
  }

  // One desktop frame (no XR session): a gamepad rumbles while the node's intensity is above 0.
  desktopFrame(now) {
    const pad = rumbleGamepad();
    this.tell(pad ? 'dual-rumble' : 'none');
    const ms = this.duration(now);
    if (!pad) return;
    if (this.actuator && this.actuator !== pad.vibrationActuator) this.stop();
    const value = this.target(now);
    if (value > 0 || this.playing > 0) {
      this.actuator = pad.vibrationActuator;
      this.play(value, ms);
    }
  }

  play(value, ms) {
    const actuator = this.actuator;
    this.playing = value;
    this.pulses++;
    try {
      const done = typeof actuator.pulse === 'function' ? actuator.pulse(value, ms)
        : actuator.playEffect('dual-rumble', { startDelay: 0, duration: ms, strongMagnitude: value, weakMagnitude: value });
      if (done && typeof done.catch === 'function') done.catch(() => {});   // a refused effect throws nothing
    } catch (error) {
      this.actuator = null;
      this.playing = 0;
    }
  }

  // Now 0 (hidden, closed, session ended): the vibration still playing is replaced by none.
  stop() {
    if (this.actuator && this.playing > 0) this.play(0, MIN_MS);
    this.actuator = null;
    this.playing = 0;
    this.lastFrame = null;
  }
}

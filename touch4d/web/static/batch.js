// A served page (the setup frame's `batch_s` > 0: touch4d.web.served): its touch is its own, so the
// server needs its frames only for the record. Each frame's pose and what it played are collected
// here and sent as one "batch" message every batch_s (touch4d.web.protocol); the controller's
// answer and re-centre buttons are read here too and go out at once. No DOM, no WebGL: run in
// node.js by tests/test_web_batch.py.

export const MAX_BATCH = 64;   // frames in one batch at most (touch4d.web.protocol.MAX_BATCH)

export class Batch {
  // periodMs: how often a batch goes out; motors: V per touch row.
  constructor(periodMs, motors) {
    this.periodMs = periodMs;
    this.motors = motors;
    this.started = null;   // performance.now() of the batch's first frame
    this.clear();
  }

  clear() {
    this.poses = { time: [], valid: [], hand: [] };
    this.touches = { time: [], intensity: [] };
    this.started = null;
  }

  get size() { return this.poses.time.length + this.touches.time.length; }

  // One frame: when it read the poses (ms, the page's clock), and the glove hand on the screen
  // ({position, orientation}: touch.js's handFromGrip) or null when it was not tracked.
  pose(time, hand, now) {
    if (this.started === null) this.started = now;
    this.poses.time.push(time);
    this.poses.valid.push(Boolean(hand));
    if (hand) this.poses.hand.push(...hand.position, ...hand.orientation);
    else this.poses.hand.push(0, 0, 0, 0, 0, 0, 1);
  }

  // What was played for the pose read at `time`: one V per motor.
  touch(time, intensity, now) {
    if (this.started === null) this.started = now;
    this.touches.time.push(time);
    for (let m = 0; m < this.motors; m++) this.touches.intensity.push(intensity[m] || 0);
  }

  // Whether the batch should go now: its period passed since its first frame, or it is full.
  due(now) {
    if (this.started === null) return false;
    return now - this.started >= this.periodMs || this.poses.time.length >= MAX_BATCH
      || this.touches.time.length >= MAX_BATCH;
  }

  // The message, and a new empty batch.
  take() {
    const message = { type: 'batch', poses: this.poses, touches: this.touches };
    this.clear();
    return message;
  }
}

// The controller's buttons newly pressed this frame -> what they ask, as the node's bridge reads
// them (touch4d.web.bridge: _answer_buttons and the re-centre button): during a trial's stimulus the
// k-th answer button answers its k-th option; during a break any of them goes on (option ""); the
// re-centre button re-centres unless it just answered. Returns {held, answer: {index, option} | null,
// recenter: bool, buttons: [name] | null (the glove hand's held buttons, when they changed: the
// scene's, e.g. the slice's c)}; `held` is what to pass as `before` next frame.
export function buttonActions(sources, before, study, setup) {
  const answerButtons = setup.answer_buttons || [];
  const held = new Set();
  for (const s of sources) for (const b of s.buttons || []) if (answerButtons.includes(b)) held.add(b);
  const pressed = [...held].filter((b) => !before.has(b));
  const control = sources.find((s) => s.handedness === setup.hand);
  const recentre = Boolean(control && (control.buttons || []).includes(setup.recenter_button));
  let answer = null;
  const used = new Set();
  if (study && pressed.length && (study.phase === 'stimulus' || study.phase === 'break')) {
    if (study.phase === 'break') {
      answer = { index: study.index, option: '' };
      pressed.forEach((b) => used.add(b));
    } else {
      for (let k = 0; k < Math.min(study.options.length, answerButtons.length); k++) {
        if (pressed.includes(answerButtons[k])) {
          answer = { index: study.index, option: study.options[k] };
          pressed.forEach((b) => used.add(b));
          break;
        }
      }
    }
  }
  const recenter = recentre && !before.has(`recenter:${setup.recenter_button}`) && !used.has(setup.recenter_button);
  if (recentre) held.add(`recenter:${setup.recenter_button}`);
  const own = control ? [...new Set(control.buttons || [])].sort() : [];
  own.forEach((b) => held.add(`scene:${b}`));
  const changed = own.length !== [...before].filter((b) => b.startsWith('scene:')).length
    || own.some((b) => !before.has(`scene:${b}`));
  return { held, answer, recenter, buttons: changed ? own : null };
}

// Holding the headset's frame rate: from each XR frame's time, when to draw fewer pixels (a lower
// framebufferScaleFactor) and fewer at the edges (a higher fixed foveation), and when to try more
// again. Pure (no DOM, no WebXR): main.js applies its steps, tests run it in node.js.
//
// Down: the median frame interval over the last second (frames since the last change only) above
// `late` x the display's nominal interval -> one step down the ladder. Up: on time (median within
// `onTime` x nominal) for `upMs` -> one step up. A step up found late at its first decision failed:
// the wait for the next doubles (up to `maxUpMs`), so a level the device cannot hold is tried less
// and less often; a step up that holds brings the wait back to `upMs`.

export const NOMINAL_HZ = 72;    // a display that does not say its rate (session.frameRate): the Quest's lowest

export const DEFAULTS = Object.freeze({
  windowMs: 1000,      // the frames a decision looks at, and the settling time after a change
  late: 1.1,           // median interval above this x nominal: late
  onTime: 1.05,        // at most this x nominal: on time (between the two: neither, nothing changes)
  scaleStep: 0.8,      // each step down multiplies the scale by this ...
  minScale: 0.5,       // ... down to this (or the node's own scale, if lower)
  foveationStep: 0.25, // ... and raises the foveation by this, up to 1
  upMs: 5000,          // on time this long: one step back up
  maxUpMs: 120000,     // the longest wait for a step up, after repeated failed ones
  gapMs: 250,          // a longer interval (a pause, a hidden session) starts the measurement over
});

// The levels from the node's setting (level 0) down to the lowest: [{scale, foveation}].
export function ladder(scale, foveation, options = DEFAULTS) {
  const o = { ...DEFAULTS, ...options };
  const floor = Math.min(o.minScale, scale);
  const levels = [{ scale, foveation }];
  for (;;) {
    const last = levels[levels.length - 1];
    const next = { scale: Math.max(floor, Math.round(last.scale * o.scaleStep * 1000) / 1000),
                   foveation: Math.min(1, Math.round((last.foveation + o.foveationStep) * 1000) / 1000) };
    if (next.scale === last.scale && next.foveation === last.foveation) return levels;
    levels.push(next);
  }
}

// The median of a Float64Array, sorted in place (no allocation in the frame loop).
export function median(values) {
  values.sort();
  const mid = values.length >> 1;
  return values.length % 2 ? values[mid] : (values[mid - 1] + values[mid]) / 2;
}

export class Pacing {
  // scale, foveation: the node's setting; adaptive false: it only measures
  constructor(scale = 1, foveation = 0, adaptive = true, options = {}) {
    this.o = { ...DEFAULTS, ...options };
    this.levels = ladder(scale, foveation, this.o);
    this.adaptive = adaptive;
    this.level = 0;
    this.lowered = 0;            // steps down so far
    this.raised = 0;             // steps up so far
    this.fps = 0;                // 1000 / the last decision's median interval
    this.nominal = NOMINAL_HZ;
    this.upMs = this.o.upMs;     // the wait for the next step up (doubles after a failed one)
    this.times = [];             // frame times since the last change, within the last windowMs
    this.since = null;           // the first frame time at the current level (or after a gap)
    this.onTimeSince = null;     // the first on-time decision of the current run
    this.trying = null;          // the time of a step up not yet found to hold
    this.scratch = new Float64Array(256);   // the intervals, reused (grown for a faster display)
    this.state = {};             // what tests and the page show (window.touch4d.pacing), updated in place
    this.show();
  }

  get scale() { return this.levels[this.level].scale; }
  get foveation() { return this.levels[this.level].foveation; }

  show() {
    const s = this.state;
    s.scale = this.scale; s.foveation = this.foveation; s.fps = this.fps; s.nominal = this.nominal;
    s.level = this.level; s.lowered = this.lowered; s.raised = this.raised; s.adaptive = this.adaptive;
  }

  // One XR frame at `time` (ms); `nominalHz` the display's rate where it says it. Returns the new
  // {scale, foveation} when the level changes, else null.
  frame(time, nominalHz) {
    this.nominal = Number.isFinite(nominalHz) && nominalHz > 0 ? nominalHz : NOMINAL_HZ;
    if (!Number.isFinite(time)) return null;
    const step = this.decide(time);
    this.show();
    return step;
  }

  decide(time) {
    const last = this.times.length ? this.times[this.times.length - 1] : null;
    if (last === null || time <= last || time - last > this.o.gapMs) this.restart(time);
    this.times.push(time);
    while (time - this.times[0] > this.o.windowMs) this.times.shift();
    if (time - this.since < this.o.windowMs || this.times.length < 3) return null;
    const n = this.times.length - 1;
    if (this.scratch.length < n) this.scratch = new Float64Array(2 * n);
    for (let i = 0; i < n; i++) this.scratch[i] = this.times[i + 1] - this.times[i];
    const interval = median(this.scratch.subarray(0, n));
    this.fps = 1000 / interval;
    const period = 1000 / this.nominal;
    if (interval > this.o.late * period) return this.lower(time);
    if (interval > this.o.onTime * period) {
      this.onTimeSince = null;
      return null;
    }
    if (this.trying !== null && time - this.trying > 2 * this.o.windowMs) {   // the step up holds
      this.trying = null;
      this.upMs = this.o.upMs;
    }
    if (this.onTimeSince === null) this.onTimeSince = time;
    return time - this.onTimeSince >= this.upMs ? this.raise(time) : null;
  }

  restart(time) {
    this.times = [];
    this.since = time;
    this.onTimeSince = null;
  }

  lower(time) {
    this.onTimeSince = null;
    if (!this.adaptive || this.level === this.levels.length - 1) return null;
    if (this.trying !== null && time - this.trying <= 2 * this.o.windowMs) {   // the step up failed
      this.upMs = Math.min(this.o.maxUpMs, 2 * this.upMs);
    }
    this.trying = null;
    this.level++;
    this.lowered++;
    this.restart(time);
    return { scale: this.scale, foveation: this.foveation };
  }

  raise(time) {
    if (!this.adaptive || this.level === 0) return null;
    this.level--;
    this.raised++;
    this.trying = time;
    this.restart(time);
    return { scale: this.scale, foveation: this.foveation };
  }
}

// What the headset tracks, read once per XR frame and sent as it is (local-floor space, metres):
// every controller's grip pose, trigger and buttons, every tracked hand's 25 joints. The node turns
// it into the glove hand's pose (touch4d/tracking/webxr.py); nothing is computed here.

// xr-standard gamepad mapping: button index -> name (0, the trigger, is sent as a value).
const BUTTONS = [null, 'squeeze', 'touchpad', 'thumbstick', 'a', 'b'];
const JOINTS = [
  'wrist',
  'thumb-metacarpal', 'thumb-phalanx-proximal', 'thumb-phalanx-distal', 'thumb-tip',
  'index-finger-metacarpal', 'index-finger-phalanx-proximal', 'index-finger-phalanx-intermediate',
  'index-finger-phalanx-distal', 'index-finger-tip',
  'middle-finger-metacarpal', 'middle-finger-phalanx-proximal', 'middle-finger-phalanx-intermediate',
  'middle-finger-phalanx-distal', 'middle-finger-tip',
  'ring-finger-metacarpal', 'ring-finger-phalanx-proximal', 'ring-finger-phalanx-intermediate',
  'ring-finger-phalanx-distal', 'ring-finger-tip',
  'pinky-finger-metacarpal', 'pinky-finger-phalanx-proximal', 'pinky-finger-phalanx-intermediate',
  'pinky-finger-phalanx-distal', 'pinky-finger-tip',
];

const round = (x) => Math.round(x * 1e6) / 1e6;   // a micrometre: shorter JSON, nothing lost

export function pose7(transform) {
  const p = transform.position, q = transform.orientation;
  return [p.x, p.y, p.z, q.x, q.y, q.z, q.w].map(round);
}

export class InputReader {
  constructor(session) {
    this.selecting = new Set();    // sources whose primary action (trigger, pinch) is held
    session.addEventListener('selectstart', (e) => this.selecting.add(e.inputSource));
    session.addEventListener('selectend', (e) => this.selecting.delete(e.inputSource));
  }

  // The input message for this frame; `tracking` is false when the headset's own pose is lost.
  // A pose the runtime can no longer give is null; WebXR's emulatedPosition is not used (emulators
  // set it on every pose, and a headset that loses tracking hides or blurs the session instead).
  read(frame, space, session, viewerPose, time) {
    const tracking = viewerPose !== null;
    const sources = [];
    for (const source of session.inputSources) {
      if (!['right', 'left', 'none'].includes(source.handedness) || sources.length >= 4) continue;
      const out = { handedness: source.handedness, grip: null, trigger: 0, buttons: [], joints: null };
      if (source.hand) {
        out.joints = this.joints(frame, source.hand, space);
      } else if (source.gripSpace) {
        const grip = frame.getPose(source.gripSpace, space);
        if (grip) out.grip = pose7(grip.transform);
      }
      const pad = source.gamepad;
      if (pad) {
        if (pad.buttons[0]) out.trigger = round(Math.min(Math.max(pad.buttons[0].value, 0), 1));
        pad.buttons.forEach((b, i) => { if (BUTTONS[i] && b.pressed) out.buttons.push(BUTTONS[i]); });
        // the thumbstick pushed forward or back past half its travel (the slice view moves c)
        if (pad.axes.length > 3 && pad.axes[3] < -0.5) out.buttons.push('thumbstick-up');
        if (pad.axes.length > 3 && pad.axes[3] > 0.5) out.buttons.push('thumbstick-down');
      }
      if (this.selecting.has(source)) out.trigger = 1;
      sources.push(out);
    }
    return {
      type: 'input', time: performance.timeOrigin + time, tracking,
      head: viewerPose ? pose7(viewerPose.transform) : null, sources,
    };
  }

  joints(frame, hand, space) {
    const out = [];
    for (const name of JOINTS) {
      const joint = hand.get(name);
      const pose = joint ? frame.getJointPose(joint, space) : null;
      if (!pose) return null;                        // a hand is sent whole or not at all
      out.push([...pose7(pose.transform), round(pose.radius)]);
    }
    return out;
  }
}

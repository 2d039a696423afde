"""The page as the glove's output: what a held controller (WebXR `pulse`) or a desktop gamepad
(`dual-rumble`) plays, from `tactile/motors`. The page's half is touch4d/web/static/haptics.js.

Mapping: the controller has one actuator, so it plays the strongest motor's intensity, clipped to
0..1, linearly as the actuator's amplitude (`pulse(intensity, ms)`; `strongMagnitude` and
`weakMagnitude` of `dual-rumble`). With config/gloves/quest-controller.yaml that is its one motor,
eq. 3 over the whole fist. Each XR frame the page pulses for 1.5 frame intervals (a new pulse
replaces the one playing), so the vibration is continuous while frames come and dies on its own
within two frames when they stop. Fail safe: the node sends 0 while the study's condition holds
the motors off, the hand is invalid (the page hidden or closed, tracking lost) or `tactile/motors`
is stale; the page plays 0 on its own when it hides, its session ends, it loses tracking or the
node's frames stop (STALE_MS in haptics.js). With the webxr node's `touch: page` the page plays the
intensity it computes itself (static/touch.js, `level`: this mapping, held to it by tests/test_web_touch.py).
"""
from __future__ import annotations

import math

import numpy as np

# the heartbeat's counts of connected pages by what they can vibrate
HAPTIC_COUNTERS = {"pulse": "haptics_pulse", "dual-rumble": "haptics_rumble", "none": "haptics_none"}


def haptic_level(intensity: np.ndarray, on: bool) -> float:
    """The controller's intensity 0..1: the strongest motor's, clipped; 0 when not `on` or no motor."""
    if not on or len(intensity) == 0:
        return 0.0
    top = float(intensity.max())
    return min(max(top, 0.0), 1.0) if math.isfinite(top) else 0.0

"""The page as the glove's output: what a held controller (WebXR `pulse`) or a desktop gamepad
(`dual-rumble`) plays, from `tactile/motors`. The page's half is touch4d/web/static/haptics.js.

Mapping: the controller has one actuator, so it plays the strongest motor's intensity, clipped to
0..1, linearly as the actuator's amplitude (`pulse(intensity, ms)`; `strongMagnitude` and
`weakMagnitude` of `dual-rumble`). With config/gloves/quest-controller.yaml that is its one motor,
eq. 3 over the whole fist. Each XR frame the page pulses for 1.5 frame intervals (a new pulse
replaces the one playing), so the vibration is continuous while frames come and dies on its own
within two frames when they stop. Fail safe: the node sends 0 while the study's condition holds
the motors off, after a `safety/stop` (for its hold), while the hand is invalid (the page hidden or
closed, tracking lost) or `tactile/motors` is stale: `PageOutput`, the "page" HapticOutput, whose
touch4d.hapticoutput.OutputGuard owns those rules as it does the CAN glove's; the page plays 0 on its own when it hides, its session ends, it loses tracking or the
node's frames stop (STALE_MS in haptics.js). With the webxr node's `touch: page` the page plays the
intensity it computes itself (static/touch.js, `level`: this mapping, held to it by tests/test_web_touch.py).
"""
from __future__ import annotations

import math

import numpy as np

from touch4d.hapticoutput import HapticOutput, OutputGuard

# the heartbeat's counts of connected pages by what they can vibrate
HAPTIC_COUNTERS = {"pulse": "haptics_pulse", "dual-rumble": "haptics_rumble", "none": "haptics_none"}


def haptic_level(intensity: np.ndarray, on: bool) -> float:
    """The controller's intensity 0..1: the strongest motor's, clipped; 0 when not `on` or no motor."""
    if not on or len(intensity) == 0:
        return 0.0
    top = float(intensity.max())
    return min(max(top, 0.0), 1.0) if math.isfinite(top) else 0.0


class PageOutput(HapticOutput):
    """The page's controller as a HapticOutput: the one level it plays (`haptic_level`) of the command
    its guard lets through; a command older than `stale_s` (the guard's watchdog) plays 0."""

    def __init__(self, motors: int, stale_s: float, stop_hold_s: float = 1.0, gate_open: bool = True):
        self.guard = OutputGuard(motors, stale_s, stop_hold_s=stop_hold_s, gate_open=gate_open)
        self._level = 0.0   # haptic_level of the last command, computed once per command

    def play(self, intensity: np.ndarray, now: float, age: float | None = None) -> None:
        if self.guard.command(intensity, now, age):
            self._level = haptic_level(self.guard.intensity, True)

    def off(self, now: float) -> None:
        self.guard.silence()
        self._level = 0.0

    def level(self, now: float, hand_valid: bool = True) -> float:
        """What the controller plays now: the command's level, 0 while the hand is invalid or a rule holds."""
        return self._level if hand_valid and self.guard.reason(now) is None else 0.0

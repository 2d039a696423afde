"""The hand's vocabulary that tracking, the tactile model and the views share: the glove's finger
names, WebXR's 25 hand joints (their order and names), and a hand shape (how the fingers bend).

A tracker without hand tracking (scripted, desktop) makes a `HandShape`; the tactile model
(touch4d.tactile.skeleton) turns it into the joints of the glove's hand; a hand tracker sends the
joints themselves (touch4d.messages.HandJoints, in `WEBXR_JOINTS` order).
"""
from __future__ import annotations

from dataclasses import dataclass, field

FINGER_NAMES = ("thumb", "index", "middle", "ring", "little")

# The 25 joints of the WebXR Hand Input module, in its order.
WEBXR_JOINTS = (
    "wrist",
    "thumb-metacarpal", "thumb-phalanx-proximal", "thumb-phalanx-distal", "thumb-tip",
    "index-finger-metacarpal", "index-finger-phalanx-proximal", "index-finger-phalanx-intermediate",
    "index-finger-phalanx-distal", "index-finger-tip",
    "middle-finger-metacarpal", "middle-finger-phalanx-proximal", "middle-finger-phalanx-intermediate",
    "middle-finger-phalanx-distal", "middle-finger-tip",
    "ring-finger-metacarpal", "ring-finger-phalanx-proximal", "ring-finger-phalanx-intermediate",
    "ring-finger-phalanx-distal", "ring-finger-tip",
    "pinky-finger-metacarpal", "pinky-finger-phalanx-proximal", "pinky-finger-phalanx-intermediate",
    "pinky-finger-phalanx-distal", "pinky-finger-tip",
)


@dataclass(frozen=True)
class HandShape:
    """How the fingers bend: `curl` per finger 0 (straight) .. 1 (fist), `spread` 0 (together) .. 1."""

    curl: dict = field(default_factory=dict)     # finger name -> 0..1 (missing: 0)
    spread: float = 0.0

    def of(self, finger: str) -> float:
        return float(self.curl.get(finger, 0.0))

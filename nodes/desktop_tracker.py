"""Desktop tracker: the hand and the controller's trigger steered from the renderer window's `ui/input`.

Keys and mouse as in touch4d.tracking.desktop; publishes `hand/pose` and `controller/state` at `rate` Hz,
and (`joints`: true) the glove hand's 25 WebXR joints on `hand/joints`, its fingers curled by keys
1 .. 5 (thumb .. little), f (fist) and v (spread), just before the pose of the same instant.
Without a window nothing steers it: it says so at start when there is no display, and once when no
`ui/input` has come within `input_timeout` seconds (a headless or missing renderer).
"""
from __future__ import annotations

import os
import time

from touch4d.bus import Node, Param
from touch4d.messages import ControllerState, HandJoints, HandPose, InputEvents
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import MAX_TRACKER_RATE
from touch4d.tracking.desktop import DesktopConfig, DesktopHand
from touch4d.tracking.outputs import from_hand

_DEFAULTS = DesktopConfig()


class DesktopTracker(Node):
    """The hand steered with keyboard and mouse in the renderer window."""

    default_name = "tracker"
    PARAMS = {
        "rate": Param(90.0, "poses per second", unit="Hz", above=0, max=MAX_TRACKER_RATE),
        "home": Param(list(_DEFAULTS.home), "where the hand starts ([x, y, z], screen units)", items=float, length=3),
        "move_speed": Param(_DEFAULTS.move_speed, "while a move key is held", unit="screen units/s", above=0),
        "turn_speed_deg": Param(_DEFAULTS.turn_speed_deg, "while a turn key is held", unit="degrees/s", above=0),
        "drag_turn": Param(_DEFAULTS.drag_turn, "turn per pixel of a left-button drag", unit="rad/pixel", above=0),
        "drag_move": Param(_DEFAULTS.drag_move, "move per pixel of a right-button drag", unit="screen units/pixel",
                           above=0),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration", path="calibration file"),
        "input_timeout": Param(5.0, "warn when no ui/input came within this time", unit="s", above=0),
        "joints": Param(True, "publish hand/joints: the fingers curl with keys 1 .. 5, f, v"),
        "curl_speed": Param(_DEFAULTS.curl_speed, "a finger curls fully in 1 / curl_speed seconds", unit="1/s",
                            above=0),
        "glove": Param("config/glove.yaml", "the glove whose hand the joints are", path="glove file"),
    }

    def setup(self) -> None:
        p = self.params
        self.rate = p["rate"]
        config = DesktopConfig(**{k: p[k] for k in ("move_speed", "turn_speed_deg", "drag_turn", "drag_move",
                                                     "curl_speed")},
                               home=tuple(p["home"]))
        self.calibration = load_calibration(p["calibration"])
        self.input_timeout = p["input_timeout"]
        self.hand = DesktopHand(config)
        self.hand_pub = self.create_publisher("hand/pose", HandPose)
        self.controller_pub = self.create_publisher("controller/state", ControllerState)
        self.glove = load_glove(p["glove"]) if p["joints"] else None
        if self.glove is not None:
            self.joints_pub = self.create_publisher("hand/joints", HandJoints)
        self.create_subscription("ui/input", InputEvents, self.on_input)
        self.create_timer(1.0 / self.rate, self.tick)
        self.started = time.monotonic()
        self.heard_input = self.warned = False
        if not os.environ.get("DISPLAY"):
            self.warned = True
            self.log.warning("no window to steer the hand from: there is no display (DISPLAY is not set), so the "
                             "renderer draws offscreen. Run on a machine with a display, or give it one with "
                             "xvfb-run -a touch4d launch tracker:=desktop (a virtual display)")
        else:
            self.log.info("steer the hand from the renderer window: a/d q/e w/s move, arrows z/c turn, space "
                          "or a mouse drag holds the trigger, n/r/p next/reset/projection, h home; 1-5 curl the "
                          "thumb .. little finger, f a fist, v spread")

    def on_input(self, msg: InputEvents) -> None:
        self.heard_input = True
        self.hand.on_input(msg.keys_down, msg.pressed, msg.mouse_delta, msg.buttons, time.monotonic())

    def tick(self) -> None:
        if not (self.heard_input or self.warned) and time.monotonic() - self.started > self.input_timeout:
            self.warned = True
            self.log.warning("no ui/input from a renderer window after %g s: is the renderer headless "
                             "(renderer.headless:=true, or no display) or not running? Nothing steers the hand",
                             self.input_timeout)
        sample = self.hand.step(1.0 / self.rate, time.monotonic())
        hand, controller = from_hand(sample, self.calibration)
        if self.glove is not None:
            g = self.glove
            self.joints_pub.publish(g.skeleton.joint_set(sample.position, sample.orientation, g.units_per_metre,
                                                         self.hand.shape).message(hand.stamp))
        self.hand_pub.publish(hand)
        self.controller_pub.publish(controller)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

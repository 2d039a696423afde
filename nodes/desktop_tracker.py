"""Desktop tracker: the hand and the controller's trigger steered from the renderer window's `ui/input`.

Keys and mouse as in touch4d.tracking.desktop; publishes `hand/pose` and `controller/state` at `rate` Hz.
Without a window nothing steers it: it says so at start when there is no display, and once when no
`ui/input` has come within `input_timeout` seconds (a headless or missing renderer).
"""
from __future__ import annotations

import os
import time

import numpy as np

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.messages import ControllerState, HandPose, InputEvents
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import MAX_TRACKER_RATE, positive_parameter
from touch4d.tracking.desktop import DesktopConfig, DesktopHand
from touch4d.tracking.outputs import from_hand


class DesktopTracker(Node):
    def __init__(self, **kwargs):
        super().__init__("tracker", **kwargs)
        source = f"parameters of node '{self.name}'"
        self.rate = positive_parameter(self.declare_parameter("rate", 90.0), source, "rate", MAX_TRACKER_RATE, "Hz")
        defaults = DesktopConfig()
        home = self.declare_parameter("home", list(defaults.home))
        if len(home) != 3 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                                     for v in home):
            raise ConfigError(source, "home", "[x, y, z] in screen units", got=home)
        speeds = {key: positive_parameter(self.declare_parameter(key, getattr(defaults, key)), source, key)
                  for key in ("move_speed", "turn_speed_deg", "drag_turn", "drag_move")}
        config = DesktopConfig(**speeds, home=tuple(float(v) for v in home))
        self.calibration = load_calibration(self.declare_path_parameter("calibration", "config/calibration.yaml",
                                                                        "calibration file"))
        self.input_timeout = positive_parameter(self.declare_parameter("input_timeout", 5.0), source, "input_timeout")
        self.hand = DesktopHand(config)
        self.hand_pub = self.create_publisher("hand/pose", HandPose)
        self.controller_pub = self.create_publisher("controller/state", ControllerState)
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
                          "or a mouse drag holds the trigger, n/r/p next/reset/projection, h home")

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
        self.hand_pub.publish(hand)
        self.controller_pub.publish(controller)


def main(argv=None):
    return run_node(DesktopTracker, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""Scripted tracker: a hand following a named path of config/paths.yaml, for demos, tests and benchmarks.

Publishes `hand/pose` (screen coordinates) and `controller/state` (room, through the calibration)
at `rate` Hz. Tick k samples the path at t = start_s + k / rate, so the poses depend on the tick
count only, never on timer jitter: every run publishes the same sequence. At the end of the path
it starts over (`loop: true`) or stops publishing.
"""
from __future__ import annotations

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.messages import ControllerState, HandPose
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import MAX_TRACKER_RATE, positive_parameter
from touch4d.tracking.outputs import from_hand
from touch4d.tracking.paths import load_path, looped


class ScriptedTracker(Node):
    def __init__(self, **kwargs):
        super().__init__("tracker", **kwargs)
        source = f"parameters of node '{self.name}'"
        self.rate = positive_parameter(self.declare_parameter("rate", 90.0), source, "rate", MAX_TRACKER_RATE, "Hz")
        name = self.declare_parameter("path", "demo")
        paths_file = self.declare_path_parameter("paths", "config/paths.yaml", "paths file")
        self.loop = self.declare_parameter("loop", True)
        self.start_s = self.declare_parameter("start_s", 0.0)
        if not 0 <= self.start_s < float("inf"):
            raise ConfigError(source, "start_s", "a finite number of seconds >= 0", got=self.start_s)
        self.path = load_path(name, paths_file)
        self.calibration = load_calibration(self.declare_path_parameter("calibration", "config/calibration.yaml",
                                                                        "calibration file"))
        self.hand_pub = self.create_publisher("hand/pose", HandPose)
        self.controller_pub = self.create_publisher("controller/state", ControllerState)
        self.tick_count = 0
        self.finished = False
        self.create_timer(1.0 / self.rate, self.tick)
        self.log.info("path %s (%.1f s%s) at %g Hz", name, self.path.duration, ", looping" if self.loop else "",
                      self.rate)

    def tick(self) -> None:
        if self.finished:
            return
        t = self.start_s + self.tick_count / self.rate
        if not self.loop and t > self.path.duration:
            self.finished = True
            self.log.info("path finished after %d poses", self.tick_count)
            return
        sample = looped(self.path, t) if self.loop else self.path.sample(t)
        hand, controller = from_hand(sample, self.calibration)
        self.hand_pub.publish(hand)
        self.controller_pub.publish(controller)
        self.tick_count += 1


def main(argv=None):
    return run_node(ScriptedTracker, argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""A tracker written outside touch4d: a hand sweeping along x through the screen and back.

Pose k (the k-th tick, also its `seq`) is at x = amplitude * sin(2 pi k / (rate * period)), so what
it publishes depends on the tick count only.
"""
from __future__ import annotations

import math

import numpy as np

from touch4d.bus import Node, Param
from touch4d.messages import HandPose


class WaveTracker(Node):
    """A hand sweeping along x through the screen, as a lab's own tracker would publish it."""

    default_name = "tracker"
    PARAMS = {
        "rate": Param(90.0, "poses per second", unit="Hz", above=0, max=1000),
        "amplitude": Param(0.5, "how far the hand goes either side of the centre", unit="screen units", above=0),
        "period": Param(4.0, "one sweep there and back", unit="s", above=0),
        "depth": Param(0.0, "z of the hand (inside the screen: -1..1)", unit="screen units", min=-1, max=1),
    }

    def setup(self) -> None:
        self.rate = self.params["rate"]
        if self.params["amplitude"] > 1.0:   # a check no declaration can express: name the parameter
            self.log.warning("amplitude %g takes the hand out of the screen", self.params["amplitude"])
        self.pub = self.create_publisher("hand/pose", HandPose)
        self.ticks = 0
        self.create_timer(1.0 / self.rate, self.tick)
        self.log.info("waving at %g Hz", self.rate)

    def tick(self) -> None:
        phase = 2.0 * math.pi * self.ticks / (self.rate * self.params["period"])
        x = self.params["amplitude"] * math.sin(phase)
        self.pub.publish(HandPose(position=np.array([x, 0.0, self.params["depth"]]),
                                  orientation=np.array([0.0, 0.0, 0.0, 1.0]), valid=True))
        self.ticks += 1

    def on_shutdown(self) -> None:
        self.log.info("waved %d poses", self.ticks)

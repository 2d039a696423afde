"""Example node: publishes a HandPose moving on a circle, at `rate` Hz, on `topic`.

A minimal node to copy, and the publisher of the bus's own tests and demo.
"""
from __future__ import annotations

import math

import numpy as np

from touch4d.bus import Node, Param
from touch4d.messages import HandPose


class ExampleTalker(Node):
    """Publishes a HandPose moving on a circle."""

    default_name = "talker"
    PARAMS = {
        "topic": Param("example/pose", "the topic to publish on"),
        "rate": Param(10.0, "messages per second", unit="Hz", above=0),
        "count": Param(0, "stop publishing after this many; 0 = never", min=0),
    }

    def setup(self) -> None:
        self.topic, self.rate, self.count = self.params["topic"], self.params["rate"], self.params["count"]
        self.pub = self.create_publisher(self.topic, HandPose)
        self.sent = 0
        self.create_timer(1.0 / self.rate, self.tick)
        self.log.info("publishing HandPose on %s at %g Hz", self.topic, self.rate)

    def tick(self):
        if self.count and self.sent >= self.count:
            return
        angle = 2.0 * math.pi * 0.2 * self.sent / self.rate
        self.pub.publish(HandPose(
            position=np.array([0.5 * math.cos(angle), 0.5 * math.sin(angle), 0.0]),
            orientation=np.array([0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]),
            valid=True,
        ))
        self.sent += 1


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

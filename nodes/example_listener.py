"""Example node: listens to HandPose on `topic`, optionally slowly, and relays what it handled.

Relaying to `relay_topic` lets tests see, from outside the process, which messages it handled;
with `stop_on_shutdown` it publishes a Stop from `on_shutdown`, as the motor node must.
"""
from __future__ import annotations

import time

from touch4d.bus import Node, run_node
from touch4d.messages import HandPose, Stop


class ExampleListener(Node):
    def __init__(self, **kwargs):
        super().__init__("listener", **kwargs)
        topic = self.declare_parameter("topic", "example/pose")
        self.delay = self.declare_parameter("delay", 0.0)  # seconds spent in each callback
        latest_only = self.declare_parameter("latest_only", False)
        relay_topic = self.declare_parameter("relay_topic", "")
        self.stop_on_shutdown = self.declare_parameter("stop_on_shutdown", False)
        self.relay = self.create_publisher(relay_topic, HandPose) if relay_topic else None
        self.stop_pub = self.create_publisher("safety/stop", Stop) if self.stop_on_shutdown else None
        self.heard = 0
        self.create_subscription(topic, HandPose, self.on_pose, latest_only=latest_only)
        self.log.info("listening on %s%s", topic, " (latest only)" if latest_only else "")

    def on_pose(self, msg: HandPose):
        self.heard += 1
        if self.delay:
            time.sleep(self.delay)
        if self.relay is not None:
            msg.stamp = 0.0  # a new message of ours; source_stamp keeps the original pose's stamp
            self.relay.publish(msg)

    def on_shutdown(self):
        self.log.info("heard %d message(s)", self.heard)
        if self.stop_pub is not None:
            self.stop_pub.publish(Stop(reason="listener shutting down", origin=self.name))


def main(argv=None):
    return run_node(ExampleListener, argv)

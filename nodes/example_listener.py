"""Example node: listens to HandPose on `topic`, optionally slowly, and relays what it handled.

Relaying to `relay_topic` lets tests see, from outside the process, which messages it handled;
with `stop_on_shutdown` it publishes a Stop from `on_shutdown`, as the motor node must.
"""
from __future__ import annotations

import time

from touch4d.bus import Node, Param
from touch4d.messages import HandPose, Stop


class ExampleListener(Node):
    """Listens to HandPose messages and relays them."""

    default_name = "listener"
    PARAMS = {
        "topic": Param("example/pose", "the topic to listen to"),
        "delay": Param(0.0, "time spent in each callback", unit="s", min=0),
        "latest_only": Param(False, "handle only the newest message of a backlog"),
        "relay_topic": Param("", "publish each handled message again here ('' = do not)"),
        "stop_on_shutdown": Param(False, "publish a Stop on safety/stop when shutting down"),
    }

    def setup(self) -> None:
        topic, latest_only = self.params["topic"], self.params["latest_only"]
        self.delay = self.params["delay"]
        relay_topic = self.params["relay_topic"]
        self.relay = self.create_publisher(relay_topic, HandPose) if relay_topic else None
        self.stop_pub = self.create_publisher("safety/stop", Stop) if self.params["stop_on_shutdown"] else None
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


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

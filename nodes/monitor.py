"""The monitor node: prints one status line per period (topic rates, touched motors, latency, and
the topics some node waits for that nobody publishes)."""
from __future__ import annotations

import time

from touch4d import glovefile
from touch4d.bus import Node, Param, names
from touch4d.bus.node import HEARTBEAT_TOPIC
from touch4d.bus.topology import shared_text
from touch4d.messages import Heartbeat, MotorCommand, MotorStatus, MotorTrace
from touch4d.status import StackStatus


class Monitor(Node):
    """Watches its stack (its namespace's topics and nodes) and prints what a user wants to see while the demo runs."""

    default_name = "monitor"
    PARAMS = {
        "period": Param(1.0, "seconds between status lines", unit="s", above=0),
        "glove": Param("config/glove.yaml", "the glove file (a motor above its touch_threshold is touched)",
                       path="glove file"),
    }

    def setup(self) -> None:
        period = self.params["period"]
        glove, _ = glovefile.load(self.params["glove"])
        self.status = StackStatus(window=max(2.0, 2 * period), touch_threshold=glove.touch_threshold)
        self.create_raw_subscription("", self.on_any)
        # What it watches is optional: a stack without motors is no fault of the monitor's.
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors, latest_only=True, optional=True)
        self.create_subscription("motors/status", MotorStatus, self.on_motor_status, latest_only=True, optional=True)
        self.create_subscription("motors/trace", MotorTrace, self.on_trace, optional=True)
        self.create_subscription(HEARTBEAT_TOPIC, Heartbeat, self.on_heartbeat, optional=True)
        self.create_timer(period, self.on_timer)

    def on_any(self, topic: str, payload: bytes) -> None:
        self.status.on_message(topic, time.time())

    def on_motors(self, msg: MotorCommand) -> None:
        self.status.on_motors(msg, time.time())

    def on_trace(self, msg: MotorTrace) -> None:
        self.status.on_trace(msg, time.time())

    def on_motor_status(self, msg: MotorStatus) -> None:
        self.status.on_motor_status(msg)

    def on_heartbeat(self, msg: Heartbeat) -> None:
        if names.in_namespace(msg.node, self.namespace):   # one stack's monitor: another's nodes are not its
            self.status.on_heartbeat(msg, time.time())

    def on_timer(self) -> None:
        now = time.time()
        for topic, nodes in self.status.shared(now).items():
            self.warn_once(("shared", topic, tuple(nodes)), shared_text(topic, nodes))
        print(self.status.line(now), flush=True)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

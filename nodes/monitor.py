"""The monitor node: prints one status line per period (topic rates, touched motors, latency)."""
from __future__ import annotations

import time

from touch4d.bus import Node, run_node
from touch4d.messages import MotorCommand, MotorStatus, MotorTrace
from touch4d.status import StackStatus


class Monitor(Node):
    """Watches the whole bus and prints what a user wants to see while the demo runs."""

    def __init__(self, name: str = "monitor", **kwargs):
        super().__init__(name, **kwargs)
        period = self.declare_parameter("period", 1.0)
        self.status = StackStatus(window=max(2.0, 2 * period))
        self.create_raw_subscription("", self.on_any)
        self.create_subscription("tactile/motors", MotorCommand, self.on_motors, latest_only=True)
        self.create_subscription("motors/status", MotorStatus, self.on_motor_status, latest_only=True)
        self.create_subscription("motors/trace", MotorTrace, self.on_trace)
        self.create_timer(period, self.on_timer)

    def on_any(self, topic: str, payload: bytes) -> None:
        self.status.on_message(topic, time.time())

    def on_motors(self, msg: MotorCommand) -> None:
        self.status.on_motors(msg, time.time())

    def on_trace(self, msg: MotorTrace) -> None:
        self.status.on_trace(msg, time.time())

    def on_motor_status(self, msg: MotorStatus) -> None:
        self.status.on_motor_status(msg)

    def on_timer(self) -> None:
        print(self.status.line(time.time()), flush=True)


def main(argv=None):
    return run_node(Monitor, argv)


if __name__ == "__main__":
    raise SystemExit(main())

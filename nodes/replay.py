"""The replay node: publishes a recorded log back onto the bus, with its timing; fits the tracker role.

`touch4d launch demo.yaml tracker:=replay tracker.file:=session.mcap` drives live tactile, renderer
and motor nodes with a recorded hand. Parameters: `file` (required), `topics` (default the
tracker's: hand/pose, controller/state; [] = every topic in the log), `rate`, `loop`, `start`
(seconds), `remap` ({from: to}) and `restamp` (default true: live nodes downstream see fresh
stamps and seq, as from a live tracker, and the recorded stamp in `recorded_stamp`; false sends
the recorded bytes unchanged, which a live motor node drops as stale).
"""
from __future__ import annotations

import sys
import threading

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.log.reader import LogReader
from touch4d.log.replay import BusSender, Plan, Replayer, ReplayOptions

TRACKER_TOPICS = ["hand/pose", "controller/state"]


class ReplayNode(Node):
    def __init__(self, **kwargs):
        super().__init__("replay", **kwargs)
        source = self._params_source or "parameters"
        path = self.declare_path_parameter("file", "", "log file")
        if not path:
            raise ConfigError(source, f"nodes.{self.name}.params.file", "the .mcap log to replay")
        explicit = "topics" in self.params
        topics = self.declare_parameter("topics", list(TRACKER_TOPICS))
        remap = self.declare_parameter("remap", {})
        options = ReplayOptions(
            rate=self.declare_parameter("rate", 1.0),
            loop=self.declare_parameter("loop", False),
            start=self.declare_parameter("start", 0.0),
            remap={str(k): str(v) for k, v in remap.items()},
            restamp=self.declare_parameter("restamp", True),
        )
        reader = LogReader(path, recover=self.declare_parameter("recover", False))
        if not explicit:  # the default: whichever tracker topics the log has, without warnings
            available = reader.topics()
            topics = [t for t in topics if t in available] or topics
        options.topics = topics or None
        plan = Plan(reader, options)
        for warning in plan.warnings():
            self.log.warning("%s: %s", path, warning)
        sys.setswitchinterval(0.0005)
        self.sender = BusSender(self.bus)
        self.replayer = Replayer(reader, plan, options, self.sender)
        self.thread = threading.Thread(target=self._run, name="replay", daemon=True)
        self.thread.start()
        self.log.info("replaying %s (%s) at rate %g%s", path, ", ".join(plan.topics), options.rate,
                      ", looping" if options.loop else "")

    def _run(self) -> None:
        stats = self.replayer.run()
        if not stats.stopped:
            self.log.info("replay finished: %d messages sent", stats.sent)
        reader = self.replayer.reader
        for problem in reader.problems:
            self.log.warning("%s: %s", reader.path, problem)
        if reader.skipped_chunks:
            self.log.warning("%s: %d damaged chunk(s) skipped, %d message(s) lost", reader.path,
                             reader.skipped_chunks, reader.skipped_messages)

    def on_shutdown(self) -> None:
        self.replayer.stop()
        self.thread.join(timeout=5.0)
        self.sender.close()


def main(argv=None):
    return run_node(ReplayNode, argv)

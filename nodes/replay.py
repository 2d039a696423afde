"""The replay node: publishes a recorded log back onto the bus, with its timing; fits the tracker role.

`touch4d launch demo.yaml tracker:=replay tracker.file:=session.mcap` drives live tactile, renderer
and motor nodes with a recorded hand. Parameters: `file` (required), `topics` (default the
tracker's: hand/joints, hand/pose, controller/state; [] = every topic in the log), `rate`, `loop`, `start`
(seconds), `remap` ({from: to}) and `restamp` (default true: live nodes downstream see fresh
stamps and seq, as from a live tracker, and the recorded stamp in `recorded_stamp`; false sends
the recorded bytes unchanged, which a live motor node drops as stale).
"""
from __future__ import annotations

import sys
import threading

from touch4d.bus import Node, Param
from touch4d.log.reader import LogReader
from touch4d.log.replay import BusSender, Plan, Replayer, ReplayOptions

TRACKER_TOPICS = ["hand/joints", "hand/pose", "controller/state"]


class ReplayNode(Node):
    """Publishes a recorded log back onto the bus, with its timing."""

    default_name = "replay"
    PARAMS = {
        "file": Param("", "the .mcap log to replay (required)", path="log file"),
        "topics": Param(list(TRACKER_TOPICS), "the topics to replay ([] = every topic of the log)", items=str),
        "remap": Param({}, "topic renames, {from: to}"),
        "rate": Param(1.0, "speed factor (2 = twice as fast)", above=0),
        "loop": Param(False, "start over at the end of the log"),
        "start": Param(0.0, "seconds into the log to start from", unit="s", min=0),
        "restamp": Param(True, "fresh stamps and seq, as from a live tracker (false: the recorded bytes)"),
        "recover": Param(False, "read a log whose writer was killed (no index)"),
    }

    def setup(self) -> None:
        p = self.params
        path = p["file"]
        if not path:
            raise self.param_error("file", "the .mcap log to replay", got=None)
        options = ReplayOptions(rate=p["rate"], loop=p["loop"], start=p["start"],
                                remap={str(k): str(v) for k, v in p["remap"].items()}, restamp=p["restamp"])
        reader = LogReader(path, recover=p["recover"])
        topics = p["topics"]
        if "topics" not in self.given:  # the default: whichever tracker topics the log has, without warnings
            available = reader.topics()
            topics = [t for t in topics if t in available] or topics
        options.topics = topics or None
        plan = Plan(reader, options)
        for warning in plan.warnings():
            self.log.warning("%s: %s", path, warning)
        sys.setswitchinterval(0.0005)
        self.sender = BusSender(self.bus, namespace=self.namespace)
        self.add_cleanup(self.sender.close)
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


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

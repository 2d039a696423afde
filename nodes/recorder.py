"""The recorder node: records bus topics into an MCAP log for as long as the launch runs.

Parameters: `file` (the .mcap to write; default `touch4d-<date>-<time>.mcap`), `topics` (list of
exact topic names; empty = all). A file that exists is never written over: a recorder restarted
with the same `file` (a respawn) writes NAME-2.mcap, NAME-3.mcap, ... beside it. Receiving and
writing run on the recorder's own socket and threads (touch4d.log.recorder), so the node thread
only reports; the report (counts, seq gaps) is logged at shutdown.
"""
from __future__ import annotations

import time
from pathlib import Path

from touch4d.bus import Node, Param
from touch4d.log.recorder import Recorder


class RecorderNode(Node):
    """Records topics into an MCAP log."""

    default_name = "recorder"
    PARAMS = {
        "file": Param("", "the .mcap to write ('' = touch4d-DATE-TIME.mcap)"),
        "topics": Param([], "exact topic names to record ([] = every topic)", items=str),
    }

    def setup(self) -> None:
        path = unused_path(Path(self.params["file"] or time.strftime("touch4d-%Y%m%d-%H%M%S.mcap")))
        topics = self.params["topics"]
        if not all(topics):
            raise self.param_error("topics", "a list of topic names")
        self.recorder = Recorder(self.bus, path, topics, namespace=self.namespace)
        self.recorder.start()
        self.tap_private(self.recorder.offer)     # its group's private topics: no socket brings them
        self.create_timer(0.25, self.on_timer)   # a full disk is said at once; the other nodes go on
        self.log.info("recording %s to %s", ", ".join(topics) if topics else "all topics", path)

    def on_timer(self) -> None:
        if self.recorder.wait(0):
            self.log.error("%s", self.recorder.error)
            self.request_shutdown()

    def on_shutdown(self) -> None:
        for line in self.recorder.stop().lines():
            self.log.info(line)


def unused_path(path: Path) -> Path:
    """`path`, or the first of path-2, path-3, ... (before the suffix) that does not exist yet."""
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    return candidate


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

"""The recorder node: records bus topics into an MCAP log for as long as the launch runs.

Parameters: `file` (the .mcap to write; default `touch4d-<date>-<time>.mcap`), `topics` (list of
exact topic names; empty = all). Receiving and writing run on the recorder's own socket and
threads (touch4d.log.recorder), so the node thread only reports; the report (counts, seq gaps)
is logged at shutdown.
"""
from __future__ import annotations

import time

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.log.recorder import Recorder


class RecorderNode(Node):
    def __init__(self, **kwargs):
        super().__init__("recorder", **kwargs)
        path = self.declare_parameter("file", time.strftime("touch4d-%Y%m%d-%H%M%S.mcap"))
        topics = self.declare_parameter("topics", [])
        if not all(isinstance(t, str) and t for t in topics):
            raise ConfigError(self._params_source or "parameters", f"nodes.{self.name}.params.topics",
                              "a list of topic names", got=topics)
        self.recorder = Recorder(self.bus, path, topics)
        self.recorder.start()
        self.create_timer(10.0, self.on_timer)
        self.log.info("recording %s to %s", ", ".join(topics) if topics else "all topics", path)

    def on_timer(self) -> None:
        if self.recorder.wait(0):
            self.log.error("recording stopped: %s", self.recorder.error)
            self.request_shutdown()

    def on_shutdown(self) -> None:
        for line in self.recorder.stop().lines():
            self.log.info(line)


def main(argv=None):
    return run_node(RecorderNode, argv)

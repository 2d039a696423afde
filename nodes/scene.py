"""Scene node: holds the 4D scene, turns it with the controller (paper §4.4), publishes `scene/state`.

Subscribes `controller/state` (latest only: motion is measured between the samples it handles, so
skipping a backlog loses no rotation) and `scene/command`. Publishes `scene/state` on every change,
at most `max_rate` times a second, and every 1/`rate` s for late joiners. The calibration file is
read again when it changes (a headset re-centring the screen turns the controller's axes with it).
"""
from __future__ import annotations

import os
import time

from touch4d.bus import Node, run_node
from touch4d.errors import ConfigError
from touch4d.geometry.scene import load_scene
from touch4d.messages import ControllerState, SceneCommand, SceneState
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import positive_parameter
from touch4d.tracking.scene_control import DEFAULT_BUTTONS, ControlConfig, SceneControl


class SceneNode(Node):
    def __init__(self, **kwargs):
        super().__init__("scene", **kwargs)
        source = f"parameters of node '{self.name}'"
        scene_file = self.declare_path_parameter("scene", "config/scenes/hypercube.yaml", "scene file")
        calibration = self.declare_path_parameter("calibration", "config/calibration.yaml", "calibration file")
        rate = positive_parameter(self.declare_parameter("rate", 2.0), source, "rate", 1000.0, "Hz")
        self.min_period = 1.0 / positive_parameter(self.declare_parameter("max_rate", 120.0), source, "max_rate",
                                                   1000.0, "Hz")
        spin_rate = positive_parameter(self.declare_parameter("spin_rate", 30.0), source, "spin_rate", 1000.0, "Hz")
        config = ControlConfig.from_params(
            gains=self.declare_parameter("gains", {}),
            trigger_threshold=self.declare_parameter("trigger_threshold", 0.5),
            buttons=self.declare_parameter("buttons", dict(DEFAULT_BUTTONS)),
            rotate=self.declare_parameter("rotate", "object"),
            spin=self.declare_parameter("spin", {}),
            source=source,
        )
        self.calibration_file = calibration
        self.control = SceneControl(load_scene(scene_file), load_calibration(calibration), config)
        self.calibration_mtime = os.stat(self.calibration_file).st_mtime_ns
        self.dirty = False
        self.last_publish = 0.0
        self.pub = self.create_publisher("scene/state", SceneState)
        self.create_subscription("controller/state", ControllerState, self.on_controller, latest_only=True)
        self.create_subscription("scene/command", SceneCommand, self.on_command)
        self.create_timer(1.0 / rate, self.publish)
        self.create_timer(self.min_period, self.flush)
        if config.spin_plane is not None:
            self.create_timer(1.0 / spin_rate, lambda: self.changed(self.control.advance(1.0 / spin_rate)))
        self.create_timer(1.0, self.reload_calibration)
        self.publish()
        self.log.info("scene %s: %d object(s), rotating %s", scene_file, len(self.control.scene.objects),
                      "the whole scene" if self.control.scene.selected < 0 else "the selected object")

    def reload_calibration(self) -> None:
        try:
            mtime = os.stat(self.calibration_file).st_mtime_ns
            if mtime != self.calibration_mtime:
                self.calibration_mtime = mtime
                self.control.calibration = load_calibration(self.calibration_file)
                self.log.info("calibration %s read again", self.calibration_file)
        except (OSError, ConfigError) as exc:
            self.log.warning("calibration %s changed but cannot be read, keeping the last one: %s",
                             self.calibration_file, exc)

    def on_controller(self, msg: ControllerState) -> None:
        self.changed(self.control.on_controller(msg.position, msg.orientation, msg.trigger, msg.buttons, msg.valid))

    def on_command(self, msg: SceneCommand) -> None:
        try:
            changed = self.control.command(msg.command, msg.argument)
        except ValueError as exc:
            self.log.warning("scene/command ignored: %s", exc)
            return
        self.changed(changed)

    def changed(self, changed: bool) -> None:
        """Publish a change now, or on the next flush if the last message went out under min_period ago."""
        if not changed:
            return
        if time.monotonic() - self.last_publish >= self.min_period:
            self.publish()
        else:
            self.dirty = True

    def flush(self) -> None:
        if self.dirty:
            self.publish()

    def publish(self) -> None:
        self.pub.publish(self.control.message())
        self.dirty = False
        self.last_publish = time.monotonic()


def main(argv=None):
    return run_node(SceneNode, argv)


if __name__ == "__main__":
    raise SystemExit(main())

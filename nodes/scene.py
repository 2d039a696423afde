"""Scene node: holds the 4D scene, turns it with the controller (paper §4.4), publishes `scene/state`.

Subscribes `controller/state` (latest only: motion is measured between the samples it handles, so
skipping a backlog loses no rotation) and `scene/command` (`load` with a scene file's text replaces
the whole scene: how a study shows each trial's stimulus). Publishes `scene/state` on every change,
at most `max_rate` times a second, and again every 1/`rate` s on a steady beat, for late joiners
(touch4d.bus.ratelimit). The calibration file is read again when it changes (a headset re-centring
the screen turns the controller's axes with it).
"""
from __future__ import annotations

import os

from touch4d.bus import Node, Param
from touch4d.bus.ratelimit import RateLimitedPublisher
from touch4d.errors import ConfigError, Touch4dError
from touch4d.geometry.scene import load_scene
from touch4d.messages import ControllerState, SceneCommand, SceneState
from touch4d.physics.config import load_physics
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.scene_control import DEFAULT_BUTTONS, ROTATE_TARGETS, ControlConfig, SceneControl


def what_turns(control: SceneControl) -> str:
    """What turns the scene, as the node starts: the controller (its `rotate`, none: nothing) and the spin."""
    config = control.config
    target = "the whole scene" if control.scene.selected < 0 else "the selected object"
    said = ["the controller turns nothing" if config.rotate == "none" else f"the controller turns {target}"]
    if config.spin_plane is not None and config.spin_deg_per_s != 0.0:
        said.append(f"spinning {target} in {config.spin_plane} at {config.spin_deg_per_s:g} deg/s")
    return "; ".join(said)


class SceneNode(Node):
    """Holds the 4D scene and turns it with the controller."""

    default_name = "scene"
    PARAMS = {
        "scene": Param("config/scenes/hypercube.yaml", "the scene file", path="scene file"),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration", path="calibration file"),
        "rate": Param(2.0, "scene/state repeats for late joiners", unit="Hz", above=0, max=1000),
        "max_rate": Param(120.0, "scene/state at most this often while it changes", unit="Hz", above=0, max=1000),
        "spin_rate": Param(30.0, "steps of the spin", unit="Hz", above=0, max=1000),
        "gains": Param({}, "controller motion -> rotation: {translation, rotation}"),
        "trigger_threshold": Param(0.5, "trigger value that grabs the object", above=0, max=1),
        "buttons": Param(dict(DEFAULT_BUTTONS), "controller button -> scene command"),
        "rotate": Param("object", "what the controller turns (none: nothing)", choices=ROTATE_TARGETS),
        "spin": Param({}, "turn by itself: {plane: xw, deg_per_s: 6}"),
    }

    def setup(self) -> None:
        p = self.params
        config = ControlConfig.from_params(gains=p["gains"], trigger_threshold=p["trigger_threshold"],
                                           buttons=p["buttons"], rotate=p["rotate"], spin=p["spin"],
                                           source=self.param_where("spin")[0])
        self.control = SceneControl(load_scene(p["scene"]), load_calibration(p["calibration"]), config)
        # a scene file's static bodies (a floor) are never the controller's, with or without physics
        self.control.fix(load_physics(p["scene"]).static)
        self.calibration_mtime = os.stat(p["calibration"]).st_mtime_ns
        self.create_timer(1.0, self.reload_calibration)
        pub = self.create_publisher("scene/state", SceneState)
        # every publish, the steady one for late joiners too, keeps max_rate's spacing
        self.scene_state = RateLimitedPublisher.for_node(self, lambda: pub.publish(self.control.message()),
                                                         rate=p["rate"], max_rate=p["max_rate"])
        self.create_subscription("controller/state", ControllerState, self.on_controller, latest_only=True)
        self.create_subscription("scene/command", SceneCommand, self.on_command, optional=True)
        if config.spin_plane is not None:
            spin_rate = p["spin_rate"]
            self.create_timer(1.0 / spin_rate, lambda: self.scene_state.changed(self.control.advance(1.0 / spin_rate)))
        self.log.info("scene %s: %d object(s); %s", p["scene"], len(self.control.scene.objects),
                      what_turns(self.control))

    def reload_calibration(self) -> None:
        """Read the calibration again when its file changed (a headset re-centred the screen)."""
        path = self.params["calibration"]
        try:
            mtime = os.stat(path).st_mtime_ns
            if mtime != self.calibration_mtime:
                self.calibration_mtime = mtime
                self.control.calibration = load_calibration(path)
                self.log.info("calibration %s read again", path)
        except (OSError, ConfigError) as exc:
            self.warn_once(("calibration", str(exc)), f"calibration {path} changed but cannot be read, keeping "
                                                      f"the last one: {exc}")

    def on_controller(self, msg: ControllerState) -> None:
        self.scene_state.changed(self.control.on_controller(msg.position, msg.orientation, msg.trigger,
                                                            msg.buttons, msg.valid))

    def on_command(self, msg: SceneCommand) -> None:
        try:
            changed = self.control.command(msg.command, msg.argument)
        except Touch4dError as exc:   # SceneCommandError, or (ConfigError) a bad scene to load: the scene stays
            self.log.warning("scene/command %s ignored: %s", msg.command, exc)
            return
        self.scene_state.changed(changed)


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

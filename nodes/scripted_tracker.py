"""Scripted tracker: a hand following a named path of config/paths.yaml, for demos, tests and benchmarks.

Publishes `hand/pose` (screen coordinates) and `controller/state` (room, through the calibration) at
`rate` Hz; with `fingers` (a shape or a motion of config/fingers.yaml: curl, point, spread, ...)
also the glove hand's 25 WebXR joints on `hand/joints`, bent as the motion says, published just
before the pose of the same tick with the same stamp. Tick k samples the path at t = start_s + k /
rate, so the poses depend on the tick count only, never on timer jitter: every run publishes the
same sequence. At the end of the path it starts over (`loop: true`) or stops publishing.
"""
from __future__ import annotations

import numpy as np

from touch4d.bus import Node, Param
from touch4d.messages import ControllerState, HandJoints, HandPose
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.config import MAX_TRACKER_RATE
from touch4d.tracking.fingers import load_motion
from touch4d.tracking.outputs import from_hand
from touch4d.tracking.paths import load_path, looped


class ScriptedTracker(Node):
    """A hand following a named path, at a fixed rate."""

    default_name = "tracker"
    PARAMS = {
        "rate": Param(90.0, "poses per second", unit="Hz", above=0, max=MAX_TRACKER_RATE),
        "path": Param("demo", "the name of a path in the paths file"),
        "paths": Param("config/paths.yaml", "the paths file", path="paths file"),
        "loop": Param(True, "start over at the end of the path (else stop publishing)"),
        "start_s": Param(0.0, "where on the path to start", unit="s", min=0),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration", path="calibration file"),
        "fingers": Param("none", "bend the fingers and publish hand/joints: a shape (flat, fist, point, spread, "
                         "pinch) or a motion of the fingers file (curl, point, spread, wave); none: poses only"),
        "fingers_file": Param("config/fingers.yaml", "the finger motions", path="fingers file"),
        "finger_speed": Param(1.0, "play the finger motion this much faster", above=0, max=100.0),
        "glove": Param("config/glove.yaml", "the glove whose hand the joints are", path="glove file"),
    }

    def setup(self) -> None:
        p = self.params
        self.rate, self.loop, self.start_s = p["rate"], p["loop"], p["start_s"]
        self.path = load_path(p["path"], p["paths"])
        self.calibration = load_calibration(p["calibration"])
        self.hand_pub = self.create_publisher("hand/pose", HandPose)
        self.controller_pub = self.create_publisher("controller/state", ControllerState)
        self.motion = None
        if p["fingers"] != "none":
            self.motion = load_motion(p["fingers"], p["fingers_file"])
            self.glove = load_glove(p["glove"])
            self.joints_pub = self.create_publisher("hand/joints", HandJoints)
        self.tick_count = 0
        self.finished = False
        self.create_timer(1.0 / self.rate, self.tick)
        self.log.info("path %s (%.1f s%s) at %g Hz%s", p["path"], self.path.duration, ", looping" if self.loop else "",
                      self.rate, f"; fingers: {p['fingers']}, on hand/joints" if self.motion else "")

    def tick(self) -> None:
        if self.finished:
            return
        t = self.start_s + self.tick_count / self.rate
        if not self.loop and t > self.path.duration:
            self.finished = True
            self.log.info("path finished after %d poses", self.tick_count)
            return
        sample = looped(self.path, t) if self.loop else self.path.sample(t)
        hand, controller = from_hand(sample, self.calibration)
        if self.motion is not None:
            self.joints_pub.publish(self.joints(sample, t, hand.stamp))
        self.hand_pub.publish(hand)
        self.controller_pub.publish(controller)
        self.tick_count += 1

    def joints(self, sample, t: float, stamp: float) -> HandJoints:
        """The glove hand's joints at the path's pose, the fingers bent as the motion says at t."""
        g = self.glove
        if not sample.valid:
            return HandJoints(handedness=g.skeleton.handedness, names=[], positions=np.zeros((0, 3)),
                              orientations=np.zeros((0, 4)), radii=np.zeros(0), valid=False, stamp=stamp,
                              source_stamp=stamp)
        shape = self.motion.looped(t * self.params["finger_speed"])
        return g.skeleton.joint_set(sample.position, sample.orientation, g.units_per_metre, shape).message(stamp)

if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

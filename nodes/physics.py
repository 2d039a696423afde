"""Physics node: the scene node with 4D rigid-body physics (`scene:=physics`).

Publishes `scene/state` as the scene node does (the bodies where physics has them, at each tick while
anything moves, at most `max_rate` times a second, and again every 1/`rate` s on a steady beat, for late
joiners: touch4d.bus.ratelimit) and `physics/contacts` (contact points that
struck harder than `contact_speed`, and the hand starting a push). Subscribes `hand/pose` (the hand pushes
what it feels, touch4d.physics.push), `controller/state` (the trigger plus controller motion
turns the selected object, paper §4.4; buttons run commands) and `scene/command` (the scene node's
commands, and pause, play, step [N]). The world steps at the scene's fixed rate (1 kHz by default),
as many steps as the clock says are due at each tick: the steps themselves never depend on the clock
(touch4d.physics.session journals them).
"""
from __future__ import annotations

import time

import numpy as np

from touch4d.bus import Node, Param
from touch4d.bus.ratelimit import RateLimitedPublisher
from touch4d.errors import Touch4dError
from touch4d.geometry.scene import load_scene
from touch4d.messages import ControllerState, HandPose, PhysicsContacts, PhysicsInput, SceneCommand, SceneState
from touch4d.physics.config import load_physics
from touch4d.physics.session import DEFAULT_BUTTONS, PhysicsSession, entry_to_map, split_buttons
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.scene_control import ControlConfig


class PhysicsNode(Node):
    """The scene with 4D physics: bodies fall, collide and slide; the controller still turns them."""

    default_name = "scene"
    PARAMS = {
        "scene": Param("config/scenes/physics-drop.yaml", "the scene file (with physics keys)", path="scene file"),
        "calibration": Param("config/calibration.yaml", "room -> screen calibration", path="calibration file"),
        "rate": Param(2.0, "scene/state repeats for late joiners", unit="Hz", above=0, max=1000),
        "publish_rate": Param(60.0, "scene/state while anything moves (the renderer's rate)", unit="Hz", above=0,
                              max=1000),
        "max_rate": Param(120.0, "scene/state at most this often (the scene node's)", unit="Hz", above=0, max=1000),
        "gains": Param({}, "controller motion -> rotation: {translation, rotation}"),
        "trigger_threshold": Param(0.5, "trigger value that grabs the object", above=0, max=1),
        "buttons": Param(dict(DEFAULT_BUTTONS), "controller button -> command (next, reset, projection, pause, step)"),
        "rotate": Param("object", "what the controller turns", choices=("object", "scene")),
        "paused": Param(False, "start paused (scene/command play or step to run)"),
        "max_steps": Param(200, "most steps per tick: a slower machine runs slow motion rather than stall", min=1),
        "glove": Param("config/glove.yaml", "the glove whose samples push (as they feel)", path="glove file"),
        "push_rate": Param(40.0, "how fast a pushed object takes up the hand's speed (0: the hand pushes nothing)",
                           unit="1/s", min=0),
        "contact_speed": Param(0.05, "closing speed from which a contact is an event on physics/contacts",
                               unit="screen units/s", min=0),
    }

    def setup(self) -> None:
        p = self.params
        scene_buttons, physics_buttons = split_buttons(p["buttons"], self.param_where("buttons")[0])
        config = ControlConfig.from_params(gains=p["gains"], trigger_threshold=p["trigger_threshold"],
                                           buttons=scene_buttons, rotate=p["rotate"], spin={},
                                           source=self.param_where("gains")[0])
        glove = load_glove(p["glove"]) if p["push_rate"] > 0 else None
        self.session = PhysicsSession(load_scene(p["scene"]), load_physics(p["scene"]),
                                      load_calibration(p["calibration"]), config, physics_buttons, paused=p["paused"],
                                      glove=glove, push_rate=p["push_rate"])
        self.dt = self.session.world.dt
        for name in ("steps", "late_steps", "contact_events", "bad_commands"):
            self.count(name, 0)              # declared: every heartbeat carries them
        self.pub = self.create_publisher("scene/state", SceneState)
        self.contacts_pub = self.create_publisher("physics/contacts", PhysicsContacts)
        self.journal_pub = self.create_publisher("physics/journal", PhysicsInput)
        self.create_subscription("controller/state", ControllerState, self.on_controller, latest_only=True)
        self.create_subscription("scene/command", SceneCommand, self.on_command, optional=True)
        if glove is not None:
            self.create_subscription("hand/pose", HandPose, self.on_hand, latest_only=True)
        self.published_revision = -1
        self.clock_start: float | None = None     # the clock starts at the first tick, not during set-up
        self.clock_steps = 0
        self.create_timer(1.0 / p["publish_rate"], self.tick)
        # what a replay needs to rebuild this node (touch4d physics replay), repeated for late recorders
        self.start_args = {"scene": str(p["scene"]), "calibration": str(p["calibration"]), "glove": str(p["glove"]),
                           "push_rate": float(p["push_rate"]), "gains": dict(p["gains"]),
                           "trigger_threshold": float(p["trigger_threshold"]), "buttons": dict(p["buttons"]),
                           "rotate": str(p["rotate"])}
        self.create_timer(1.0 / p["rate"], self.publish_start)
        self.publish_start()
        # every publish, the steady one for late joiners too, keeps max_rate's spacing
        self.scene_state = RateLimitedPublisher.for_node(self, self.publish, rate=p["rate"], max_rate=p["max_rate"])
        w = self.session.world
        self.log.info("scene %s: %d bodies (%d static), %g Hz steps, gravity %s%s", p["scene"], len(w.names),
                      int(w.static.sum()), 1.0 / self.dt, w.gravity.tolist(), ", paused" if p["paused"] else "")

    def on_controller(self, msg: ControllerState) -> None:
        self.session.on_controller(msg.position, msg.orientation, msg.trigger, msg.buttons, msg.valid)
        self.flush_journal()

    def publish_start(self) -> None:
        self.journal_pub.publish(PhysicsInput(step=0, kind="start", args=self.start_args))

    def flush_journal(self) -> None:
        """Publish the journal's new entries (a recording of them replays to the same states), then forget them."""
        for entry in self.session.journal:
            self.journal_pub.publish(PhysicsInput(step=entry.step, kind=entry.kind, args=entry_to_map(entry)))
        self.session.journal.clear()

    def on_hand(self, msg: HandPose) -> None:
        try:
            self.session.on_hand(msg.position, msg.orientation, msg.valid)
        except Touch4dError as exc:      # a pose the tactile model refuses (PoseError): no push from it
            self.warn_once(str(exc), f"hand/pose ignored: {exc}")
        self.flush_journal()

    def on_command(self, msg: SceneCommand) -> None:
        at = self.session.state.steps
        try:
            self.session.command(msg.command, msg.argument)
        except Touch4dError as exc:      # SceneCommandError, or (ConfigError) a bad scene to load: nothing changes
            self.count("bad_commands")
            self.log.warning("scene/command ignored: %s", exc)
        else:
            s = self.session
            said = msg.command + (f" {msg.argument}" if msg.argument and msg.command != "load" else "")
            self.log.info("scene/command %s at step %d: %s at step %d%s", said, at, "paused" if s.paused else "running",
                          s.state.steps, f", {s.single_steps} single steps due" if s.single_steps else "")
        self.flush_journal()

    def tick(self) -> None:
        """Run the steps the clock says are due, then publish what moved and what struck."""
        if self.clock_start is None:
            self.clock_start = time.monotonic()
        due = int((time.monotonic() - self.clock_start) / self.dt) - self.clock_steps
        if due > self.params["max_steps"]:
            self.count("late_steps", due - self.params["max_steps"])
            self.warn_once("late", f"physics falls behind the clock: at most {self.params['max_steps']} steps per "
                                   "tick, the rest dropped (slow motion)", every=10.0)
            due = self.params["max_steps"]
        self.clock_steps += due
        before = self.session.state.steps
        contacts = self.session.advance(max(due, 0))
        self.count("steps", self.session.state.steps - before)
        self.publish_contacts(contacts)
        self.flush_journal()
        self.scene_state.changed(self.session.control.scene.revision != self.published_revision)

    def publish_contacts(self, contacts) -> None:
        """Contact points that struck harder than contact_speed and carried an impulse, and pushes the hand
        started, as one physics/contacts message (the hand is body -1)."""
        floor = self.params["contact_speed"]
        columns = []                         # a, b, points, normals, impulses, speeds of each source
        for c in contacts:
            m = (c.speed < -floor) & (c.impulse > 0)
            if m.any():
                columns.append((c.a[m], c.b[m], c.points[m], c.normals[m], c.impulse[m], -c.speed[m]))
        events = [e for e in self.session.hand_events if e.speed > floor]
        self.session.hand_events.clear()
        if events:
            columns.append((np.full(len(events), -1), np.array([e.body for e in events]),
                            np.array([e.point for e in events]), np.array([e.normal for e in events]),
                            np.array([e.impulse for e in events]), np.array([e.speed for e in events])))
        if not columns:
            return
        a, b, points, normals, impulses, speeds = (np.concatenate(column) for column in zip(*columns))
        self.count("contact_events", len(a))
        s = self.session.state
        self.contacts_pub.publish(PhysicsContacts(
            names=list(self.session.world.names), a=a.astype(np.int64), b=b.astype(np.int64), points=points,
            normals=normals, impulses=impulses,
            speeds=speeds, step=int(s.steps), time=float(s.time)))

    def publish(self) -> None:
        self.pub.publish(self.session.message())
        self.published_revision = self.session.control.scene.revision

    def on_shutdown(self) -> None:
        c = self.stats_flat()            # one count of steps (the world's own restarts at each reset)
        self.log.info("%d steps run (%d more dropped behind the clock, %.3f s simulated since the last reset), "
                      "%d contact events, %d bad commands", c.get("steps", 0), c.get("late_steps", 0),
                      self.session.state.time, c.get("contact_events", 0), c.get("bad_commands", 0))


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)

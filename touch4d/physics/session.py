"""The physics node's logic without a bus: the scene node's controller and commands over a physics world.

Every input (a controller sample, a hand pose, a command) is applied between two fixed steps and written to the
journal with the step it was applied before; `replay(...)` feeds a journal to a fresh session and
reaches the same states, byte for byte, since `world.step` is a pure function. Commands beyond the
scene node's: `pause`, `play` (`pause` toggles when already paused) and `step [N]` (N steps while
paused); `reset` puts bodies back where the scene file has them, moving as the file says; `load` (scene-file
text) builds the new scene's world with its physics keys. The steps run are journaled too, so a replay
needs no clock.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from touch4d.errors import ConfigError
from touch4d.geometry.scene import Scene
from touch4d.messages import PHYSICS_COMMANDS
from touch4d.tracking.calibration import Calibration
from touch4d.tracking.scene_control import BUTTON_COMMANDS, ControlConfig, SceneCommandError, SceneControl

from .bivector import vee
from .config import PhysicsConfig
from .push import Touch, push_impulses, touch_from_stimulus
from .world import Contacts, build_world, step, with_pose

DEFAULT_BUTTONS = {"menu": "next", "grip": "reset", "trackpad": "projection", "thumbstick": "pause"}
MAX_SINGLE_STEPS = 100000


@dataclass(frozen=True)
class JournalEntry:
    """An input and the step count it was applied at."""

    step: int
    kind: str          # "controller", "hand", "command" or "run" (args: the number of steps)
    args: tuple


_ARG_NAMES = {"controller": ("position", "orientation", "trigger", "buttons", "valid"),
              "hand": ("position", "orientation", "valid"), "command": ("command", "argument"), "run": ("steps",)}


def entry_to_map(entry: JournalEntry) -> dict:
    """A journal entry's arguments by name (the `args` of a `physics/journal` message)."""
    return {name: list(value) if isinstance(value, tuple) else value
            for name, value in zip(_ARG_NAMES[entry.kind], entry.args)}


def entry_from_map(step: int, kind: str, args: dict) -> JournalEntry:
    """The journal entry of a `physics/journal` message (ValueError names what is missing)."""
    if kind not in _ARG_NAMES:
        raise ValueError(f"physics/journal: unknown kind {kind!r}")
    try:
        values = [args[name] for name in _ARG_NAMES[kind]]
    except KeyError as exc:
        raise ValueError(f"physics/journal: a {kind} entry without {exc.args[0]!r}") from None
    values = [tuple(v) if isinstance(v, (list, tuple)) else v for v in values]
    return JournalEntry(int(step), kind, tuple(values))


class HandEvent(NamedTuple):
    """The hand starting to push a body: a contact event with the hand as body a."""

    body: int
    point: np.ndarray             # (4,) world, the push's centre
    normal: np.ndarray            # (4,) the push's direction
    impulse: float                # its first step's impulse
    speed: float                  # the hand's speed, screen units/s


class PhysicsSession:
    """A physics world driven like the scene node: controller rotation (paper §4.4), buttons, commands."""

    def __init__(self, scene: Scene, physics: PhysicsConfig | None, calibration: Calibration,
                 config: ControlConfig | None = None, physics_buttons: dict | None = None, paused: bool = False,
                 glove=None, push_rate: float = 0.0):
        self.control = SceneControl(scene, calibration, config)
        self.world, self.initial = build_world(self.control.scene, physics)
        self.control.fix(np.flatnonzero(self.world.static))     # a static body is never the controller's
        self.state = self.initial
        self.paused = paused
        self.single_steps = 0
        self.physics_buttons = dict(physics_buttons or {})
        self._held: frozenset[str] = frozenset()
        self.journal: list[JournalEntry] = []
        self.glove = glove                    # the hand pushes (push_rate > 0) with the glove's samples
        self.push_rate = push_rate
        self.touch = Touch.none()
        self._hand: tuple[np.ndarray, int] | None = None    # last valid hand position and its step
        self._pushed: frozenset[int] = frozenset()
        self.hand_events: list[HandEvent] = []
        self._turn_rate, self._turn_step = np.zeros(6), None
        self._sync_scene()

    # ---- inputs (between steps) -------------------------------------------------------------------

    def on_controller(self, position_m, quat_room, trigger: float, buttons, valid: bool = True) -> bool:
        """One controller sample: physics buttons (pause, step), then the scene node's handling."""
        self.journal.append(JournalEntry(self.state.steps, "controller", (
            tuple(map(float, position_m)), tuple(map(float, quat_room)), float(trigger), tuple(buttons), bool(valid))))
        now = frozenset(buttons)
        changed = False
        for button in sorted(now - self._held):
            command = self.physics_buttons.get(button)
            if command is not None:
                changed |= self._physics_command(command, "")
        self._held = now
        before = self._poses()
        holding = self.control.holding
        changed |= self.control.on_controller(position_m, quat_room, trigger, buttons, valid)
        self._take_poses(before)
        self._throw(before, holding, self.control.holding)
        return changed

    def _throw(self, before, was_holding: bool, holding: bool) -> None:
        """While the trigger holds the selected body, it turns with the controller only (no spin of its own) and
        its rate is measured; released, it keeps turning at that rate: the controller throws it (§4.4 mapping)."""
        index = self.control.scene.selected
        if index < 0 or self.world.static[index]:
            return
        if holding:
            obj = self.control.scene.objects[index]
            rate = np.zeros(6)
            if was_holding and self._turn_step is not None and self.state.steps > self._turn_step:
                delta = obj.orientation @ before[index][1].T
                rate = vee(delta) / ((self.state.steps - self._turn_step) * self.world.dt)
            self._turn_rate, self._turn_step = rate, self.state.steps
            self.state = with_pose(self.world, self.state, index, angular_velocity_world=np.zeros(6))
        elif was_holding:
            self.state = with_pose(self.world, self.state, index, angular_velocity_world=self._turn_rate)
            self._turn_rate, self._turn_step = np.zeros(6), None

    def on_hand(self, position, quat_xyzw, valid: bool = True) -> None:
        """A hand pose (screen units): what it touches now pushes while the hand moves (`touch4d.physics.push`)."""
        self.journal.append(JournalEntry(self.state.steps, "hand", (
            tuple(map(float, position)), tuple(map(float, quat_xyzw)), bool(valid))))
        if self.glove is None or self.push_rate <= 0:
            return
        if not valid:
            self.touch, self._hand = Touch.none(), None
            return
        from touch4d.tactile.stimulus import compute_stimulus

        position = np.asarray(position, dtype=float)
        velocity = np.zeros(3)
        if self._hand is not None and self.state.steps > self._hand[1]:
            velocity = (position - self._hand[0]) / ((self.state.steps - self._hand[1]) * self.world.dt)
        elif self._hand is not None:
            velocity = self.touch.velocity
        self._hand = (position, self.state.steps)
        scene = self.control.scene
        st = compute_stimulus(self.glove, scene.ray_caster(), position, quat_xyzw)
        self.touch = touch_from_stimulus(st.positions, st.l, st.hit, st.h, velocity, scene.perspective_eye)

    def command(self, name: str, argument: str = "") -> bool:
        """A `scene/command`: the physics ones here, the others as the scene node does (ValueError if bad)."""
        at = self.state.steps
        if name in PHYSICS_COMMANDS:
            result = self._physics_command(name, argument)
        else:
            before = self._poses()
            result = self.control.command(name, argument)
            if name == "load":                  # another scene (file text): new bodies, its physics keys
                self._rebuild(argument)
            elif name == "reset":
                self.state = self.initial
                self.touch, self._hand, self._pushed = Touch.none(), None, frozenset()
                self._sync_scene()
            else:
                self._take_poses(before)
        self.journal.append(JournalEntry(at, "command", (name, argument)))
        return result

    def _physics_command(self, name: str, argument: str) -> bool:
        if name == "pause":
            self.paused = not self.paused
        elif name == "play":
            self.paused = False
        else:
            text = argument.strip() or "1"
            try:
                count = int(text)
            except ValueError:
                count = -1
            if not 0 < count <= MAX_SINGLE_STEPS:
                raise SceneCommandError(f"step: expected a number of steps 1..{MAX_SINGLE_STEPS}, got {argument!r}")
            self.paused = True
            self.single_steps += count
        return False

    # ---- stepping ---------------------------------------------------------------------------------

    def advance(self, steps: int) -> list[Contacts]:
        """Run the `steps` fixed steps that are due (while paused: the single steps asked instead);
        returns their contacts."""
        if self.paused:
            steps, self.single_steps = self.single_steps, 0
        return self.run(steps)

    def run(self, steps: int) -> list[Contacts]:
        """Exactly `steps` fixed steps, journaled."""
        out = []
        for _ in range(steps):
            impulses = push_impulses(self.world, self.state, self.touch, self.push_rate) if len(self.touch.points) else None
            if impulses is not None:
                self._hand_events(impulses)
            self.state, contacts = step(self.world, self.state, impulses)
            out.append(contacts)
        if steps:
            self.journal.append(JournalEntry(self.state.steps - steps, "run", (steps,)))
            self._sync_scene()
        return out

    def _hand_events(self, impulses) -> None:
        """A push that starts on an object is a contact event (the hand as body -1)."""
        pushed = frozenset(int(b) for b in impulses[:, 0])
        for body in sorted(pushed - self._pushed):
            rows = impulses[impulses[:, 0] == body]
            total = rows[:, 5:9].sum(axis=0)
            size = float(np.linalg.norm(total))
            point = (rows[:, 1:5] * np.linalg.norm(rows[:, 5:9], axis=1)[:, None]).sum(axis=0) / max(
                float(np.linalg.norm(rows[:, 5:9], axis=1).sum()), 1e-300)
            self.hand_events.append(HandEvent(body, point, total / size if size > 0 else total, size,
                                              float(np.linalg.norm(self.touch.velocity))))
        self._pushed = pushed

    # ---- the scene it shows -----------------------------------------------------------------------

    def _rebuild(self, text: str) -> None:
        """The world of the scene the control now holds, with the physics of the scene-file text it came from."""
        from touch4d.schema import parse_yaml

        from .config import parse_physics

        source = "scene/command load"
        self.world, self.initial = build_world(self.control.scene, parse_physics(parse_yaml(text, source), source))
        self.state = self.initial
        self.touch, self._hand, self._pushed = Touch.none(), None, frozenset()
        self._turn_rate, self._turn_step = np.zeros(6), None

    def _poses(self):
        return [(o.position.copy(), o.orientation.copy()) for o in self.control.scene.objects]

    def _take_poses(self, before) -> None:
        """Objects the controller turned (or commands moved) are placed so in the physics state."""
        for i, (obj, (pos, rot)) in enumerate(zip(self.control.scene.objects, before)):
            if not (np.array_equal(obj.position, pos) and np.array_equal(obj.orientation, rot)):
                self.state = with_pose(self.world, self.state, i, position=obj.position, orientation=obj.orientation)

    def _sync_scene(self) -> None:
        """The scene's objects where the bodies are (a new revision when anything moved)."""
        from .world import object_positions

        positions = object_positions(self.world, self.state)
        moved = False
        for i, obj in enumerate(self.control.scene.objects):
            if not (np.array_equal(obj.position, positions[i]) and np.array_equal(obj.orientation, self.state.r[i])):
                obj.position = positions[i].copy()
                obj.orientation = self.state.r[i].copy()
                moved = True
        if moved:
            self.control.scene.revision += 1

    def message(self):
        return self.control.message()


def split_buttons(buttons: dict, source="buttons") -> tuple[dict, dict]:
    """A button map split into the scene node's commands and the physics commands (a ConfigError names a bad
    one, in `source`)."""
    scene, physics = {}, {}
    for button, command in buttons.items():
        if command in PHYSICS_COMMANDS:
            physics[button] = command
        elif command in BUTTON_COMMANDS:
            scene[button] = command
        else:
            raise ConfigError(source, f"buttons.{button}", f"one of {', '.join(BUTTON_COMMANDS + PHYSICS_COMMANDS)}",
                              got=command)
    return scene, physics


def replay(scene: Scene, physics: PhysicsConfig | None, calibration: Calibration, config: ControlConfig | None,
           physics_buttons: dict | None, journal, glove=None, push_rate: float = 0.0, after=None) -> PhysicsSession:
    """A fresh session fed a journal's inputs and steps in order: it reaches the same states, byte for byte.
    `after(session)`, if given, is called after each entry."""
    session = PhysicsSession(scene, physics, calibration, config, physics_buttons, glove=glove, push_rate=push_rate)
    for entry in journal:
        if entry.step != session.state.steps:
            raise ValueError(f"journal entry at step {entry.step} reached at step {session.state.steps}")
        if entry.kind == "controller":
            session.on_controller(*entry.args)
        elif entry.kind == "hand":
            session.on_hand(*entry.args)
        elif entry.kind == "command":
            session.command(*entry.args)
        else:
            session.run(*entry.args)
        if after is not None:
            after(session)
    return session

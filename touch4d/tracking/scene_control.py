"""The scene node's logic, without a bus: controller samples and commands in, a changed scene out.

While the trigger is held, the controller's motion between two samples turns the selected object
(or the whole scene, about its centre) by `geometry.rotation.controller_rotation` (paper §4.4):
its translation, in the screen's axes and in metres, turns the xw, yw, zw planes; its rotation
turns the yz, zx, xy planes. Button presses (edges, not levels) and `scene/command` messages
select the next object, reset the scene, switch the projection or the view, or move the slice.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import msgspec
import numpy as np

from touch4d import schema
from touch4d.errors import Touch4dError
from touch4d.schema import Finite, parse_yaml
from touch4d.geometry.rotation import PLANES, controller_rotation, plane_axes, plane_rotation, renormalize
from touch4d.geometry.scene import Scene, SceneFile, parse_scene
from touch4d.messages import PHYSICS_COMMANDS, PROJECTIONS, SCENE_COMMANDS, VIEWS
from touch4d.geometry.physics_keys import static_indices

from touch4d.geometry import quaternion
from .calibration import Calibration

DEFAULT_BUTTONS = {"menu": "next", "grip": "reset", "trackpad": "projection", "thumbstick": "view",
                   "a": "slice up", "b": "slice down", "thumbstick-up": "slice up", "thumbstick-down": "slice down"}
ROTATE_TARGETS = ("object", "scene", "none")   # none: the controller turns nothing (a study's fixed stimuli)
BUTTON_COMMANDS = ("next", "reset", "projection", "view", "slice up", "slice down")   # a button's command
SLICE_STEP = 0.05                              # screen units of w per slice up / down


class SceneCommandError(Touch4dError, ValueError):
    """A scene/command the scene cannot carry out (an unknown command, a bad argument): says what was expected."""


class Gains(msgspec.Struct, forbid_unknown_fields=True):
    """The scene node's `gains` parameter (defaults: ControlConfig's)."""

    translation: Finite | None = None
    rotation: Finite | None = None


class Spin(msgspec.Struct, forbid_unknown_fields=True):
    """The scene node's `spin` parameter: turn by itself in `plane` at `deg_per_s`."""

    plane: str
    deg_per_s: Finite = 10.0


@dataclass(frozen=True)
class ControlConfig:
    """How the controller drives the scene; every field is a scene node parameter of the same name."""

    translation_gain: float = 6.0      # radians of xw/yw/zw rotation per metre of controller travel
    rotation_gain: float = 1.0         # radians of yz/zx/xy rotation per radian the controller turns
    trigger_threshold: float = 0.5     # trigger travel above which the controller holds the object
    buttons: dict = field(default_factory=lambda: dict(DEFAULT_BUTTONS))  # button -> command
    rotate: str = "object"             # "object": the selected one; "scene": everything, about its centre;
                                       # "none": nothing
    spin_plane: str | None = None      # slow automatic rotation (the demo's turning hypercube)
    spin_deg_per_s: float = 0.0

    @classmethod
    def from_params(cls, gains: dict, trigger_threshold: float, buttons: dict, rotate: str, spin: dict,
                    source: str = "scene parameters") -> "ControlConfig":
        """Check the scene node's parameters; errors name the parameter and what was expected."""
        g = schema.convert(gains, Gains, source, "gains")
        t_gain = cls.translation_gain if g.translation is None else g.translation
        r_gain = cls.rotation_gain if g.rotation is None else g.rotation
        threshold = schema.convert(trigger_threshold, Finite, source, "trigger_threshold")
        if not 0.0 < threshold <= 1.0:
            schema.fail(source, "trigger_threshold", "a number in (0, 1]", got=threshold)
        schema.convert(buttons, dict[str, Literal[BUTTON_COMMANDS]], source, "buttons")
        rotate = schema.convert(rotate, Literal[ROTATE_TARGETS], source, "rotate")
        plane, rate = None, 0.0
        if spin:
            sp = schema.convert(spin, Spin, source, "spin")
            try:
                plane_axes(sp.plane)
            except ValueError:
                schema.fail(source, "spin.plane", f"a rotation plane ({', '.join(PLANES)})", got=sp.plane, choices=PLANES)
            plane, rate = sp.plane, sp.deg_per_s
        return cls(t_gain, r_gain, threshold, dict(buttons), rotate, plane, rate)


def controller_object(selected: int, fixed, count: int) -> int:
    """The object the controller turns: `selected` unless it is fixed (a static body), then the first of
    the `count` objects that is not, else -1 (the whole scene)."""
    if selected < 0 or selected not in fixed:
        return selected
    return next((i for i in range(count) if i not in fixed), -1)


class SceneControl:
    """The scene and what the controller does to it; every method returns whether the scene changed."""

    def __init__(self, scene: Scene, calibration: Calibration, config: ControlConfig | None = None):
        self.config = config or ControlConfig()
        self.calibration = calibration
        self.scene = scene.copy()
        if self.config.rotate == "scene":
            self.scene.selected = -1
        self._initial = self.scene.copy()
        self._grab: tuple[np.ndarray, np.ndarray] | None = None
        self._held: frozenset[str] = frozenset()
        self.fixed: frozenset[int] = frozenset()    # objects the controller never turns (physics' static bodies)

    def fix(self, indices) -> None:
        """Objects the controller never turns (a static floor): never selected, `next` passes them by, the
        whole scene turns without them; a selection on one moves to the first that may move."""
        self.fixed = frozenset(int(i) for i in indices)
        for scene in (self.scene, self._initial):
            scene.selected = controller_object(scene.selected, self.fixed, len(scene.objects))

    # ---- controller ----------------------------------------------------------------------------

    @property
    def holding(self) -> bool:
        """The trigger holds the selected object: the controller's motion turns it."""
        return self._grab is not None

    def on_controller(self, position_m, quat_room, trigger: float, buttons, valid: bool = True) -> bool:
        """One controller sample (room frame): button edges run commands, a held trigger rotates."""
        changed = False
        now = frozenset(buttons)
        for button in sorted(now - self._held):
            command = self.config.buttons.get(button)
            if command is not None:
                changed |= self.command(*command.split(" ", 1))
        self._held = now
        if not valid or trigger < self.config.trigger_threshold or self.config.rotate == "none":
            self._grab = None
            return changed
        position = np.asarray(position_m, dtype=float)
        rotation = quaternion.canonical(quat_room)
        grab, self._grab = self._grab, (position, rotation)
        if grab is None:
            return changed  # the first held sample only anchors the motion
        d_trans = self.calibration.direction_to_screen(position - grab[0])
        d_rot = self.calibration.direction_to_screen(
            quaternion.to_rotvec(quaternion.multiply(rotation, quaternion.conjugate(grab[1]))))
        if not (d_trans.any() or d_rot.any()):
            return changed
        gains = (self.config.translation_gain, self.config.rotation_gain)
        self.rotate(controller_rotation(d_trans, d_rot, gains))
        return True

    def advance(self, dt: float) -> bool:
        """The slow automatic spin over `dt` seconds, if configured."""
        if self.config.spin_plane is None or self.config.spin_deg_per_s == 0.0 or dt <= 0:
            return False
        self.rotate(plane_rotation(self.config.spin_plane, np.radians(self.config.spin_deg_per_s * dt)))
        return True

    def rotate(self, r: np.ndarray) -> None:
        """Turn the selected object about its centre, or (selected -1) every object about the scene's centre."""
        objects = self.scene.objects
        if self.scene.selected >= 0:
            obj = objects[self.scene.selected]
            obj.orientation = renormalize(r @ obj.orientation)
        else:
            objects = [o for i, o in enumerate(objects) if i not in self.fixed]
            if not objects:
                return
            centre = np.mean([o.position for o in objects], axis=0)
            for obj in objects:
                obj.position = centre + r @ (obj.position - centre)
                obj.orientation = renormalize(r @ obj.orientation)
        self.scene.revision += 1

    # ---- commands ------------------------------------------------------------------------------

    def command(self, name: str, argument: str = "") -> bool:
        """next | select ARG (index, name, or 'scene') | reset | projection [orthographic|perspective|toggle]
        | view [projection|slice|both|next] | slice C|+D|-D|up|down | load SCENE-FILE-TEXT.

        A bad command or argument raises SceneCommandError saying what was expected.
        """
        if name == "next":
            return self._select(self._next_index())
        if name == "select":
            return self._select(self._parse_selection(argument))
        if name == "reset":
            revision = self.scene.revision
            self.scene = self._initial.copy()
            self.scene.revision = revision + 1
            self._grab = None
            return True
        if name == "projection":
            return self._projection(argument)
        if name == "view":
            return self._view(argument)
        if name == "slice":
            return self._slice(argument)
        if name == "load":
            return self.load(argument)
        if name in PHYSICS_COMMANDS:
            raise SceneCommandError(f"{name!r} is a physics command and the scene node runs no physics: run the "
                                    f"physics node in its place (touch4d launch demo scene:=physics "
                                    f"scene.scene:=config/scenes/physics-drop.yaml)")
        own = [c for c in SCENE_COMMANDS if c not in PHYSICS_COMMANDS]
        raise SceneCommandError(f"unknown scene command {name!r}; expected one of {', '.join(own)} (and the physics "
                                f"node's {', '.join(PHYSICS_COMMANDS)})")

    def load(self, text: str, source: str = "scene/command load") -> bool:
        """Replace the whole scene by one given as scene-file text (YAML); `reset` returns to it, and its
        static bodies (physics keys) are never the controller's. A bad scene raises ConfigError (a
        Touch4dError) naming `source` and the key, and the scene stays."""
        data = parse_yaml(text, source)
        scene = parse_scene(data, source)
        static = static_indices([o.physics for o in schema.convert(data, SceneFile, source).objects])
        if self.config.rotate == "scene":
            scene.selected = -1
        scene.revision = self.scene.revision + 1
        self.scene = scene
        self._initial = scene.copy()
        self.fix(static)
        self._grab = None
        return True

    def _next_index(self) -> int:
        order = [i for i in range(len(self.scene.objects)) if i not in self.fixed] + [-1]
        if len(order) <= 2:
            return self.scene.selected  # one object: it is the whole scene
        return order[(order.index(self.scene.selected) + 1) % len(order)]

    def _parse_selection(self, argument: str) -> int:
        argument = argument.strip()
        if argument in ("scene", "-1"):
            return -1
        names = [o.name for o in self.scene.objects]
        try:
            index = names.index(argument) if argument in names else int(argument)
        except ValueError:
            index = None
        if index is None or not 0 <= index < len(names):
            raise SceneCommandError(f"select: expected an object index 0..{len(names) - 1}, a name ({', '.join(names)}) "
                             f"or 'scene', got {argument!r}")
        if index in self.fixed:
            movable = ", ".join(n for i, n in enumerate(names) if i not in self.fixed) or "none"
            raise SceneCommandError(f"select: {names[index]!r} (object {index}) is static: the controller never turns "
                                    f"it; expected one that moves ({movable}) or 'scene'")
        return index

    def _select(self, index: int) -> bool:
        if index == self.scene.selected:
            return False
        self.scene.selected = index
        self._grab = None
        self.scene.revision += 1
        return True

    def _projection(self, argument: str) -> bool:
        argument = argument.strip() or "toggle"
        if argument == "toggle":
            target = PROJECTIONS[1 - PROJECTIONS.index(self.scene.projection)]
        elif argument in PROJECTIONS:
            target = argument
        else:
            raise SceneCommandError(f"projection: expected {', '.join(PROJECTIONS)} or toggle, got {argument!r}")
        if target == self.scene.projection:
            return False
        self.scene.projection = target
        self.scene.revision += 1
        return True

    def _view(self, argument: str) -> bool:
        argument = argument.strip() or "next"
        if argument == "next":
            target = VIEWS[(VIEWS.index(self.scene.view) + 1) % len(VIEWS)]
        elif argument in VIEWS:
            target = argument
        else:
            raise SceneCommandError(f"view: expected {', '.join(VIEWS)} or next, got {argument!r}")
        if target == self.scene.view:
            return False
        self.scene.view = target
        self.scene.revision += 1
        return True

    def _slice(self, argument: str) -> bool:
        """Move the slice: to w = C (a number), or up (+w, away from the viewer) / down by D (default
        one step)."""
        words = argument.split()
        try:
            if words and words[0] in ("up", "down") and len(words) <= 2:
                step = float(words[1]) if len(words) == 2 else SLICE_STEP
                target = self.scene.slice_w + (step if words[0] == "up" else -step)
            elif len(words) == 1:
                target = float(words[0])
            else:
                target = None
        except ValueError:
            target = None
        if target is None or not np.isfinite(target):
            raise SceneCommandError(f"slice: expected where to cut (a number, w = C) or up / down [D], "
                                    f"got {argument!r}")
        if target == self.scene.slice_w:
            return False
        self.scene.slice_w = float(target)
        self.scene.revision += 1
        return True

    def message(self):
        """The current scene as a `scene/state` message."""
        return self.scene.to_message()

"""Room (metres) <-> 3D screen (screen units): the one place tracked poses change frame and unit.

The 3D screen is the cube [-1, 1]^3 of the 4D world's hyperplane w = 0 (paper §4.2, Fig. 16).
In the room it is a cube `edge_m` metres wide, centred at `center_m`, its axes turned by
`rotation_deg` from the room's. The glove hand sits at a fixed offset from the controller it
holds (`hand_in_controller` for an OpenVR controller, `hand_in_grip` for a WebXR grip space).
A headset places the screen in front of its user (`placed_in_front`) and stores the placement
back in the file (`save_screen_placement`). Quaternions are (x, y, z, w), as on the wire.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import numpy as np
from scipy.spatial.transform import Rotation

from touch4d import schema
from touch4d.atomic import write_atomic
from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError
from touch4d.schema import Finite, Positive

from touch4d.geometry import quaternion
from .config import CONFIG_DIR

DEFAULT_CALIBRATION = CONFIG_DIR / "calibration.yaml"
AXES = ("x", "y", "z")


Vec3 = Annotated[tuple[Finite, Finite, Finite], msgspec.Meta(description="a list of 3 finite numbers")]
AxisStep = Annotated[tuple[Literal["x", "y", "z"], Finite],
                     msgspec.Meta(description="[axis, degrees] with axis one of x, y, z")]
Steps = Annotated[list[AxisStep], msgspec.Meta(description="a list of [axis, degrees] steps, axis one of x, y, z")]


def rotation_from_steps(steps, file=None, key: str = "rotation_deg") -> Rotation:
    """A rotation from [[axis, degrees], ...] applied in order (the first step acts first)."""
    return _steps(schema.convert(list(steps) if isinstance(steps, tuple) else steps, Steps, file, key))


def _steps(steps) -> Rotation:
    rot = Rotation.identity()
    for axis, degrees in steps:
        rot = Rotation.from_euler(axis, float(degrees), degrees=True) * rot
    return rot


class ScreenSection(msgspec.Struct, forbid_unknown_fields=True):
    center_m: Vec3                       # screen centre in the room, metres
    edge_m: Positive                     # the screen cube's edge, metres
    rotation_deg: Steps = []             # screen axes -> room axes


class HandMount(msgspec.Struct, forbid_unknown_fields=True):
    """Where the glove hand sits in a tracked device's frame."""

    position_m: Vec3 = (0.0, 0.0, 0.0)
    rotation_deg: Steps = []


class Placement(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """Where a headset's re-centre puts the screen: ahead of the eyes and below them, metres."""

    distance_m: Positive = 0.45
    below_eye_m: Finite = 0.35


class CalibrationFile(msgspec.Struct, forbid_unknown_fields=True):
    """A calibration file (config/calibration.yaml), as written."""

    screen: ScreenSection
    hand_in_controller: HandMount = msgspec.field(default_factory=HandMount)
    hand_in_grip: HandMount = msgspec.field(default_factory=HandMount)
    placement: Placement = msgspec.field(default_factory=Placement)


@dataclass(frozen=True)
class Calibration:
    """Where the 3D screen stands in the room and where the hand sits on the controller."""

    center_m: np.ndarray                 # (3,) screen centre in the room, metres
    screen_rotation: Rotation            # screen axes -> room axes
    edge_m: float                        # physical edge length of the screen cube, metres
    hand_offset_m: np.ndarray            # (3,) hand origin in the controller's frame, metres
    hand_rotation: Rotation              # hand frame -> controller frame

    def __post_init__(self):
        # numpy forms of the two rotations for the per-pose path (see quaternion.py)
        object.__setattr__(self, "_screen_q", quaternion.canonical(self.screen_rotation.as_quat()))
        object.__setattr__(self, "_screen_m", quaternion.to_matrix(self._screen_q))
        object.__setattr__(self, "_hand_q", quaternion.canonical(self.hand_rotation.as_quat()))
        # ... and as Python floats for one pose's few steps (hand_from_controller)
        object.__setattr__(self, "_floats", (tuple(quaternion.conjugate(self._screen_q).tolist()),
                                             tuple(self._hand_q.tolist()),
                                             tuple(np.asarray(self.hand_offset_m, dtype=float).tolist()),
                                             tuple(np.asarray(self.center_m, dtype=float).tolist()),
                                             tuple(map(tuple, self._screen_m.T.tolist()))))

    @property
    def units_per_metre(self) -> float:
        return 2.0 / self.edge_m

    # ---- points and directions ------------------------------------------------------------------

    def room_to_screen(self, points_m) -> np.ndarray:
        """Room points (..., 3) in metres -> screen points in screen units."""
        return (np.asarray(points_m, dtype=float) - self.center_m) @ self._screen_m * self.units_per_metre

    def screen_to_room(self, points) -> np.ndarray:
        """Screen points (..., 3) in screen units -> room points in metres."""
        return np.asarray(points, dtype=float) @ self._screen_m.T / self.units_per_metre + self.center_m

    def direction_to_screen(self, vectors_m) -> np.ndarray:
        """Room vectors (e.g. a controller displacement) turned into the screen's axes, still in metres."""
        return np.asarray(vectors_m, dtype=float) @ self._screen_m

    def orientation_to_screen(self, quat_room) -> np.ndarray:
        """An orientation (object frame -> room) as object frame -> screen, quaternion (x, y, z, w)."""
        return quaternion.canonical(quaternion.multiply(quaternion.conjugate(self._screen_q), np.asarray(quat_room, float)))

    # ---- the hand held on the controller --------------------------------------------------------

    def hand_from_controller(self, position_m, quat_room) -> tuple[np.ndarray, np.ndarray]:
        """Controller pose in the room -> the glove hand's pose in screen coordinates."""
        # on Python floats: a page's every input comes here, and numpy costs ~1 us per step on 3- and 4-vectors
        screen_conj, hand_q, offset, center, screen_columns = self._floats
        controller = quaternion.unit(np.asarray(quat_room, dtype=float).tolist())
        turned = quaternion.rotate(controller, offset)
        d = [p + t - c for p, t, c in zip(np.asarray(position_m, dtype=float).tolist(), turned, center)]
        upm = self.units_per_metre
        # room_to_screen: (p - centre) @ screen matrix, in screen units
        position = np.array([(d[0] * m0 + d[1] * m1 + d[2] * m2) * upm for m0, m1, m2 in screen_columns])
        hand = quaternion.product(quaternion.product(screen_conj, controller), hand_q)
        return position, np.array(quaternion.unit(hand))

    def controller_from_hand(self, position, quat_screen) -> tuple[np.ndarray, np.ndarray]:
        """The glove hand's pose in screen coordinates -> the controller's pose in the room (inverse of above)."""
        hand = quaternion.canonical(quat_screen)
        controller = quaternion.canonical(quaternion.multiply(quaternion.multiply(self._screen_q, hand),
                                                              quaternion.conjugate(self._hand_q)))
        position_m = self.screen_to_room(position) - quaternion.to_matrix(controller) @ self.hand_offset_m
        return position_m, controller


    def placed_in_front(self, head_position_m, head_quat, distance_m: float, below_eye_m: float) -> "Calibration":
        """This calibration with the screen moved in front of a head: its centre `distance_m` ahead
        of the eyes along the horizontal gaze and `below_eye_m` below them, turned about the room's
        vertical (+y) to face the user (room frame: +y up, the user looking along -z at yaw 0)."""
        yaw = yaw_of(head_quat)
        forward = np.array([-math.sin(yaw), 0.0, -math.cos(yaw)])
        center = np.asarray(head_position_m, dtype=float) + distance_m * forward - np.array([0.0, below_eye_m, 0.0])
        return replace(self, center_m=center, screen_rotation=Rotation.from_euler("y", yaw))


def yaw_of(quat) -> float:
    """The heading (radians about +y, 0 = looking along -z) of an orientation, ignoring pitch and roll."""
    forward = Rotation.from_quat(np.asarray(quat, dtype=float)).apply([0.0, 0.0, -1.0])
    if math.hypot(forward[0], forward[2]) < 1e-6:  # looking straight up or down: use the head's up axis
        forward = -Rotation.from_quat(np.asarray(quat, dtype=float)).apply([0.0, 1.0, 0.0]) * np.sign(forward[1])
    return math.atan2(-forward[0], -forward[2])


HAND_KEYS = ("hand_in_controller", "hand_in_grip")


def read_calibration_file(path=None) -> tuple[CalibrationFile, Path]:
    """The calibration file at `path` (default config/calibration.yaml), checked, and its path."""
    path = resolve_path(path if path is not None else "config/calibration.yaml", what="calibration file")
    return schema.load(path, CalibrationFile, "calibration file"), path


def load_calibration(path=None, hand: str = "hand_in_controller") -> Calibration:
    """Read config/calibration.yaml (or `path`); a bad file stops with the file, key and what was expected.
    `hand` names the section placing the glove hand on the tracked device (one of HAND_KEYS)."""
    data, _ = read_calibration_file(path)
    mount = getattr(data, hand)
    return Calibration(
        center_m=np.array(data.screen.center_m, dtype=float), screen_rotation=_steps(data.screen.rotation_deg),
        edge_m=data.screen.edge_m,
        hand_offset_m=np.array(mount.position_m, dtype=float), hand_rotation=_steps(mount.rotation_deg),
    )


def load_placement(path=None) -> Placement:
    """The `placement:` section of a calibration file (defaults when absent)."""
    return read_calibration_file(path)[0].placement


def save_screen_placement(path, calibration: Calibration) -> None:
    """Write the screen's centre and rotation into a calibration file, keeping everything else in it
    (comments included). The rotation is stored as its yaw about +y when it is one, else as x-y-z steps."""
    path = Path(path)
    text = path.read_text()
    center = "[" + ", ".join(f"{v:.4f}" for v in calibration.center_m) + "]"
    rotvec = calibration.screen_rotation.as_rotvec()
    if abs(rotvec[0]) < 1e-9 and abs(rotvec[2]) < 1e-9:
        steps = [["y", math.degrees(rotvec[1])]] if abs(rotvec[1]) > 1e-9 else []
    else:
        steps = [[axis, float(a)] for axis, a in zip("xyz", calibration.screen_rotation.as_euler("xyz", degrees=True))]
    rotation = "[" + ", ".join(f"[{axis}, {deg:.3f}]" for axis, deg in steps) + "]"
    for key, value in (("center_m", center), ("rotation_deg", rotation)):
        # The key's line inside the `screen:` block (indented), its value replaced, its comment kept.
        pattern = re.compile(rf"(^screen:\s*\n(?:[ \t]+.*\n|\s*\n)*?[ \t]+{key}:[ \t]*)(\[[^#\n]*\]|[^#\n]*?)([ \t]*(#.*)?)$",
                             re.MULTILINE)
        text, n = pattern.subn(lambda m: m.group(1) + value + m.group(3), text, count=1)
        if n != 1:
            raise ConfigError(path, f"screen.{key}", "a one-line value under `screen:` to update")
    write_atomic(path.resolve(), text)   # whole or not at all (a link of the user's is followed: its file replaced)

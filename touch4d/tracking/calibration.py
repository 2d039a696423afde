"""Room (metres) <-> 3D screen (screen units): the one place tracked poses change frame and unit.

The 3D screen is the cube [-1, 1]^3 of the 4D world's hyperplane w = 0 (paper §4.2, Fig. 16).
In the room it is a cube `edge_m` metres wide, centred at `center_m`, its axes turned by
`rotation_deg` from the room's. The glove hand sits at a fixed offset from the controller it
holds (`hand_in_controller`). Quaternions are (x, y, z, w), as on the wire.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.configfile import resolve_path
from touch4d.errors import ConfigError

from . import quaternion
from .config import CONFIG_DIR, get_map, get_number, get_vector, read_yaml

DEFAULT_CALIBRATION = CONFIG_DIR / "calibration.yaml"
AXES = ("x", "y", "z")


def rotation_from_steps(steps, file=None, key: str = "rotation_deg") -> Rotation:
    """A rotation from [[axis, degrees], ...] applied in order (the first step acts first)."""
    if not isinstance(steps, list):
        raise ConfigError(file, key, "a list of [axis, degrees] steps, axis one of x, y, z", got=steps)
    rot = Rotation.identity()
    for index, step in enumerate(steps):
        if (
            not isinstance(step, (list, tuple))
            or len(step) != 2
            or step[0] not in AXES
            or isinstance(step[1], bool)
            or not isinstance(step[1], (int, float))
        ):
            raise ConfigError(file, f"{key}[{index}]", "[axis, degrees] with axis one of x, y, z", got=step)
        rot = Rotation.from_euler(step[0], float(step[1]), degrees=True) * rot
    return rot


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
        controller = quaternion.canonical(quat_room)
        hand_room = np.asarray(position_m, dtype=float) + quaternion.to_matrix(controller) @ self.hand_offset_m
        hand = quaternion.multiply(quaternion.multiply(quaternion.conjugate(self._screen_q), controller), self._hand_q)
        return self.room_to_screen(hand_room), quaternion.canonical(hand)

    def controller_from_hand(self, position, quat_screen) -> tuple[np.ndarray, np.ndarray]:
        """The glove hand's pose in screen coordinates -> the controller's pose in the room (inverse of above)."""
        hand = quaternion.canonical(quat_screen)
        controller = quaternion.canonical(quaternion.multiply(quaternion.multiply(self._screen_q, hand),
                                                              quaternion.conjugate(self._hand_q)))
        position_m = self.screen_to_room(position) - quaternion.to_matrix(controller) @ self.hand_offset_m
        return position_m, controller


def load_calibration(path=None) -> Calibration:
    """Read config/calibration.yaml (or `path`); a bad file stops with the file, key and what was expected."""
    path = resolve_path(path if path is not None else "config/calibration.yaml", what="calibration file")
    data = read_yaml(path)
    screen = get_map(data, "screen", path)
    hand = get_map(data, "hand_in_controller", path, default={})
    return Calibration(
        center_m=get_vector(screen, "center_m", path, 3, "screen."),
        screen_rotation=rotation_from_steps(screen.get("rotation_deg", []), path, "screen.rotation_deg"),
        edge_m=get_number(screen, "edge_m", path, "screen.", positive=True),
        hand_offset_m=get_vector(hand, "position_m", path, 3, "hand_in_controller.", default=[0, 0, 0]),
        hand_rotation=rotation_from_steps(hand.get("rotation_deg", []), path, "hand_in_controller.rotation_deg"),
    )

"""A hand steered by keyboard and mouse (the renderer window's `ui/input`), integrated step by step.

Keys (held): a/d move the hand along -x/+x, q/e along -y/+y, w/s along -z/+z (into / out of the
screen); the arrows turn it (left/right about y, up/down about x), z/c roll it about z; left_shift
slows everything to a quarter; space holds the trigger. n, r, p hold the controller's 'menu' (next
object), 'grip' (reset) and 'trackpad' (projection) buttons, m, k, j its 'thumbstick' (the next view:
projection, slice, both), 'a' and 'b' (the slice one step up / down in w); pressing h brings the
hand home.
Fingers: hold 1 .. 5 to curl the thumb .. little finger, f to make a fist, v to spread them (they
straighten again when released). Mouse drags hold the trigger: with the left button they turn the
hand (and so the selected object's yz/zx planes), with the right button they move it in x/y (the
xw/yw planes).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from touch4d.geometry import quaternion
from touch4d.hands import FINGER_NAMES, HandShape

from .paths import PathSample

MOVE_KEYS = {"d": (0, 1.0), "a": (0, -1.0), "e": (1, 1.0), "q": (1, -1.0), "s": (2, 1.0), "w": (2, -1.0)}
TURN_KEYS = {"right": (1, -1.0), "left": (1, 1.0), "up": (0, -1.0), "down": (0, 1.0), "c": (2, -1.0), "z": (2, 1.0)}
BUTTON_KEYS = {"n": "menu", "r": "grip", "p": "trackpad", "m": "thumbstick", "k": "a", "j": "b"}
SLOW_KEYS = ("left_shift", "right_shift")
FINGER_KEYS = {str(k + 1): finger for k, finger in enumerate(FINGER_NAMES)}   # 1 thumb .. 5 little
FIST_KEY, SPREAD_KEY = "f", "v"
LEFT_BUTTON, RIGHT_BUTTON = 1, 2


@dataclass(frozen=True)
class DesktopConfig:
    move_speed: float = 0.8          # screen units per second while a move key is held
    turn_speed_deg: float = 90.0     # degrees per second while a turn key is held
    drag_turn: float = 0.01          # radians per pixel of a left-button drag
    drag_move: float = 0.004         # screen units per pixel of a right-button drag
    limit: float = 2.0               # the hand stays within [-limit, limit]^3
    input_timeout: float = 1.0       # seconds without input after which held keys count as released
    home: tuple = (0.0, 0.0, 1.5)    # start outside the screen, in front of it
    curl_speed: float = 4.0          # a finger curls (or straightens) fully in 1 / curl_speed seconds


class DesktopHand:
    """The integrated hand pose; feed it `ui/input` messages and step it at the tracker's rate."""

    def __init__(self, config: DesktopConfig | None = None):
        self.config = config or DesktopConfig()
        self.position = np.array(self.config.home, dtype=float)
        self.rotation = Rotation.identity()
        self._keys: frozenset[str] = frozenset()
        self._buttons: frozenset[int] = frozenset()
        self._drag = np.zeros(2)
        self._last_input = -np.inf
        self.curl = {f: 0.0 for f in FINGER_NAMES}
        self.spread = 0.0

    @property
    def shape(self) -> HandShape:
        """How the fingers bend now (keys 1 .. 5, f, v)."""
        return HandShape(curl=dict(self.curl), spread=self.spread)

    def on_input(self, keys_down, pressed, mouse_delta, buttons, now: float) -> None:
        """One `ui/input` message (held keys and buttons, mouse motion since the previous one)."""
        self._keys = frozenset(keys_down)
        self._buttons = frozenset(buttons)
        self._last_input = now
        if self._buttons & {LEFT_BUTTON, RIGHT_BUTTON}:
            self._drag += np.asarray(mouse_delta, dtype=float)
        if "h" in pressed:
            self.position = np.array(self.config.home, dtype=float)
            self.rotation = Rotation.identity()

    def step(self, dt: float, now: float) -> PathSample:
        """Advance by `dt` seconds and return the hand's pose and the controller's inputs."""
        cfg = self.config
        if now - self._last_input > cfg.input_timeout:
            self._keys, self._buttons, self._drag = frozenset(), frozenset(), np.zeros(2)
        keys = self._keys
        scale = 0.25 if keys & set(SLOW_KEYS) else 1.0
        move = np.zeros(3)
        for key in keys & MOVE_KEYS.keys():
            axis, sign = MOVE_KEYS[key]
            move[axis] += sign
        turn = np.zeros(3)
        for key in keys & TURN_KEYS.keys():
            axis, sign = TURN_KEYS[key]
            turn[axis] += sign
        move *= cfg.move_speed * scale * dt
        turn *= np.radians(cfg.turn_speed_deg) * scale * dt
        dx, dy = self._drag * scale
        self._drag = np.zeros(2)
        if LEFT_BUTTON in self._buttons:
            turn += cfg.drag_turn * np.array([dy, dx, 0.0])      # drag right turns about +y, down about +x
        elif RIGHT_BUTTON in self._buttons:
            move += cfg.drag_move * np.array([dx, -dy, 0.0])     # window pixels grow downward
        self.position = np.clip(self.position + move, -cfg.limit, cfg.limit)
        if turn.any():
            self.rotation = Rotation.from_rotvec(turn) * self.rotation   # about the screen's axes
        step = cfg.curl_speed * dt
        for key, finger in FINGER_KEYS.items():
            target = 1.0 if key in keys or FIST_KEY in keys else 0.0
            self.curl[finger] += float(np.clip(target - self.curl[finger], -step, step))
        self.spread += float(np.clip((1.0 if SPREAD_KEY in keys else 0.0) - self.spread, -step, step))
        trigger = 1.0 if "space" in keys or self._buttons & {LEFT_BUTTON, RIGHT_BUTTON} else 0.0
        buttons = tuple(sorted(BUTTON_KEYS[k] for k in keys & BUTTON_KEYS.keys()))
        return PathSample(self.position.copy(), quaternion.canonical(self.rotation.as_quat()), trigger, buttons)

"""The renderer's window (moderngl-window, glfw backend): orbit camera control and the `ui/input` state.

Mouse: middle-button drag, or left-button drag with Ctrl held, orbits the camera; the scroll wheel
zooms. Plain left/right drags and the keys are left to the desktop tracker, which reads them from
`ui/input`.
"""
from __future__ import annotations

import glfw
import numpy as np

from touch4d.messages import InputEvents

from .camera import OrbitCamera

# glfw key codes -> the contract's lower-case names ("w", "left", "space", "left_shift", "f1", ...).
KEY_NAMES = {getattr(glfw, attr): attr[4:].lower() for attr in dir(glfw)
             if attr.startswith("KEY_") and attr not in ("KEY_UNKNOWN", "KEY_LAST")}
MIDDLE_BUTTON = 3
LEFT_BUTTON = 1


def key_name(code: int) -> str | None:
    return KEY_NAMES.get(code)


class InputState:
    """Keyboard and mouse state between two `ui/input` messages; `take()` makes the message."""

    def __init__(self):
        self.keys_down: set[str] = set()
        self.pressed: list[str] = []
        self.buttons: set[int] = set()
        self.mouse = np.zeros(2)
        self.mouse_delta = np.zeros(2)
        self.scroll = 0.0

    def key(self, code: int, pressed: bool) -> None:
        name = key_name(code)
        if name is None:
            return
        if pressed:
            if name not in self.keys_down:
                self.pressed.append(name)
            self.keys_down.add(name)
        else:
            self.keys_down.discard(name)

    def move(self, x: float, y: float, dx: float, dy: float) -> None:
        self.mouse = np.array([x, y], dtype=float)
        self.mouse_delta += (dx, dy)

    def button(self, button: int, pressed: bool) -> None:
        (self.buttons.add if pressed else self.buttons.discard)(int(button))

    def wheel(self, amount: float) -> None:
        self.scroll += float(amount)

    def take(self) -> InputEvents:
        """The message for everything since the previous one; resets what accumulates."""
        msg = InputEvents(keys_down=sorted(self.keys_down), pressed=list(self.pressed), mouse=self.mouse.copy(),
                          mouse_delta=self.mouse_delta.copy(), buttons=sorted(self.buttons), scroll=self.scroll)
        self.pressed = []
        self.mouse_delta = np.zeros(2)
        self.scroll = 0.0
        return msg

    def orbiting(self) -> bool:
        """Whether a drag now turns the camera (middle button, or Ctrl + left button)."""
        ctrl = bool(self.keys_down & {"left_control", "right_control"})
        return MIDDLE_BUTTON in self.buttons or (ctrl and LEFT_BUTTON in self.buttons)


def open_window(size: tuple[int, int], camera: OrbitCamera, state: InputState, title: str = "touch4d",
                samples: int = 4):
    """A glfw window with a GL 3.3 context whose events feed `state` and turn `camera`."""
    from moderngl_window.context.glfw import Window

    window = Window(title=title, size=size, vsync=False, resizable=True, samples=samples, gl_version=(3, 3))
    window.exit_key = None            # Esc is a key like any other: the launcher stops the node

    def on_key(key, action, modifiers):
        if action == window.keys.ACTION_PRESS:
            state.key(key, True)
        elif action == window.keys.ACTION_RELEASE:
            state.key(key, False)

    def on_drag(x, y, dx, dy):
        state.move(x, y, dx, dy)
        if state.orbiting():
            camera.orbit(dx, dy)

    window.key_event_func = on_key
    window.mouse_position_event_func = lambda x, y, dx, dy: state.move(x, y, dx, dy)
    window.mouse_drag_event_func = on_drag
    window.mouse_press_event_func = lambda x, y, button: state.button(button, True)
    window.mouse_release_event_func = lambda x, y, button: state.button(button, False)

    def on_scroll(dx, dy):
        state.wheel(dy)
        camera.zoom(dy)

    window.mouse_scroll_event_func = on_scroll
    return window

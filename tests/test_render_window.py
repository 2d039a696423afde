"""The renderer node's real window (glfw through moderngl-window) under Xvfb: it draws the scene and
publishes the window's input on `ui/input`; the keyboard names follow the contract."""
from __future__ import annotations

import os
import shutil
import subprocess
import time

import glfw
import numpy as np
import pytest
from PIL import Image

from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.geometry.scene import parse_scene
from touch4d.messages import InputEvents, SceneState
from touch4d.render.window import InputState, key_name


@pytest.fixture
def xvfb_display(monkeypatch):
    """A private Xvfb server (its display number chosen by Xvfb), stopped afterwards."""
    if shutil.which("Xvfb") is None:
        pytest.fail("Xvfb is not installed: run the suite with ./dev test, which installs Debian's xvfb")
    read_end, write_end = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write_end), "-screen", "0", "800x600x24", "-nolisten", "tcp"],
                            pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    os.close(write_end)
    try:
        number = b""
        deadline = time.monotonic() + 20
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            chunk = os.read(read_end, 16)
            if not chunk:
                break
            number += chunk
        if not number.strip():
            pytest.fail("Xvfb did not report a display")
        monkeypatch.setenv("DISPLAY", ":" + number.decode().strip())
        yield os.environ["DISPLAY"]
    finally:
        os.close(read_end)
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.timeout(240)
def test_window_draws_the_scene_and_publishes_input(xvfb_display, tmp_path):
    out = tmp_path / "window.png"                 # numbered: window-000000.png, window-000001.png, ...
    scene = parse_scene({"objects": [{"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5],
                                      "color": [0, 1, 0, 1]}]}).to_message()
    params = {"rate": 20.0, "width": 320, "height": 240, "samples": 0, "output": str(out),
              "camera": "yaw=0,pitch=0,distance=4,target=0:0:0,ortho", "show_status": False,
              "show_tactile": False, "show_frame": False}
    with running_broker() as bus, node_process("renderer", bus, params=params) as proc:
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            inputs = collect(probe, "ui/input", InputEvents)
            pub = probe.create_publisher("scene/state", SceneState)

            def drawn():
                pub.publish(scene)
                probe.spin_once(0.2)
                frames = sorted(tmp_path.glob("window-*.png"))
                if not frames or len(inputs) < 3:
                    return False
                image = np.asarray(Image.open(frames[-1]))   # written whole: renamed into place
                return image.shape[:2] == (240, 320) and (image[..., 1] > 200).sum() > 100

            try:
                wait_until(drawn, timeout=150, interval=0.0)
            except TimeoutError:
                pytest.fail(f"no window frame with the scene after 150 s ({len(inputs)} ui/input messages); "
                            f"renderer output:\n{proc.text}")
        finally:
            probe.shutdown()
        assert "window 320x240" in proc.text
    msg = inputs[-1]
    assert msg.keys_down == [] and msg.buttons == [] and msg.mouse.shape == (2,)


def test_input_state_names_keys_and_accumulates_between_messages():
    assert key_name(glfw.KEY_W) == "w" and key_name(glfw.KEY_LEFT) == "left"
    assert key_name(glfw.KEY_SPACE) == "space" and key_name(glfw.KEY_LEFT_SHIFT) == "left_shift"
    state = InputState()
    state.key(glfw.KEY_W, True)
    state.key(glfw.KEY_LEFT_SHIFT, True)
    state.move(10, 20, 3, -1)
    state.move(12, 21, 2, 1)
    state.button(1, True)
    state.wheel(1.5)
    msg = state.take()
    assert msg.keys_down == ["left_shift", "w"] and msg.pressed == ["w", "left_shift"]
    assert msg.mouse.tolist() == [12, 21] and msg.mouse_delta.tolist() == [5, 0]
    assert msg.buttons == [1] and msg.scroll == 1.5
    state.key(glfw.KEY_W, False)
    msg = state.take()
    assert msg.keys_down == ["left_shift"] and msg.pressed == [] and msg.scroll == 0.0
    assert msg.mouse_delta.tolist() == [0, 0] and not state.orbiting()
    state.button(3, True)
    assert state.orbiting()

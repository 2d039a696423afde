"""The slice view in the headset, in a real browser (Debian's chromium, a Quest 3 emulated by iwer): the
right controller's thumbstick pushed forward / back moves the slice through w (one step of 0.05 per
push), the text panel above the screen says where it cuts, and the solid drawn in both eyes follows."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from touch4d.bus import Node
from touch4d.bus.testing import free_port, launch_process
from touch4d.messages import SceneCommand
from touch4d.web.testing import chromium, enter_vr, headset_page

from test_web_slice import cell_coloured, command

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def stack():
    """launch/webxr.yaml without motors, the page its tracker (the controller's buttons drive the scene)."""
    port = free_port()
    args = ["launch/webxr.yaml", "motors:=none", "monitor:=none", f"tracker.port:={port}",
            "tracker.save_calibration:=false"]
    with launch_process(args) as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        commander = Node("slice-headset-test", bus=bus, heartbeat=False)
        try:
            yield {"url": f"http://127.0.0.1:{port}/", "commands": commander.create_publisher("scene/command",
                                                                                            SceneCommand)}
        finally:
            commander.shutdown()


def push(page, y: float, expect_w: float) -> None:
    """The right thumbstick pushed (y < 0: forward) until the page's frames cut at `expect_w`, then let go."""
    page.evaluate(f"xr.controllers.right.updateAxes('thumbstick', 0, {y})")
    page.wait_for_function(f"Math.abs(touch4d.frame.slice_w - {expect_w}) < 1e-6", timeout=30_000)
    page.evaluate("xr.controllers.right.updateAxes('thumbstick', 0, 0)")
    page.wait_for_timeout(200)                         # released: the next push is a new press


def eyes(page) -> list[np.ndarray]:
    image = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"), dtype=float)
    w = image.shape[1]
    return [image[:, : w // 2], image[:, w // 2:]]


def test_the_thumbstick_moves_the_slice_and_the_headset_shows_it(stack, tmp_path):
    with chromium() as browser:
        page = headset_page(browser, stack["url"], 480, 270)
        try:
            enter_vr(page)
            page.wait_for_function("touch4d.geometry !== null && touch4d.xrFrames > 5")
            command(stack, page, "view", "slice", "touch4d.view === 'slice'")
            # the hypercube (size 1.2 at w = 1.5) spans w 0.9 .. 2.1: 2.05 cuts it, two steps up do not
            command(stack, page, "slice", "2.05", "Math.abs(touch4d.frame.slice_w - 2.05) < 1e-6")
            page.wait_for_timeout(300)
            inside = eyes(page)
            (tmp_path / "slice-in-the-headset.png").write_bytes(page.screenshot())
            assert all(cell_coloured(eye).sum() > 300 for eye in inside)      # the solid, in both eyes
            assert page.evaluate("touch4d.panel") == ["slice view: slice at w = 2.05 (objects span w 0.90 .. 2.10)"]
            push(page, -1.0, 2.10)
            assert page.evaluate("touch4d.panel") == ["slice view: slice at w = 2.10 (objects span w 0.90 .. 2.10)"]
            push(page, -1.0, 2.15)
            page.wait_for_timeout(300)
            assert page.evaluate("touch4d.panel") == ["slice view: slice at w = 2.15 (objects span w 0.90 .. 2.10)"]
            assert all(cell_coloured(eye).sum() < 30 for eye in eyes(page))    # past the object: nothing cut
            push(page, 1.0, 2.10)                                             # pulled back: down through w
            push(page, 1.0, 2.05)
            page.wait_for_timeout(300)
            back = eyes(page)
            assert all(cell_coloured(eye).sum() > 300 for eye in back)
            assert "slice at w = 2.05" in page.inner_text("#status")
        finally:
            page.context.close()

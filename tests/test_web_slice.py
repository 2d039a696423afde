"""The WebXR page in the slice view, in a real browser (Debian's chromium, WebGL2 through
SwiftShader): `scene/command view slice` turns the page's picture into the cross-section, a solid in
its cells' colours (in the both view, inside the projection), and its status line says where the
slice cuts; `slice` moves the cut. In a Quest 3 emulated by iwer, the right controller's thumbstick
pushed forward / back moves the slice through w (one step of 0.05 per push), the text panel above the
screen says where it cuts, and the solid drawn in both eyes follows."""
from __future__ import annotations

import io
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from touch4d.bus import Node
from touch4d.bus.testing import free_port, launch_process
from touch4d.messages import SceneCommand
from touch4d.render.frame import CELL_PALETTE
from touch4d.web.testing import chromium, context_options, enter_vr, headset_page, wait_connected

BACKGROUND = np.array([0.04, 0.04, 0.06]) * 255


@pytest.fixture(scope="module")
def stack():
    """launch/webxr.yaml without motors: the scene node, the webxr node (the page its tracker: the
    controller's buttons drive the scene), the tactile node."""
    port = free_port()
    args = ["launch/webxr.yaml", "motors:=none", "monitor:=none", f"tracker.port:={port}",
            "tracker.save_calibration:=false"]
    with launch_process(args) as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        commander = Node("slice-test", bus=bus, heartbeat=False)
        try:
            yield {"url": f"http://127.0.0.1:{port}/", "commands": commander.create_publisher("scene/command",
                                                                                            SceneCommand)}
        finally:
            commander.shutdown()


def screenshot(page) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"), dtype=float)


def cell_coloured(image: np.ndarray) -> np.ndarray:
    """Pixels in a cell's colour of the palette, shaded (a solid face): the hue of one of its colours,
    and bright (the projection's faces are translucent, its centre copies blended with the background)."""
    hues = CELL_PALETTE / CELL_PALETTE.max(axis=1, keepdims=True)
    top = image.max(axis=2, keepdims=True)
    hue = image / np.maximum(top, 1)
    near = np.min(np.abs(hue[:, :, None, :] - hues[None, None]).max(axis=-1), axis=-1) < 0.06
    return near & (top[..., 0] > 0.5 * 255)


def command(stack, page, name, argument, expect):
    for _ in range(100):                              # the bus may drop the first while it joins
        stack["commands"].publish(SceneCommand(command=name, argument=argument))
        try:
            page.wait_for_function(expect, timeout=300)
            return
        except Exception:  # noqa: BLE001 - playwright's TimeoutError: not yet
            continue
    raise AssertionError(f"the page never showed {expect}")


@contextmanager
def desktop_page(stack):
    """The stack's page in a desktop browser window, connected to its node."""
    with chromium() as browser:
        context = browser.new_context(**context_options(640, 400))
        page = context.new_page()
        try:
            page.goto(stack["url"])
            wait_connected(page)
            yield page
        finally:
            context.close()


def test_the_page_draws_the_slice_and_says_where_it_cuts(stack):
    with desktop_page(stack) as page:
        page.wait_for_function("touch4d.geometry !== null && touch4d.frames > 5")
        command(stack, page, "view", "projection", "touch4d.view === 'projection'")
        page.wait_for_timeout(300)
        projection = screenshot(page)
        command(stack, page, "view", "slice", "touch4d.view === 'slice'")
        command(stack, page, "slice", "1.5", "touch4d.frame.slice_w === 1.5")
        page.wait_for_timeout(300)
        cut = screenshot(page)
        drawn = np.abs(cut - BACKGROUND).sum(axis=2) > 30
        # the hypercube's section (a cube of its size, 1.2) is a solid in its cells' colours ...
        assert cell_coloured(cut).sum() > 2000 and cell_coloured(cut).sum() > 0.5 * drawn.sum() - 2000
        # ... where the projection showed translucent faces
        assert cell_coloured(projection).sum() < 0.2 * cell_coloured(cut).sum()
        assert page.evaluate("touch4d.panel") == ["slice view: slice at w = 1.50 (objects span w 0.90 .. 2.10)"]
        # the status line is rewritten once a second (with the frame rate): wait for its next turn
        page.wait_for_function("document.getElementById('status').textContent"
                               ".includes('slice view: slice at w = 1.50 (objects span w 0.90 .. 2.10)')", timeout=5_000)
        # both: the same solid, seen through the projection drawn faintly around it
        command(stack, page, "view", "both", "touch4d.view === 'both'")
        page.wait_for_timeout(300)
        both = screenshot(page)
        solid = cell_coloured(cut)
        assert np.abs(both - cut)[solid].mean() < 40                    # the solid, faintly tinted
        assert (np.abs(both - cut).sum(axis=2) > 60).sum() > 300        # and the projection's edges
        # moved out of the object's w range: nothing left to draw but the frame and the hand's cube
        command(stack, page, "view", "slice", "touch4d.view === 'slice'")
        command(stack, page, "slice", "2.5", "touch4d.frame.slice_w === 2.5")
        page.wait_for_timeout(300)
        assert cell_coloured(screenshot(page)).sum() < 50


def ghost_scene(c, *z_ghost, view="both") -> str:
    """A tesseract cut through at w = c (its section the same cube for every c in 0.9 .. 2.1) and, for
    each z given, a smaller one that w = c misses (only its translucent projection drawn), partly over
    the first at that z."""
    ghosts = "".join(f"  - {{name: ghost, shape: tesseract, size: 0.6, position: [0.5, 0.0, {z}, 2.6], "
                     f"color: [1.0, 1.0, 0.2, 1.0]}}\n" for z in z_ghost)
    return (f"projection: orthographic\nview: {view}\nslice_w: {c}\nobjects:\n"
            "  - {name: cut, shape: tesseract, size: 1.2, position: [0.0, 0.0, 0.0, 1.5]}\n" + ghosts)


def test_in_the_both_view_the_page_hides_the_projection_behind_the_solid(stack):
    """As the desktop backends: a projection surface behind the solid is hidden, one in front tints it."""
    with desktop_page(stack) as page:
        pictures = []
        for c, z, view in ((1.6, (), "slice"), (1.55, (), "both"), (1.5, (-1.0,), "both"), (1.45, (1.0,), "both")):
            command(stack, page, "load", ghost_scene(c, *z, view=view),      # c tells the scenes apart
                    f"touch4d.view === '{view}' && Math.abs(touch4d.frame.slice_w - {c}) < 1e-6")
            page.wait_for_timeout(300)
            pictures.append(screenshot(page))
        cut, alone, behind, front = pictures
        solid = cell_coloured(cut)
        changed = lambda image: np.abs(image - alone).max(axis=2) > 3
        assert solid.sum() > 2000
        assert changed(front)[solid].sum() > 300               # the ghost in front tints the solid ...
        assert changed(behind)[solid].sum() < 20               # ... behind it, the solid hides it
        assert changed(behind)[~solid].sum() > 100             # where it sticks out, it is drawn


def push(page, y: float, expect_w: float) -> None:
    """The right thumbstick pushed (y < 0: forward) until the page's frames cut at `expect_w`, then let go."""
    page.evaluate(f"xr.controllers.right.updateAxes('thumbstick', 0, {y})")
    page.wait_for_function(f"Math.abs(touch4d.frame.slice_w - {expect_w}) < 1e-6", timeout=30_000)
    sent = page.evaluate("xr.controllers.right.updateAxes('thumbstick', 0, 0); touch4d.sent")
    # released: the next push is a new press once the scene node has taken a released sample (it reads
    # the controller's state latest-only): twenty inputs without the stick, and half a second
    page.wait_for_function(f"touch4d.sent >= {sent} + 20", timeout=30_000)
    page.wait_for_timeout(500)


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
            command(stack, page, "load", Path("config/scenes/hypercube.yaml").read_text(),   # as the stack began
                    "touch4d.view === 'projection'")
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
            # the status line is rewritten once a second (with the frame rate): wait for its next turn
            page.wait_for_function("document.getElementById('status').textContent.includes('slice at w = 2.05')",
                                   timeout=5_000)
        finally:
            page.context.close()

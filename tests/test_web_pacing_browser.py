"""The webxr node's framebuffer_scale and foveation in a real browser (Debian's chromium, a Quest 3
emulated by iwer): the page's first XRWebGLLayer is made with the node's scale and given its
foveation; when its frames run late for the display (iwer's nominal rate raised to 120 Hz, which
headless Chromium's 60 Hz frames cannot keep) the page makes the next layer of the ladder its base
layer, shows it on window.touch4d.pacing and reports its scale to the node (heartbeat page_scale).
With `pacing: false` it keeps the node's layer. The pacing rule itself: test_web_pacing."""
from __future__ import annotations

import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, free_port, node_process, running_broker, wait_until
from touch4d.messages import Heartbeat
from touch4d.web.testing import chromium, enter_vr, headset_page, wait_connected

pytestmark = pytest.mark.timeout(180)

# Every XRWebGLLayer the page makes, with its options and the foveation the page gives it (iwer's
# layer has no fixedFoveation: this one has, as the Quest browser's).
RECORD_LAYERS = """() => {
  const Base = window.XRWebGLLayer;
  window.layers = [];
  window.XRWebGLLayer = class extends Base {
    constructor(session, gl, init) {
      super(session, gl, init);
      this.recorded = { init: init === undefined ? null : { ...init }, foveation: 0 };
      layers.push(this);
    }
    get fixedFoveation() { return this.recorded.foveation; }
    set fixedFoveation(value) { this.recorded.foveation = value; }
  };
}"""
LAYERS = "layers.map((l) => ({...l.recorded, base: touch4d.session.renderState.baseLayer === l}))"


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


def open_page(browser, port):
    page = headset_page(browser, f"http://127.0.0.1:{port}/", 320, 180)
    wait_connected(page)
    page.evaluate(RECORD_LAYERS)
    enter_vr(page)
    page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")   # the screen behind: cheap frames
    return page


def test_the_nodes_setting_makes_the_layer_and_late_frames_lower_it(browser):
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "port": port, "tracker": True, "save_calibration": False, "framebuffer_scale": 0.6,
            "foveation": 0.25}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)
        probe = Node("pacing-test", bus=bus, heartbeat=False)
        beats = collect(probe, "node/heartbeat", Heartbeat)
        page = open_page(browser, port)
        try:
            first = page.evaluate(LAYERS)[0]
            assert first["init"] == {"framebufferScaleFactor": 0.6} and first["foveation"] == 0.25
            page.evaluate("touch4d.session.updateTargetFrameRate(120)")
            assert page.evaluate("touch4d.session.frameRate") == 120
            # the next step of the ladder from (0.6, 0.25): the scale 0.8x but not below 0.5, the foveation +0.25
            page.wait_for_function("layers.length >= 2 && touch4d.pacing.lowered >= 1", timeout=20000)
            layers = page.evaluate(LAYERS)
            assert (layers[1]["init"], layers[1]["foveation"]) == ({"framebufferScaleFactor": 0.5}, 0.5)
            page.wait_for_function("touch4d.session.renderState.baseLayer === layers[layers.length - 1]",
                                   timeout=10000)
            pacing = page.evaluate("touch4d.pacing")
            assert pacing["nominal"] == 120 and 0 < pacing["fps"] < 120 / 1.1 and pacing["scale"] == 0.5
            made = [(l["init"]["framebufferScaleFactor"], l["foveation"]) for l in page.evaluate(LAYERS)]
            assert made == [(0.6, 0.25), (0.5, 0.5), (0.5, 0.75), (0.5, 1.0)][:len(made)]
            # the page's stats carry its layer's scale: the node's heartbeat shows it
            wait_until(lambda: any(b.node == "webxr" and b.stats.get("page_scale") == 0.5 and
                                   b.stats.get("page_fps", 0) > 0 for b in beats), timeout=20, spin=probe)
        finally:
            page.context.close()
            probe.shutdown()


def test_pacing_off_keeps_the_nodes_layer(browser):
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "port": port, "tracker": True, "save_calibration": False, "framebuffer_scale": 0.7,
            "pacing": False}) as proc:
        proc.wait_for_line("WebXR page", timeout=30)
        page = open_page(browser, port)
        try:
            page.evaluate("touch4d.session.updateTargetFrameRate(120)")
            frames = page.evaluate("touch4d.xrFrames")
            page.wait_for_function(f"touch4d.xrFrames > {frames} + 60 && touch4d.pacing.fps > 0", timeout=30000)
            layers = page.evaluate(LAYERS)
            assert len(layers) == 1 and layers[0]["init"] == {"framebufferScaleFactor": 0.7} and layers[0]["base"]
            assert page.evaluate("touch4d.pacing.lowered") == 0
            assert layers[0]["foveation"] == 0.5                                   # the node's default
        finally:
            page.context.close()

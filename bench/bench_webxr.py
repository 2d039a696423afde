"""WebXR benchmark: a pose set in the page -> its duty frame on the CAN bus, and the page's frame rate.

The stack of launch/webxr.yaml runs as processes (the page is the tracker; the motor node, with
emulated boards and `trace: true`, reports when each command's duty frames were on the virtual
bus). Headless Chromium with a Quest 3 emulated by iwer opens the page and enters VR; the bench
moves the controller into and out of a tesseract's front vertex (the motors change every time)
every 150 ms and records, in the page's clock (this machine's), when it set the pose. Per move:

    sample -> CAN   from the XR frame that read the pose (the stamp the node gives it) to the frame
                    on the bus: the page, its WebSocket, the node, the bus, tactile, motors;
    set -> CAN      from the moment the bench set the pose: the above plus the wait for the page's
                    next XR frame (up to one frame period: on a headset the runtime samples the
                    pose at the frame, so this part is the emulator's, not the headset's).

Baseline, in the same run: the same stack with hand/pose published by this process (no page).
Frame rate: the page in a stereo immersive session at each size, beside an empty WebXR frame loop
(clear only) in the same browser. The device (the WebGL renderer Chromium reports, the CPU) and
the load are printed.

    .venv/bin/python bench/bench_webxr.py [--moves 40] [--sizes 640x360 1280x720] [--screenshot PNG]

`--screenshot` also saves the two eyes' view (1280x640) with the hand on the vertex, as in the README.
"""
from __future__ import annotations

import argparse
import os
import platform
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.bus import Node
from touch4d.bus.testing import free_port, launch_process
from touch4d.messages import HandPose, MotorTrace
from touch4d.web.testing import chromium, enter_vr, headset_page

INSIDE = (0.0, 1.2, -0.43)       # the grip 2 cm in front of the screen's centre: on the front vertex
OUTSIDE = (0.45, 1.2, -0.43)     # beside the screen
EMPTY_PAGE = """<!doctype html><html><body><canvas id=c></canvas><script type=module>
const gl = document.getElementById('c').getContext('webgl2', {xrCompatible: true});
window.touch4d = {fps: 0, session: null, xrFrames: 0, connected: true, setup: {}};
window.addEventListener('click', async () => {
  const s = await navigator.xr.requestSession('immersive-vr', {requiredFeatures: ['local-floor']});
  s.updateRenderState({baseLayer: new XRWebGLLayer(s, gl)});
  const space = await s.requestReferenceSpace('local-floor');
  touch4d.session = s;
  let n = 0, t0 = performance.now();
  s.requestAnimationFrame(function frame(t, f) {
    s.requestAnimationFrame(frame);
    f.getViewerPose(space);
    gl.bindFramebuffer(gl.FRAMEBUFFER, s.renderState.baseLayer.framebuffer);
    gl.clearColor(0.04, 0.04, 0.06, 1); gl.clear(gl.COLOR_BUFFER_BIT);
    touch4d.xrFrames++; n++;
    const now = performance.now();
    if (now - t0 >= 1000) { touch4d.fps = 1000 * n / (now - t0); n = 0; t0 = now; }
  });
});
</script><button id=enter-vr>Enter VR</button></body></html>"""


def pct(values, q):
    return float(np.percentile(values, q)) * 1e3 if len(values) else float("nan")


class Probe:
    def __init__(self, bus):
        self.node = Node("bench-webxr", bus=bus, heartbeat=False)
        self.traces: list[MotorTrace] = []
        self.node.create_subscription("motors/trace", MotorTrace, self.traces.append)
        self.pose = self.node.create_publisher("hand/pose", HandPose)

    def traced(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.traces:
            return np.zeros(0), np.zeros(0)
        return (np.concatenate([t.source_stamps for t in self.traces]),
                np.concatenate([t.frame_times for t in self.traces]))

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.node.spin_once(0.005)


def page_latency(page, probe: Probe, moves: int) -> tuple[np.ndarray, np.ndarray]:
    """(set -> CAN, sample -> CAN) in seconds for each move of the controller."""
    probe.traces.clear()
    sets = []
    for k in range(moves):
        x, y, z = INSIDE if k % 2 == 0 else OUTSIDE
        sets.append(page.evaluate(f"""() => {{
            const t = performance.timeOrigin + performance.now();
            xr.controllers.right.position.set({x}, {y}, {z});
            return t / 1000; }}"""))
        probe.spin(0.15)
    probe.spin(0.5)
    src, frames = probe.traced()
    order = np.argsort(src)
    src, frames = src[order], frames[order]
    set_lat, sample_lat = [], []
    for t in sets:
        k = np.searchsorted(src, t)          # the first command from a pose sampled after the set
        if k < len(src) and src[k] - t < 0.15:
            set_lat.append(frames[k] - t)
            sample_lat.append(frames[k] - src[k])
    return np.array(set_lat), np.array(sample_lat)


def bus_latency(probe: Probe, moves: int) -> np.ndarray:
    """The baseline: hand poses published here, in and out of the vertex, no page."""
    from touch4d.tracking.calibration import load_calibration
    from touch4d.tracking.webxr import XRSource, hand_pose

    calibration = load_calibration(None, "hand_in_grip")
    probe.traces.clear()
    stamps = []
    for k in range(moves):
        grip = np.r_[INSIDE if k % 2 == 0 else OUTSIDE, 0, 0, 0, 1]
        pose = hand_pose(XRSource("right", grip=grip), "controller", calibration, time.time())
        probe.pose.publish(pose)
        stamps.append(pose.source_stamp)
        probe.spin(0.15)
    probe.spin(0.5)
    src, frames = probe.traced()
    keep = np.isin(src, stamps)
    return frames[keep] - src[keep]


def frame_rate(page, seconds: float = 4.0) -> float:
    page.wait_for_timeout(1000)
    rates = []
    for _ in range(int(seconds)):
        page.wait_for_timeout(1000)
        rates.append(page.evaluate("touch4d.fps"))
    return float(np.median(rates))


def stereo_screenshot(browser, path: str) -> None:
    """Both eyes, standing a little back from the screen, while the scripted hand presses the
    tesseract's front vertex (the demo with `renderer:=webxr`: the page only shows; a page as slow
    as SwiftShader's would let a tracked hand lapse between its poses)."""
    port = free_port()
    launch = ["renderer:=webxr", f"renderer.port:={port}", "monitor:=none", "tracker.path:=vertex-press",
              "scene.scene:=config/scenes/hypercube-vertex.yaml", "scene.spin:={}"]
    with launch_process(launch) as run:
        run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", 1280, 640)
        try:
            enter_vr(page)
            page.evaluate("xr.position.set(-0.25, 1.55, 0.3)")
            page.evaluate("xr.quaternion.set(-0.1730, -0.0858, -0.0152, 0.9811)")     # 20 degrees down, 10 left
            touching = "touch4d.frame !== null && touch4d.frame.hand_valid && touch4d.motorsOn > 3"
            page.wait_for_function(touching, timeout=120000)
            n = page.evaluate("touch4d.xrFrames")
            page.wait_for_function(f"touch4d.xrFrames > {n} + 2 && {touching}", timeout=120000)
            page.screenshot(path=path)
        finally:
            page.context.close()


def serve_empty_page() -> tuple[ThreadingHTTPServer, int]:
    class Handler(SimpleHTTPRequestHandler):
        def do_GET(self):
            body = EMPTY_PAGE.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass
    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.server_address[1]


def cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown CPU"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--moves", type=int, default=40)
    parser.add_argument("--sizes", nargs="+", default=["640x360", "1280x720"])
    parser.add_argument("--screenshot", help="save the stereo view here (PNG)")
    args = parser.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes]
    port = free_port()
    launch = ["launch/webxr.yaml", "monitor:=none", f"tracker.port:={port}", "tracker.save_calibration:=false",
              "scene.scene:=config/scenes/hypercube-vertex.yaml"]
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    with launch_process(launch) as run, chromium() as browser:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        probe = Probe(bus)
        try:
            page = headset_page(browser, f"http://127.0.0.1:{port}/", *sizes[0])
            enter_vr(page)
            device = page.evaluate("touch4d.gpu")
            print(f"device: {device} in headless Chromium {browser.version}; CPU {cpu_name()}, "
                  f"{os.cpu_count()} cores")
            page.evaluate(f"xr.controllers.right.position.set{OUTSIDE}")
            probe.spin(1.0)
            set_lat, sample_lat = page_latency(page, probe, args.moves)
            page.context.close()
            base = bus_latency(probe, args.moves)
            print(f"\npage -> CAN duty frame, {len(sample_lat)} of {args.moves} moves traced "
                  f"(page at {sizes[0][0]}x{sizes[0][1]}):")
            print(f"  sample -> CAN   p50 {pct(sample_lat, 50):6.2f} ms   p99 {pct(sample_lat, 99):6.2f} ms   "
                  f"(goal p99 <= 15 ms over loopback)")
            print(f"  set -> CAN      p50 {pct(set_lat, 50):6.2f} ms   p99 {pct(set_lat, 99):6.2f} ms   "
                  "(plus the wait for the emulated headset's next frame)")
            print(f"  baseline: hand/pose published by the bench -> CAN, {len(base)} traced: "
                  f"p50 {pct(base, 50):6.2f} ms   p99 {pct(base, 99):6.2f} ms")
            if len(base) and len(sample_lat):
                print(f"  ratio sample -> CAN / baseline: p50 {pct(sample_lat, 50) / pct(base, 50):.2f}x   "
                      f"p99 {pct(sample_lat, 99) / pct(base, 99):.2f}x")

            print("\npage frame rate, immersive stereo session (both eyes side by side):")
            server, empty_port = serve_empty_page()
            try:
                for w, h in sizes:
                    page = headset_page(browser, f"http://127.0.0.1:{port}/", w, h)
                    enter_vr(page)
                    page.evaluate(f"xr.controllers.right.position.set{INSIDE}")
                    fps = frame_rate(page)
                    page.context.close()
                    empty = headset_page(browser, f"http://127.0.0.1:{empty_port}/", w, h)
                    empty.click("#enter-vr")
                    empty.wait_for_function("touch4d.xrFrames > 3")
                    base_fps = frame_rate(empty)
                    empty.context.close()
                    print(f"  {w}x{h}: {fps:6.1f} fps   baseline (empty WebXR frame loop) {base_fps:6.1f} fps   "
                          f"ratio {fps / base_fps:.2f}")
            finally:
                server.shutdown()
            if args.screenshot:
                stereo_screenshot(browser, args.screenshot)
                print(f"\nstereo view saved to {args.screenshot}")
        finally:
            probe.node.shutdown()
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()

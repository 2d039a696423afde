"""Touch where the hand is: the WebXR page's own touch (`touch: page`, launch/quest.yaml) against the
tactile node's played by the page (`touch: node`), in one run, in headless Chromium with a Quest 3
emulated by iwer (WebGL2 on SwiftShader, the CPU: not a headset's GPU; the figures say so).

The bench moves the glove hand's controller into and out of the hypercube's front cell (full drive,
then none) every 200 ms and records, on the page's clock, when it set the pose and every pulse the
page played. Per mode:

    set -> pulse    from setting the pose to the first pulse that plays it (the page's next XR
                    frame included): the page's own touch needs its next frame and one more (the
                    pass's result read back a frame later); the node's a WebSocket round trip, the
                    tactile node and the node's next frame besides;
    frame           the XR frame interval (ms) with the hand in the object, and, page mode only, the
                    time the touch takes on the page's thread per frame (issuing the pass, reading
                    back the previous one, eq. 1-3): its ratio to the node mode's frame is the cost.

Each at the loopback's latency and at an emulated network latency (Chromium's emulation of the
page's connection, `--rtt`): the page's own touch does not wait for the network, the node's does.

    .venv/bin/python bench/bench_touch.py [--moves 30] [--size 320x180] [--rtt 0 80]
"""
from __future__ import annotations

import argparse
import os
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.bus.testing import free_port, launch_process
from touch4d.web.testing import chromium, enter_vr, headset_page

INSIDE = (0.0, 1.2, -0.45)       # the screen's centre: in the hypercube's front cell, full drive
OUTSIDE = (0.6, 1.2, -0.45)      # beside the screen: nothing
RECORD_PULSES = """() => {
  window.pulses = [];
  for (const source of touch4d.session.inputSources) {
    const actuator = source.gamepad && source.gamepad.hapticActuators[0];
    if (!actuator || source.handedness !== 'right') continue;
    const pulse = actuator.pulse.bind(actuator);
    actuator.pulse = (value, duration) => { pulses.push([value, performance.timeOrigin + performance.now()]);
                                            return pulse(value, duration); };
  }
}"""
NOW = "performance.timeOrigin + performance.now()"


def run_mode(browser, mode: str, moves: int, size, rtt_ms: float = 0.0) -> dict:
    port = free_port()
    args = ["launch/quest.yaml", "monitor:=none", f"tracker.port:={port}", "tracker.save_calibration:=false",
            f"tracker.touch:={mode}", f"tactile.motors:={'true' if mode == 'node' else 'false'}"]
    with launch_process(args) as run:
        run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", *size)
        if rtt_ms:   # Chromium's own network emulation: the page's WebSocket messages delayed
            cdp = page.context.new_cdp_session(page)
            cdp.send("Network.enable")
            cdp.send("Network.emulateNetworkConditions", {"offline": False, "latency": rtt_ms,
                                                          "downloadThroughput": -1, "uploadThroughput": -1})
        try:
            enter_vr(page)
            page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")   # the screen out of view
            page.evaluate(RECORD_PULSES)
            page.evaluate(f"xr.controllers.right.position.set{INSIDE}")
            page.wait_for_function("pulses.some(([v]) => v > 0.99)", timeout=30000)
            sets = []
            for k in range(moves):
                where = OUTSIDE if k % 2 == 0 else INSIDE
                sets.append((page.evaluate(f"() => {{ xr.controllers.right.position.set{where}; return {NOW}; }}"),
                             k % 2 == 1))
                time.sleep(0.2)
            played = page.evaluate("pulses")
            latency = []
            for t, inside in sets:
                first = next((pt for v, pt in played if pt >= t and ((v > 0.99) if inside else (v == 0))), None)
                if first is not None:
                    latency.append(first - t)
            page.evaluate(f"xr.controllers.right.position.set{INSIDE}")
            time.sleep(0.5)
            start = page.evaluate("[touch4d.xrFrames, touch4d.touchCost.frames, touch4d.touchCost.ms, "
                                  "performance.now()]")
            time.sleep(4.0)
            end = page.evaluate("[touch4d.xrFrames, touch4d.touchCost.frames, touch4d.touchCost.ms, "
                                "performance.now()]")
            frames = end[0] - start[0]
            touch_frames = end[1] - start[1]
            return {"latency": np.array(latency), "sets": len(sets), "frame_ms": (end[3] - start[3]) / max(frames, 1),
                    "touch_ms": (end[2] - start[2]) / touch_frames if touch_frames else float("nan"),
                    "gpu": page.evaluate("touch4d.gpu")}
        finally:
            page.context.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--moves", type=int, default=30)
    parser.add_argument("--size", default="320x180")
    parser.add_argument("--rtt", type=float, nargs="+", default=[0.0, 80.0],
                        help="network latencies to emulate (ms, Chromium's emulation of the page's connection)")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    with chromium() as browser:
        runs = {rtt: {mode: run_mode(browser, mode, args.moves, size, rtt) for mode in ("node", "page")}
                for rtt in args.rtt}
    first = next(iter(runs.values()))
    print(f"device: {first['page']['gpu']} (software WebGL2: SwiftShader on the CPU, not a headset's GPU), "
          f"{os.cpu_count()} cores; page {size[0]}x{size[1]}, the screen out of view")
    for rtt, results in runs.items():
        print(f"emulated network latency {rtt:.0f} ms:")
        for mode, r in results.items():
            lat = r["latency"]
            print(f"  touch: {mode:4s}  set -> pulse p50 {np.percentile(lat, 50):6.1f} ms  p95 "
                  f"{np.percentile(lat, 95):6.1f} ms ({len(lat)} of {r['sets']} moves)   frame {r['frame_ms']:5.1f} ms"
                  + (f"   touch on the page's thread {r['touch_ms']:.2f} ms/frame" if mode == "page" else ""))
        node, page = results["node"], results["page"]
        print(f"  ratio page / node: set -> pulse p50 "
              f"{np.percentile(page['latency'], 50) / np.percentile(node['latency'], 50):.2f}x   frame "
              f"{page['frame_ms'] / node['frame_ms']:.2f}x   touch's own time / node frame "
              f"{page['touch_ms'] / node['frame_ms']:.3f}")
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()

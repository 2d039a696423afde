"""The WebXR page's frame with and without its own touch, both eyes drawn: launch/quest.yaml in
headless Chromium with a Quest 3 emulated by iwer (stereo: two views per frame; WebGL2 on
SwiftShader, the CPU: not a headset's GPU; the figures say so), looking at the screen, the glove
hand's controller in the hypercube's front cell (touching: full drive).

    touch: node     baseline: the tactile node's touch, played by the page (no tactile pass on the page)
    touch: page     the page's own tactile pass every XR frame (static/touch.js)

Per mode: the XR frame rate and interval over `--seconds`, and, page mode, the time the touch takes
on the page's thread per frame (window.touch4d.touchCost: issuing the pass, reading back the previous
one, eq. 1-3). The modes alternate for `--rounds` rounds (a machine's load drifts; each figure is the
median of its rounds) and the page's figures are given as a ratio to the baseline of the same run.
The page's pacing is off (`tracker.pacing:=false`): the layer stays the node's.

    .venv/bin/python bench/bench_frame.py [--seconds 5] [--rounds 2] [--size 640x360]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads

from bench_touch import INSIDE
from touch4d.bus.testing import free_port, launch_process
from touch4d.web.testing import chromium, enter_vr, headset_page

SAMPLE = "[touch4d.xrFrames, touch4d.touchCost.frames, touch4d.touchCost.ms, performance.now()]"


def run_mode(browser, touch: str, seconds: float, size) -> dict:
    """One launch in `touch` mode: frames, frame interval and the page's touch time over `seconds`."""
    port = free_port()
    args = ["launch/quest.yaml", "monitor:=none", f"tracker.port:={port}", "tracker.save_calibration:=false",
            f"tracker.touch:={touch}", f"tactile.motors:={'true' if touch == 'node' else 'false'}",
            "tracker.pacing:=false"]
    with launch_process(args) as run:
        run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", *size)
        try:
            enter_vr(page)
            page.evaluate(f"xr.controllers.right.position.set{INSIDE}")
            # touching, and the scene drawn: the node's frames say the hand is in; the page's own touch ran
            page.wait_for_function("touch4d.frame && touch4d.frame.hand_valid && touch4d.geometry" +
                                   (" && touch4d.touch && touch4d.touch.level > 0.99" if touch == "page" else ""),
                                   timeout=60000)
            time.sleep(1.0)
            start = page.evaluate(SAMPLE)
            time.sleep(seconds)
            end = page.evaluate(SAMPLE)
            frames, touch_frames = end[0] - start[0], end[1] - start[1]
            return {"fps": 1000 * frames / (end[3] - start[3]), "frame_ms": (end[3] - start[3]) / max(frames, 1),
                    "touch_ms": (end[2] - start[2]) / touch_frames if touch_frames else float("nan"),
                    "touch_frames": touch_frames, "frames": frames, "views": page.evaluate("xr.stereoEnabled ? 2 : 1"),
                    "gpu": page.evaluate("touch4d.gpu")}
        finally:
            page.context.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--size", default="640x360")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    runs: dict[str, list[dict]] = {"node": [], "page": []}
    with chromium() as browser:
        for _ in range(args.rounds):
            for touch in runs:
                runs[touch].append(run_mode(browser, touch, args.seconds, size))
    first = runs["node"][0]
    print(f"device: {first['gpu']} (software WebGL2: SwiftShader on the CPU, not a headset's GPU), "
          f"{os.cpu_count()} cores; page {size[0]}x{size[1]}, {first['views']} eyes, the screen in view, "
          f"the hand in the hypercube's front cell; {args.rounds} rounds of {args.seconds:.0f} s per mode (medians)")
    med = {touch: {k: statistics.median(r[k] for r in rs) for k in ("fps", "frame_ms", "touch_ms")}
           for touch, rs in runs.items()}
    node, page = med["node"], med["page"]
    print(f"  touch: node (baseline)  {node['fps']:5.1f} fps   frame {node['frame_ms']:5.1f} ms")
    print(f"  touch: page             {page['fps']:5.1f} fps   frame {page['frame_ms']:5.1f} ms   "
          f"touch on the page's thread {page['touch_ms']:.2f} ms/frame "
          f"({100 * page['touch_ms'] / page['frame_ms']:.1f}% of its frame; in "
          f"{sum(r['touch_frames'] for r in runs['page'])} of {sum(r['frames'] for r in runs['page'])} frames)")
    print(f"  ratio page / node: fps {page['fps'] / node['fps']:.2f}x   "
          f"frame {page['frame_ms'] / node['frame_ms']:.2f}x"
          f"   touch's own time / baseline frame {page['touch_ms'] / node['frame_ms']:.3f}")
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()

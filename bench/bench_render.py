"""Renderer benchmark: the GPU backend beside the clip-unit backend, in the same run, on the same frames.

1. CPU time per frame: all work before the draw calls, for a scene whose every object moved (a new
   `scene/state`): adopting the scene (SceneView.set_scene) and the backend's prepare (GPU: the
   transforms texture; clip: culling, clip units, cutting and the vertex upload). Main-thread CPU
   time, so llvmpipe's rasteriser threads and other processes count as little as possible.
   Baseline: the clip-unit backend (the ratio is clip / gpu) and the 90 Hz frame budget (11.1 ms).
2. GPU time per frame of the draw calls, from GL timer queries (on llvmpipe the "GPU" is the CPU's
   rasteriser threads), and frames per second of the whole loop (prepare, draw, finish) at
   1920x1080 and at 2 x 2064x2208 (one Quest 3 stereo frame: the scene drawn twice).

Scenes: 1, 8, 64, 256 and 1024 tesseracts in a grid over the screen at several depths, turned at
random, so that neighbours overlap on the screen and hide each other; a 120-cell.
Run: .venv/bin/python bench/bench_render.py [--quick]
"""
from __future__ import annotations

import math
import sys
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.render.backends import create_backend
from touch4d.render.camera import OrbitCamera
from touch4d.render.context import OffscreenTarget, create_headless_context
from touch4d.render.view import SceneView, Show

BUDGET = 1 / 90
MONO = (1920, 1080)
QUEST3 = (2064, 2208)
BARE = Show(frame=False, hand=False, tactile=False, status=False)


def best_of(fn, repeat=5, number=None, clock=time.thread_time) -> float:
    """Seconds per call: the best of `repeat` timings of `number` calls, on `clock`."""
    if number is None:
        t0 = clock()
        fn()
        number = max(1, int(0.05 / max(clock() - t0, 1e-7)))
    times = []
    for _ in range(repeat):
        t0 = clock()
        for _ in range(number):
            fn()
        times.append((clock() - t0) / number)
    return min(times)


def random_rotation(rng, spread=0.5):
    r = np.eye(4)
    for plane in ("xy", "xz", "xw", "yz", "yw", "zw"):
        r = plane_rotation(plane, rng.uniform(-spread, spread)) @ r
    return r


def tesseracts(n: int) -> Scene:
    """n tesseracts on a k x k x k grid over the screen (k >= 4), at five depths."""
    rng = np.random.default_rng(1)
    k = max(4, math.ceil(n ** (1 / 3) - 1e-9))
    grid = np.linspace(-0.75, 0.75, k)
    spots = [(x, y, z) for x in grid for y in grid for z in grid]
    objects = [SceneObject(name=f"t{i}", shape="tesseract", size=1.36 / k, orientation=random_rotation(rng),
                           position=np.array([*spots[i], 1.0 + 0.6 * ((7 * i) % 5)]),
                           color=np.r_[rng.uniform(0.2, 1, 3), 1.0]) for i in range(n)]
    return Scene(objects=objects)


def cell120() -> Scene:
    rng = np.random.default_rng(2)
    return Scene(objects=[SceneObject(name="c", shape="120-cell", size=1.5, orientation=random_rotation(rng, 1.0),
                                      position=np.array([0, 0, 0, 2.0]), color=np.array([0.3, 0.6, 1.0, 1.0]))])


def turned(scene: Scene, angle: float) -> Scene:
    """The scene with every object turned by `angle` in the xw plane (a new scene/state)."""
    out = scene.copy()
    turn = plane_rotation("xw", angle)
    for obj in out.objects:
        obj.orientation = turn @ obj.orientation
    return out


class Loop:
    """One backend drawing a scene that moves between two poses every frame."""

    def __init__(self, ctx, backend: str, scene: Scene, projection: str):
        self.ctx = ctx
        self.backend = create_backend(backend, ctx)
        self.view = SceneView(None, show=BARE)
        a = Scene(objects=scene.objects, projection=projection)
        self.poses = [a, turned(a, 0.01)]
        self.step = 0
        self.prepare()

    def prepare(self) -> None:
        """All CPU work of a frame before its draw calls."""
        self.step += 1
        self.view.set_scene(self.poses[self.step % 2])
        self.backend.prepare(self.view.frame())

    def draw(self, target, camera, background=(0, 0, 0, 1)) -> None:
        target.use()
        self.backend.draw(camera.matrix(target.size), target.size, background)

    def release(self) -> None:
        self.backend.release()


def cpu_rows(ctx, cases, projections) -> None:
    print(f"CPU per frame, every object moved (main-thread CPU time; budget {BUDGET * 1e3:.1f} ms at 90 Hz)")
    print(f"  {'scene':<16}{'projection':<14}{'gpu ms':>9}{'clip ms':>10}{'clip/gpu':>10}{'gpu/budget':>12}")
    for name, scene in cases:
        for projection in projections:
            t = {}
            for backend in ("gpu", "clip"):
                loop = Loop(ctx, backend, scene, projection)
                ctx.finish()
                t[backend] = best_of(loop.prepare, repeat=5 if len(scene.objects) < 256 else 2)
                loop.release()
            print(f"  {name:<16}{projection:<14}{t['gpu'] * 1e3:>9.3f}{t['clip'] * 1e3:>10.2f}"
                  f"{t['clip'] / t['gpu']:>9.0f}x{t['gpu'] / BUDGET:>12.3f}")


def gpu_ms(ctx, query, loop, targets, cameras, max_seconds: float, repeat: int = 7) -> float:
    """Median GPU time of one frame's draw calls (every camera of the frame), from GL timer queries:
    `repeat` frames, fewer where they take over `max_seconds` together (llvmpipe)."""
    times, t0 = [], time.perf_counter()
    while len(times) < repeat and (not times or time.perf_counter() - t0 < max_seconds):
        with query:
            for camera in cameras:
                loop.draw(targets, camera)
        ctx.finish()
        times.append(query.elapsed / 1e6)
    return float(np.median(times))


def warm_up(ctx, scene: Scene, target, camera, seconds: float = 1.0) -> None:
    """Draw for a second, untimed: a GPU that has idled runs at low clocks for its first frames."""
    loop = Loop(ctx, "gpu", scene, "orthographic")
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        loop.prepare()
        loop.draw(target, camera)
        ctx.finish()
    loop.release()


def frame_rows(ctx, cases, max_seconds: float) -> None:
    cameras = {"mono": [OrbitCamera()], "stereo": [OrbitCamera(yaw=27.0), OrbitCamera(yaw=29.0)]}
    targets = {"mono": OffscreenTarget(ctx, MONO), "stereo": OffscreenTarget(ctx, QUEST3)}
    mono, stereo = "x".join(map(str, MONO)), "2x" + "x".join(map(str, QUEST3))
    print("GPU time per frame (GL timer queries, draw calls only, median of up to 7 frames) and frames per second of the "
          f"whole loop (prepare + draw + finish, for {max_seconds:g} s), orthographic")
    print(f"  {'scene':<16}{'backend':<9}{'GPU ms ' + mono:>18}{'fps ' + mono:>15}"
          f"{'GPU ms ' + stereo:>20}{'fps ' + stereo:>17}")
    query = ctx.query(time=True)
    warm_up(ctx, cases[0][1], targets["mono"], cameras["mono"][0])
    for name, scene in cases:
        for backend in ("gpu", "clip"):
            loop = Loop(ctx, backend, scene, "orthographic")
            loop.draw(targets["mono"], cameras["mono"][0])        # shaders compile on first use
            ctx.finish()
            ms, fps = {}, {}
            for kind in ("mono", "stereo"):
                ms[kind] = gpu_ms(ctx, query, loop, targets[kind], cameras[kind], max_seconds)
                frames, t0 = 0, time.perf_counter()
                while frames < 1 or time.perf_counter() - t0 < max_seconds:
                    loop.prepare()
                    for camera in cameras[kind]:
                        loop.draw(targets[kind], camera)
                    ctx.finish()
                    frames += 1
                fps[kind] = frames / (time.perf_counter() - t0)
            print(f"  {name:<16}{backend:<9}{ms['mono']:>18.2f}{fps['mono']:>15.1f}"
                  f"{ms['stereo']:>20.2f}{fps['stereo']:>17.1f}")
            loop.release()
    for t in targets.values():
        t.release()


def cpu_name() -> str:
    """The processor's model name (Linux), else the machine type."""
    import platform
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def main() -> None:
    quick = "--quick" in sys.argv
    ctx = create_headless_context()
    print(f"GL: {ctx.info['GL_RENDERER']} ({ctx.info['GL_VERSION']}); CPU: {cpu_name()}")
    counts = (1, 8, 64) if quick else (1, 8, 64, 256, 1024)
    cases = [(f"{n} tesseract{'s' if n > 1 else ''}", tesseracts(n)) for n in counts] + [("120-cell", cell120())]
    cpu_rows(ctx, cases, ("orthographic", "perspective"))
    frame_rows(ctx, cases, 0.5 if quick else 2.0)
    ctx.release()


if __name__ == "__main__":
    main()

"""Renderer benchmark: CPU time to build one frame (culling, clip units, clipping, vertex arrays) for 1, 8
and 64 tesseracts and a 120-cell, beside the time to upload and draw the same buffers (EGL, llvmpipe here).

The build is timed in process CPU time, upload + draw in wall time (llvmpipe rasterises on
threads). Baselines from the same run: the same build without clipping (so the ratio is what
hidden-hypersurface removal costs) and the 90 Hz headset frame budget (11.1 ms). "build" moves every
body on each call, so nothing of the last frame is reused; "one turning" moves one body (the
controller's case), so the builder reuses the cut pieces of the bodies it does not touch. The
tesseracts stand in a 4 x 4 x 4 grid at several depths, turned at random, so neighbours overlap on
the screen and clip each other.
Run: .venv/bin/python bench/bench_render.py
"""
from __future__ import annotations

import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.shapes import get_shape
from touch4d.render.camera import OrbitCamera
from touch4d.render.context import OffscreenTarget, create_headless_context
from touch4d.render.draw import Layers, Painter
from touch4d.render.scene_mesh import Body, MeshBuilder, Style

BUDGET = 1 / 90


def best_of(fn, repeat=7, number=None, clock=time.perf_counter) -> float:
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


def tesseracts(n: int) -> list[Body]:
    rng = np.random.default_rng(1)
    cube = get_shape("tesseract").parts[0]
    grid = np.linspace(-0.75, 0.75, 4)
    spots = [(x, y, z) for x in grid for y in grid for z in grid]
    return [Body(cube, random_rotation(rng), np.array([*spots[i], 1.0 + 0.6 * ((7 * i) % 5)]), 0.34,
                 np.r_[rng.uniform(0.2, 1, 3), 1.0]) for i in range(n)]


def nudged(bodies: list[Body], which) -> list[Body]:
    """The bodies with those in `which` turned by 0.01 rad in the xw plane."""
    turn = plane_rotation("xw", 0.01)
    out = list(bodies)
    for i in which:
        b = bodies[i]
        out[i] = Body(b.polytope, turn @ b.orientation, b.position, b.size, b.color, b.object_index)
    return out


def alternate(builder: MeshBuilder, a: list[Body], b: list[Body], projection: str):
    """A build call that switches between two poses of the scene each time, as a moving scene would."""
    scenes = [a, b]

    def build():
        scenes.reverse()
        builder.build(scenes[0], projection, 3.0)
    return build


def cell120() -> list[Body]:
    rng = np.random.default_rng(2)
    return [Body(get_shape("120-cell").parts[0], random_rotation(rng, 1.0), np.array([0, 0, 0, 2.0]), 1.5,
                 np.array([0.3, 0.6, 1.0, 1.0]))]


def main() -> None:
    ctx = create_headless_context()
    size = (1280, 800)
    target = OffscreenTarget(ctx, size)
    painter = Painter(ctx)
    camera = OrbitCamera()
    print(f"GL: {ctx.info['GL_RENDERER']}; frame {size[0]}x{size[1]}; budget {BUDGET * 1e3:.1f} ms (90 Hz)")
    print(f"{'scene':<16}{'projection':<13}{'tris':>6}{'lines':>6}  {'build ms':>9}{'no-clip ms':>11}"
          f"{'ratio':>7}{'/budget':>8}  {'upload+draw ms':>15}")
    print(f"{'':<41}{'(CPU)':>9}{'(CPU)':>11}{'':>15}  {'(wall)':>15}")
    builder = MeshBuilder()
    cases = [("1 tesseract", tesseracts(1)), ("8 tesseracts", tesseracts(8)), ("64 tesseracts", tesseracts(64)),
             ("120-cell", cell120())]
    for name, bodies in cases:
        for projection in ("orthographic", "perspective"):
            # The build is single-threaded numpy: its CPU time, which other processes on a busy
            # machine inflate less than wall time. Drawing runs on llvmpipe's threads: wall time.
            # Every body moves between two poses on each call, so nothing of the last frame is reused.
            build = best_of(alternate(builder, bodies, nudged(bodies, range(len(bodies))), projection),
                            clock=time.process_time)
            plain = best_of(lambda: builder.build(bodies, projection, 3.0, Style(clip=False)), clock=time.process_time)
            mesh = builder.build(bodies, projection, 3.0)
            layers = Layers(triangles=[mesh.fills, mesh.centres], lines=[mesh.edges])
            target.use()
            mvp = camera.matrix(size)

            def upload_draw():
                painter.draw(painter.upload(layers), mvp, size)
                ctx.finish()

            gpu = best_of(upload_draw, repeat=5)
            c = mesh.counts
            print(f"{name:<16}{projection:<13}{c['fill_triangles'] + c['centre_triangles']:>6}{c['edge_segments']:>6}  "
                  f"{build * 1e3:>9.2f}{plain * 1e3:>11.2f}{build / plain:>7.2f}{build / BUDGET:>8.2f}  "
                  f"{gpu * 1e3:>15.2f}")
            if len(bodies) > 1:
                # One object turning (the controller's case): the others' cut pieces are reused.
                one = best_of(alternate(builder, bodies, nudged(bodies, [0]), projection), clock=time.process_time)
                print(f"{'  one turning':<16}{projection:<13}{'':>12}  {one * 1e3:>9.2f}{plain * 1e3:>11.2f}"
                      f"{one / plain:>7.2f}{one / BUDGET:>8.2f}")
    painter.release()
    target.release()


if __name__ == "__main__":
    main()

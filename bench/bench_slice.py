"""Slice view benchmark: CPU per frame of the projection, slice and both views, in the same run, on the
same moving scenes, with the GPU backend (and the clip-unit backend beside it).

CPU time per frame: all work before the draw calls for a scene whose every object moved (a new
`scene/state`): SceneView.set_scene (in the slice and both views: cutting every body at w = c,
`touch4d.geometry.section`), the frame, and the backend's prepare (the upload of the section's
triangles with the other flat layers). Main-thread CPU time, best of 5. Baselines: the projection
view of the same backend (the ratio slice / projection) and the 1 ms target of the gpu backend.
Scenes: 64 tesseracts turned at random on a 4 x 4 x 4 grid at five depths (bench_render's), cut
through the middle of their w range (a fifth of them cut); the same 64 all at one depth (every one
cut); 8 tesseracts; a 120-cell (120 dodecahedral cells). Then the cut alone of the 64 all cut, compiled
(`SectionKernel.triangles`) against the same fans from the array operations of `SectionKernel.polygons`.
Run: .venv/bin/python bench/bench_slice.py
"""
from __future__ import annotations

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads

from dataclasses import replace

import numpy as np

from touch4d.geometry.section import kernel
from touch4d.render.context import create_headless_context
from touch4d.render.section_mesh import section_triangles

from bench_render import Loop, best_of, cell120, tesseracts

TARGET = 1e-3          # CPU per frame the gpu backend must stay under, in the slice and both views


class ViewLoop(Loop):
    """bench_render's loop (the scene moving between two poses) in a given view."""

    def __init__(self, ctx, backend, scene, view):
        extent = [p.vertices[:, 3] for _, p in scene.world_parts()]
        middle = 0.5 * (min(w.min() for w in extent) + max(w.max() for w in extent))
        super().__init__(ctx, backend, replace(scene, view=view, slice_w=middle), "orthographic")
        self.poses = [replace(p, view=view, slice_w=middle) for p in self.poses]


def all_cut(scene):
    """The scene with every object at w = 1.5, so that the slice through the middle cuts every one."""
    out = scene.copy()
    for obj in out.objects:
        obj.position = np.r_[obj.position[:3], 1.5]
    return out


def main() -> None:
    ctx = create_headless_context()
    print(f"GL renderer: {ctx.info['GL_RENDERER']}")
    print("CPU per frame, every object moved (main-thread CPU time, best of 5; ratio: against the projection "
          "view of the same backend)")
    print(f"  {'scene':<14}{'view':<12}{'gpu ms':>9}{'gpu ratio':>11}{'gpu <= 1 ms':>13}{'clip ms':>10}"
          f"{'clip ratio':>12}{'section ms':>12}{'triangles':>11}")
    for name, scene in (("64 tesseracts", tesseracts(64)), ("64 all cut", all_cut(tesseracts(64))),
                        ("8 tesseracts", tesseracts(8)), ("120-cell", cell120())):
        base = {}
        for view in ("projection", "slice", "both"):
            t = {}
            for backend in ("gpu", "clip"):
                loop = ViewLoop(ctx, backend, scene, view)
                ctx.finish()
                t[backend] = best_of(loop.prepare, repeat=5)
                if backend == "gpu":
                    layer, c = loop.view.layer, loop.view.slice_w
                    section = best_of(lambda: section_triangles(layer, c), repeat=5)
                    n = len(section_triangles(layer, c)) // 3
                loop.release()
            base.setdefault("gpu", t["gpu"])
            base.setdefault("clip", t["clip"])
            ok = "yes" if t["gpu"] <= TARGET else "NO"
            print(f"  {name:<14}{view:<12}{t['gpu'] * 1e3:>9.3f}{t['gpu'] / base['gpu']:>10.2f}x{ok:>13}"
                  f"{t['clip'] * 1e3:>10.2f}{t['clip'] / base['clip']:>11.2f}x"
                  f"{section * 1e3 if view != 'projection' else 0:>12.3f}{n if view != 'projection' else 0:>11}")
    ctx.release()
    cut_alone(all_cut(tesseracts(64)))


def cut_alone(scene) -> None:
    """The cut of every body at one c, compiled and from `polygons`' array operations (the baseline)."""
    parts = [p for _, p in scene.world_parts()]
    vertices, normals = np.stack([p.vertices for p in parts]), np.stack([p.normals for p in parts])
    k = kernel(parts[0].topology)
    k.triangles(vertices, normals, 1.5)                     # compiled (or loaded from numba's cache) here
    compiled = best_of(lambda: k.triangles(vertices, normals, 1.5), repeat=20)
    arrays = best_of(lambda: k.fans(*k.polygons(vertices, normals, 1.5)), repeat=20)
    print(f"The cut alone, {len(parts)} tesseracts all cut at w = 1.5: compiled {compiled * 1e3:.3f} ms, "
          f"array operations {arrays * 1e3:.3f} ms ({arrays / compiled:.1f}x the compiled)")


if __name__ == "__main__":
    main()

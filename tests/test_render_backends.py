"""The GPU backend against the clip-unit backend and against touch: on every scene of the catalog, in
both projections, the two draw the same visible layers per object and the same outlines; for
interpenetrating objects and an object crossing the screen (w = 0), where clip units cannot follow,
the object seen at each 3D screen point is the one the tactile ray cast hits first there, at the
depth where it enters; turning the scene rewrites nothing but the objects' transforms.

Pictures are identity renders (offscreen.OffscreenRenderer.identities / layer_counts): per pixel
the 3D screen point, object and 4D depth of the nearest visible face, or how many visible layers of
each object it shows, so that comparing them is exact rather than a matter of blended colours."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import moderngl
import numpy as np
import pytest
from scipy import ndimage

from touch4d.geometry.polytope import Polytope
from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.rotation import plane_rotation, rotation_from_list
from touch4d.geometry.scene import load_scene, parse_scene
from touch4d.geometry.visibility import Relation, relations
from touch4d.render.camera import parse_camera
from touch4d.render.context import create_headless_context
from touch4d.render.frame import Style
from touch4d.render.offscreen import OffscreenRenderer
from touch4d.render.view import SceneView, Show

SIZE = (160, 160)
CATALOG = sorted(Path(__file__).resolve().parents[1].joinpath("config", "scenes").glob("*.yaml"))
OBLIQUE = parse_camera("yaw=25,pitch=15,distance=4.2,target=0:0:0")
FACE_ON = parse_camera("yaw=0,pitch=0,distance=4,target=0:0:0,ortho")
BARE = Show(frame=False, hand=False, tactile=False, status=False)


@pytest.fixture(scope="module")
def renderers():
    ctx = create_headless_context()
    out = {name: OffscreenRenderer(SIZE, backend=name, ctx=ctx) for name in ("gpu", "clip")}
    yield out
    for r in out.values():
        r.release()
    ctx.release()


def frame_of(scene, style=Style()):
    view = SceneView(None, style, BARE)
    view.set_scene(scene)
    return view.frame()


def outline(mask: np.ndarray) -> np.ndarray:
    return mask & ~ndimage.binary_erosion(mask, border_value=0)


def share_within(a: np.ndarray, b: np.ndarray, pixels: int) -> float:
    """The share of a's pixels that lie within `pixels` of one of b's."""
    if not a.any():
        return 1.0
    return float((a & ndimage.binary_dilation(b, iterations=pixels)).sum() / a.sum())


def test_auto_backend_and_fallback(renderers, monkeypatch, caplog):
    """"auto" draws with clip units on a software rasteriser (llvmpipe here) and with the GPU backend
    elsewhere; a context that cannot run the GPU backend gets the clip-unit one, with a warning."""
    import logging

    from touch4d.render import backends
    from touch4d.render.backends.gpu import GpuBackend

    ctx = renderers["gpu"].ctx
    # The renderer strings as Mesa, SwiftShader (Chrome's ANGLE) and NVIDIA's driver give them; the
    # suite runs on llvmpipe and on GPU machines alike, so the context's own string is not assumed.
    for renderer, expected in (("llvmpipe (LLVM 15.0.6, 256 bits)", "clip"),
                               ("Google SwiftShader", "clip"),
                               ("NVIDIA H100 80GB HBM3/PCIe/SSE2", "gpu")):
        monkeypatch.setitem(ctx.info, "GL_RENDERER", renderer)
        backend = backends.create_backend("auto", ctx)
        assert backend.name == expected, renderer
        backend.release()

    def unavailable(self, *args, **kwargs):
        raise backends.BackendUnavailable("no float render targets")
    monkeypatch.setattr(GpuBackend, "__init__", unavailable)
    log = logging.getLogger("test-renderer")
    with caplog.at_level(logging.WARNING):
        backend = backends.open_backend("gpu", ctx, log=log)
    assert backend.name == "clip" and "no float render targets" in caplog.text
    backend.release()
    with pytest.raises(ValueError, match="vulkan"):
        backends.create_backend("vulkan", ctx)


# ---- the two backends draw the same picture --------------------------------------------------------


@pytest.mark.timeout(300)
@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_gpu_and_clip_draw_the_same_layers_and_outlines_on_the_catalog(renderers, projection):
    """Per pixel and object, the number of visible face layers is the same on at least 97% of the
    pixels (and of those the scene covers); every object's outline in one picture lies within 2
    pixels of its outline in the other; edges too (99%). Objects that pass through each other have no
    front/behind order, which clip units need: there the GPU picture is checked against touch."""
    report = []
    for path in CATALOG:
        scene = replace(load_scene(path), projection=projection)
        frame = frame_of(scene)
        world = [p for _, p in scene.world_parts()]
        objects = np.array([i for i, _ in scene.world_parts()])
        meet = relations(world, scene.perspective_eye) == Relation.INTERSECTING
        faces = {n: r.layer_counts(frame, OBLIQUE) for n, r in renderers.items()}
        if (meet & (objects[:, None] != objects[None, :])).any():
            obj, w, hit, entry, gap = seen_versus_touched(renderers["gpu"], scene, Style(), OBLIQUE)
            agree = ((obj == hit) & (np.abs(w - entry) < 2e-3))[gap > 2e-3]
            same = np.all(faces["gpu"] == faces["clip"], axis=-1).mean()
            report.append(f"{path.stem} intersecting: seen = touched {agree.mean():.4f} (gpu = clip {same:.4f})")
            assert len(agree) > 3000 and agree.mean() >= 0.999, report[-1]
            continue
        edges = {n: r.layer_counts(frame, OBLIQUE, "edges") for n, r in renderers.items()}
        same = np.all(faces["gpu"] == faces["clip"], axis=-1)
        covered = (faces["gpu"].sum(-1) > 0) | (faces["clip"].sum(-1) > 0)
        assert covered.sum() > 500, path.name
        report.append(f"{path.stem} {same.mean():.4f} {same[covered].mean():.4f}")
        assert same.mean() >= 0.97 and same[covered].mean() >= 0.97, report[-1]
        for k in range(min(len(scene.objects), 4)):
            a, b = outline(faces["gpu"][..., k] > 0), outline(faces["clip"][..., k] > 0)
            assert a.any() and share_within(a, b, 2) == 1.0 and share_within(b, a, 2) == 1.0, (path.name, k)
            a, b = edges["gpu"][..., k] > 0, edges["clip"][..., k] > 0
            assert a.any() and min(share_within(a, b, 2), share_within(b, a, 2)) >= 0.99, (path.name, k)
    print("\n".join(report))


def test_the_comparison_sees_hidden_layers(renderers):
    """Drawing what nearer objects hide (clip off) changes the layer counts beyond the 97%: the
    comparison above would notice a backend that does not remove hidden hypersurfaces."""
    scene = load_scene(CATALOG[[p.stem for p in CATALOG].index("multi-object")])
    gpu_all = renderers["gpu"].layer_counts(frame_of(scene, Style(clip=False)), FACE_ON)
    clip = renderers["clip"].layer_counts(frame_of(scene), FACE_ON)
    assert np.all(gpu_all == clip, axis=-1).mean() < 0.97


# ---- what is seen is what is touched ---------------------------------------------------------------


def tesseract(position, size, rotation, color):
    return {"shape": "tesseract", "size": size, "position": position, "rotation": rotation, "color": color}


INTERPENETRATING = [tesseract([-0.15, 0.05, 0.0, 1.5], 1.0, [["xw", 25], ["yz", 20], ["yw", 10]], [0.3, 0.6, 1, 1]),
                    tesseract([0.25, -0.1, 0.1, 1.7], 0.9, [["zw", 30], ["xy", 35], ["xw", -20]], [1, 0.5, 0.2, 1])]
def crowd(n: int) -> list:
    """n tesseracts turned at random around one spot, at depths 1.2 to 2.5: every grid cell there
    lists many bodies (more than a cell holds for n = 20, so that all bodies are asked). No cell is
    nearly edge-on (|n_w| > 0.02): across such a cell the depth changes thousands of times faster
    than the screen point, so a float32 point would say nothing about which body is first."""
    rng = np.random.default_rng(n)
    planes = ["xy", "xz", "xw", "yz", "yw", "zw"]
    out = []
    while len(out) < n:
        rotation = [[p, float(rng.uniform(-40, 40))] for p in planes]
        if np.abs(rotation_from_list(rotation)[3]).min() > 0.02:   # n_w of the cells +-e_i
            out.append(tesseract([*rng.uniform(-0.3, 0.3, 3), 1.2 + 1.3 * len(out) / n], 0.7, rotation,
                                 [*rng.uniform(0.2, 1, 3), 1]))
    return out


CROSSING = [tesseract([0.1, 0.0, 0.0, 0.15], 1.0, [["xw", 35], ["zw", 20], ["xz", 15]], [0.3, 0.6, 1, 1]),
            {"shape": "24-cell", "size": 0.8, "position": [-0.45, 0.25, 0.0, 1.4], "rotation": [["yw", 25]],
             "color": [1, 0.5, 0.2, 1]}]


def first_hits(scene, points: np.ndarray):
    """The tactile ray cast (touch4d.geometry.raycast) through screen points: the object hit first,
    its entry depth w and the gap to the next object's entry (inf if none). The bodies are grown by
    1e-5 so that points on their surfaces, rounded to float32 by the GPU, count as on them."""
    eye = scene.perspective_eye
    parts = [(i, Polytope(p.vertices, p.normals, p.offsets + 1e-5, p.topology)) for i, p in scene.world_parts()]
    per_object = object_entries(RayCaster(parts, eye), points, eye)
    order = np.sort(per_object, axis=1)
    hit = np.where(np.isfinite(order[:, 0]), per_object.argmin(axis=1), -1)
    with np.errstate(invalid="ignore"):
        gap = np.where(np.isfinite(order[:, 0]), order[:, 1] - order[:, 0], np.inf)
    return hit, order[:, 0], gap


def object_entries(caster, points, eye):
    """(N, objects): where the ray through each point enters each object, w (inf: a miss)."""
    enter, _ = caster.intervals(points)
    if eye is not None:
        enter = enter * eye / (1.0 - enter)               # the projective depth back to w
    enter = np.where(np.isnan(enter), np.inf, enter)
    objects = caster.part_object
    return np.stack([enter[:, objects == k].min(axis=1) for k in range(objects.max() + 1)], axis=1)


def seen_versus_touched(renderer, scene, style, camera):
    """Every point the camera sees, the nearest face in front of several sections across the picture
    (so that faces inside it show too): its object and depth, and what the tactile ray cast says."""
    frame = frame_of(scene, style)
    seen_ids, seen_w = [], []
    for cut in (1.0, 0.25, 0.0, -0.25):
        ids, depth = renderer.identities(frame, camera, section=(*(camera.eye - camera.target), cut))
        seen = ids[..., 3] > 0.5
        seen_ids.append(ids[seen])
        seen_w.append(depth[seen])
    ids, w = np.concatenate(seen_ids), np.concatenate(seen_w)
    points = ids[:, :3].astype(np.float64)
    obj = np.round(ids[:, 3]).astype(int) - 1
    hit, entry, gap = first_hits(scene, points)
    return obj, w, hit, entry, gap


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
@pytest.mark.parametrize("objects", [INTERPENETRATING, CROSSING, crowd(10), crowd(20)],
                         ids=["interpenetrating", "crossing-w0", "crowd-10", "crowd-20"])
def test_the_object_seen_is_the_object_the_tactile_ray_hits_first(renderers, objects, projection):
    scene = parse_scene({"projection": projection, "eye_distance": 3.0, "objects": objects})
    if objects is CROSSING:
        w = scene.objects[0].world_parts()[0].vertices[:, 3]
        assert w.min() < -0.3 and w.max() > 0.3             # the screen cuts the first object
    for camera in (OBLIQUE, FACE_ON):
        obj, w, hit, entry, gap = seen_versus_touched(renderers["gpu"], scene, Style(), camera)
        contested = np.isfinite(gap)                # rays that meet two objects
        assert len(obj) > 3000 and contested.sum() > 150 and len(set(obj)) >= min(len(objects), 6)
        clear = gap > 2e-3                          # two entries at one depth: either may show
        assert clear.mean() > 0.97
        agree = (obj == hit) & (np.abs(w - entry) < 2e-3)
        assert agree[clear].mean() >= 0.999, (camera, np.unique(obj[clear & ~agree], return_counts=True))
        assert (w > -1e-3).all()                    # nothing before the screen, where the ray starts
    # Without hidden-hypersurface removal the check fails: it can tell.
    obj, w, hit, entry, gap = seen_versus_touched(renderers["gpu"], scene, Style(clip=False), OBLIQUE)
    assert ((obj == hit) & (np.abs(w - entry) < 2e-3))[gap > 2e-3].mean() < 0.99


# ---- per frame, only the transforms change ---------------------------------------------------------


class WriteLog:
    """Counts the bytes moderngl sends to buffers and textures (writes and creation with data)."""

    def __init__(self, monkeypatch):
        self.writes = []
        for cls in (moderngl.Buffer, moderngl.Texture):
            original = cls.write

            def write(obj, data, *args, _original=original, **kwargs):
                self.writes.append((obj, memoryview(data).nbytes))
                return _original(obj, data, *args, **kwargs)
            monkeypatch.setattr(cls, "write", write)
        for name in ("buffer", "texture"):
            original = getattr(moderngl.Context, name)

            def make(ctx, *args, _original=original, _name=name, **kwargs):
                obj = _original(ctx, *args, **kwargs)
                data = kwargs.get("data", args[0] if _name == "buffer" and args else
                                  args[2] if _name == "texture" and len(args) > 2 else None)
                if data is not None:
                    self.writes.append((obj, memoryview(data).nbytes))
                return obj
            monkeypatch.setattr(moderngl.Context, name, make)

    def take(self):
        out, self.writes = self.writes, []
        return out


@pytest.mark.parametrize("backend", ["gpu", "clip"])
def test_turning_the_scene_rewrites_only_the_transforms(renderers, monkeypatch, backend):
    """A rotation of the 4D scene: the GPU backend writes the objects' transforms (6 RGBA32F texels,
    96 bytes, per object) and nothing else; the clip backend re-sends its vertex arrays."""
    renderer = renderers[backend]
    objects = [tesseract([-0.3 + 0.3 * k, 0.1 * k, 0.0, 1.5 + 0.4 * k], 0.6, [["xw", 10 * k]], [0.2 * k, 1, 0.5, 1])
               for k in range(3)]
    view = SceneView(None, Style(), BARE)
    view.set_scene(parse_scene({"objects": objects}))
    log = WriteLog(monkeypatch)
    first = renderer.render(view, FACE_ON)
    assert sum(n for _, n in log.take()) > 3 * 96                 # the geometry, once
    renderer.render(view, FACE_ON)
    if backend == "gpu":
        assert log.take() == []                                   # nothing moved: nothing written
    for step in range(1, 4):
        turned = parse_scene({"objects": objects})
        for obj in turned.objects:
            obj.orientation = plane_rotation("xw", 0.2 * step) @ plane_rotation("yz", 0.1 * step) @ obj.orientation
        view.set_scene(turned)
        image = renderer.render(view, FACE_ON)
        writes = log.take()
        assert not np.array_equal(image, first)                   # the picture did change
        if backend == "gpu":
            assert len(writes) == 1 and writes[0][1] == 3 * 96    # the transforms texture only
            assert writes[0][0].size == (1024, 1)                 # a data texture: 1024 texels a row
        else:
            assert sum(n for _, n in writes) > 20 * 96

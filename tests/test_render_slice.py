"""The slice view in the desktop renderer: the cross-section drawn solid where the closed form puts it,
in its cells' colours; the GPU and clip-unit backends draw the same pictures in the slice and both views
on scenes generated at random; the status line says where the slice cuts."""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image

from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.scene import Scene, SceneObject, parse_scene
from touch4d.geometry.section import w_extent
from touch4d.geometry.shapes import get_shape
from touch4d.commands import render as render_cli
from touch4d.render.camera import parse_camera
from touch4d.render.context import create_headless_context
from touch4d.render.frame import CELL_PALETTE, Style
from touch4d.render.offscreen import OffscreenRenderer
from touch4d.render.view import BACKGROUND, SceneView, Show

from test_geometry_section import turn

SIZE = (200, 160)
FACE_ON = parse_camera("yaw=0,pitch=0,distance=4,target=0:0:0,ortho")
OBLIQUE = parse_camera("yaw=30,pitch=20,distance=4.5,target=0:0:0")
BARE = Show(frame=False, hand=False, tactile=False, status=False)
SHAPES = ("tesseract", "16-cell", "24-cell", "5-cell", "prism", "duoprism")


@pytest.fixture(scope="module")
def renderers():
    ctx = create_headless_context()
    out = {name: OffscreenRenderer(SIZE, backend=name, ctx=ctx) for name in ("gpu", "clip")}
    yield out
    for r in out.values():
        r.release()
    ctx.release()


def picture(renderer, scene, camera=FACE_ON, **view):
    v = SceneView(None, Style(), BARE, **view)
    v.set_scene(scene)
    return renderer.render(v, camera)


def drawn(image) -> np.ndarray:
    background = np.round(np.array(BACKGROUND[:3]) * 255)
    return np.any(np.abs(image[..., :3].astype(int) - background) > 2, axis=-1)


def box_pixels(mask) -> tuple[int, int]:
    rows, cols = np.nonzero(mask)
    return cols.max() - cols.min() + 1, rows.max() - rows.min() + 1


def pixels_per_unit() -> float:
    """Pixels per screen unit across the picture, for the face-on orthographic camera."""
    return FACE_ON.matrix(SIZE)[0, 0] * SIZE[0] / 2


def one(shape="tesseract", size=1.0, orientation=np.eye(4), w=1.5, c=1.5, view="slice", projection="orthographic"):
    obj = SceneObject(name="a", shape=shape, size=size, position=np.array([0, 0, 0, w]), orientation=orientation)
    return Scene(objects=[obj], view=view, slice_w=c, projection=projection)


def random_scene(seed: int, view: str) -> Scene:
    """A few shapes of the catalog, turned, sized and placed at random in cells of a grid (so that they
    do not interpenetrate: there clip units cannot follow), each moved along w so that the cut goes
    through the middle half of its w extent (every object has a section to draw)."""
    rng = np.random.default_rng(seed)
    objects = []
    c = float(rng.uniform(1.4, 1.6))
    corners = rng.permutation([[x, y, z] for x in (-0.55, 0.55) for y in (-0.55, 0.55) for z in (-0.55, 0.55)])
    for i in range(rng.integers(2, 5)):
        name, size, orientation = str(rng.choice(SHAPES)), float(rng.uniform(0.4, 0.5)), turn(rng)
        lo, hi = w_extent(np.vstack([p.transformed(orientation, size=size).vertices for p in get_shape(name).parts]))
        objects.append(SceneObject(            # within 0.5 of its centre (every shape of size 1 lies within 1)
            name=f"o{i}", shape=name, size=size, orientation=orientation,
            position=np.r_[corners[i] + rng.uniform(-0.04, 0.04, 3), c - lo - rng.uniform(0.25, 0.75) * (hi - lo)],
            color=np.r_[rng.uniform(0.2, 1, 3), 1.0]))
    projection = str(rng.choice(["orthographic", "perspective"]))
    return Scene(objects=objects, view=view, slice_w=c, projection=projection)


def test_a_tesseract_is_cut_in_a_cube_of_its_size(renderers):
    """Face on, with an orthographic camera, the section of an upright tesseract covers the square of
    its projection; turned by theta in xw it is 1 / cos(theta) wide (the projection: cos + sin)."""
    r = renderers["clip"]
    unit = pixels_per_unit()
    for size in (1.0, 1.2):
        assert box_pixels(drawn(picture(r, one(size=size)))) == pytest.approx((size * unit, size * unit), abs=1.5)
    for degrees in (20, 35):
        turned = drawn(picture(r, one(orientation=plane_rotation("xw", np.radians(degrees)))))
        assert box_pixels(turned) == pytest.approx((unit / np.cos(np.radians(degrees)), unit), abs=1.5)
    assert not drawn(picture(r, one(c=2.2))).any()                 # outside w 1 .. 2: nothing to cut


def test_the_section_faces_wear_their_cells_colours(renderers):
    image = picture(renderers["clip"], one(orientation=plane_rotation("xy", 0.3) @ plane_rotation("yz", 0.4)),
                    OBLIQUE)
    seen = image[drawn(image)][:, :3].astype(float) / 255
    hues = CELL_PALETTE / CELL_PALETTE.max(axis=1, keepdims=True)   # shading scales a colour, keeps its hue
    seen_hue = seen / np.maximum(seen.max(axis=1, keepdims=True), 1e-6)
    nearest = np.min(np.abs(seen_hue[:, None] - hues[None]).max(axis=-1), axis=1)
    assert np.mean(nearest < 0.06) > 0.97
    assert len(np.unique(np.argmin(np.abs(seen_hue[:, None] - hues[None]).max(axis=-1), axis=1))) >= 3


def test_perspective_puts_the_section_inside_the_projection(renderers):
    r = renderers["clip"]
    section = drawn(picture(r, one(c=1.5, projection="perspective")))
    whole = drawn(picture(r, one(c=1.5, projection="perspective", view="projection")))
    assert section.sum() > 500 and not (section & ~whole).any()
    # the unit cube at w = 1.5 is drawn at d / (d + 1.5) of its size (eye distance d = 3)
    assert box_pixels(section) == pytest.approx((3 / 4.5 * pixels_per_unit(),) * 2, abs=1.5)


@pytest.mark.parametrize("view", ["slice", "both"])
@pytest.mark.parametrize("seed", range(6))
def test_gpu_and_clip_draw_the_same_picture(renderers, view, seed):
    """Pixel for pixel, no neighbour allowed: the same solid through the same painter; the translucent
    projection's edges and faces where both backends put them, its faces blended order-independently by
    both, under the same depth rule."""
    scene = random_scene(seed, view)
    camera = parse_camera(f"yaw={20 + 15 * seed},pitch={10 + 5 * seed},distance=3.4,target=0:0:0")
    gpu = picture(renderers["gpu"], scene, camera).astype(int)
    clip = picture(renderers["clip"], scene, camera).astype(int)
    assert drawn(clip).sum() > 300                 # something to compare
    same = np.abs(gpu[..., :3] - clip[..., :3]).max(axis=-1) <= 2
    if view == "slice":
        assert same.all(), seed
    assert same[drawn(gpu) | drawn(clip)].mean() >= 0.995, (view, seed)


@pytest.mark.parametrize("backend", ["gpu", "clip"])
def test_in_the_both_view_the_projection_behind_the_solid_is_hidden_and_in_front_tints_it(renderers, backend):
    """Face on from +z: a tesseract cut through (its section, a solid cube) and a smaller one that w = c
    misses (only its translucent projection drawn), partly over the solid, behind it or in front of it."""
    r = renderers[backend]
    cut = SceneObject(name="cut", shape="tesseract", size=1.2, position=np.array([0.0, 0.0, 0.0, 1.5]))

    def scene(*z_ghost):
        ghosts = [SceneObject(name="ghost", shape="tesseract", size=0.6, position=np.array([0.5, 0.0, z, 2.6]),
                              color=np.array([1.0, 1.0, 0.2, 1.0])) for z in z_ghost]
        return Scene(objects=[cut, *ghosts], view="both", slice_w=1.5)

    alone, behind, front = (picture(r, scene(*z)) for z in ((), (-1.0,), (1.0,)))
    unit, (width, height) = pixels_per_unit(), SIZE
    cols = np.arange(width) - width / 2 + 0.5
    rows = height / 2 - np.arange(height) + 0.5
    inner = lambda lo, hi, v: (v > lo * unit + 3) & (v < hi * unit - 3)      # 3 pixels in from the edges
    ghost = inner(0.2, 0.6, cols)[None] & inner(-0.3, 0.3, rows)[:, None]      # the ghost's square over the solid
    assert ghost.sum() > 300 and drawn(alone)[ghost].all()
    assert np.array_equal(behind[ghost], alone[ghost])                      # the solid hides what is behind it
    tint = np.abs(front[ghost][:, :3].astype(int) - alone[ghost][:, :3]).max(axis=-1)
    assert tint.min() >= 3                                                  # what is in front tints it
    assert not np.array_equal(behind, alone)                                # and drawn where it sticks out


def test_the_renderer_can_override_the_scenes_view(renderers):
    r = renderers["clip"]
    scene = one(view="projection")
    overridden = picture(r, scene, OBLIQUE, view="slice", slice_w=1.5)
    assert np.array_equal(overridden, picture(r, replace(scene, view="slice"), OBLIQUE))


def test_the_status_line_says_where_the_slice_cuts():
    view = SceneView(None, Style(), BARE)
    view.set_scene(one(orientation=np.eye(4), c=1.25, view="both"))
    assert "both view: slice at w = 1.25 (objects span w 1.00 .. 2.00)" in view.status_lines()
    view.set_scene(one(view="projection"))
    assert not any("slice" in line for line in view.status_lines())


def test_render_command_draws_the_slice(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    render_cli.register(parser.add_subparsers())
    out = tmp_path / "slice.png"
    args = parser.parse_args(["render", "--scene", "config/scenes/hypercube.yaml", "--view", "slice", "--slice-w",
                              "1.5", "--camera", "yaw=0,pitch=0,distance=4,ortho", "--backend", "clip",
                              "--size", "200x160", "--samples", "0", "--no-frame", "--no-status", "-o", str(out)])
    assert args.func(args) == 0
    image = np.asarray(Image.open(out).convert("RGBA"))
    width, height = box_pixels(drawn(image))
    # the scene's tesseract (size 1.2) is cut in a 1.2 cube: face on, a square
    assert width == pytest.approx(height, abs=1) and width > 40
    scene = parse_scene({"objects": [{"shape": "tesseract", "position": [0, 0, 0, 1.5]}]})
    assert scene.slice_w == 1.5                                    # by default the middle of the w extent


def test_the_renderer_node_draws_the_slice_its_view_parameter_asks_for():
    from touch4d.bus import Node
    from touch4d.bus.testing import running_broker, wait_until
    from touch4d.errors import ConfigError
    from touch4d.nodes.renderer import RendererNode

    params = {"headless": True, "width": 200, "height": 160, "samples": 0, "rate": 30.0, "show_status": False,
              "show_frame": False, "show_tactile": False, "backend": "clip",
              "camera": "yaw=0,pitch=0,distance=4,target=0:0:0,ortho"}
    msg = one(view="projection").to_message()
    with running_broker() as bus:
        with pytest.raises(ConfigError, match="view.*sideways"):
            RendererNode(params={**params, "view": "sideways"}, bus=bus, heartbeat=False)
        node = RendererNode(params={**params, "view": "slice", "slice_w": 1.5}, bus=bus, heartbeat=False)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            pub = probe.create_publisher("scene/state", type(msg))

            def drawn_cube():
                pub.publish(msg)
                node.spin_once(0.05)
                if not node.counts["frames"] or node.view.scene is None:
                    return None
                image = node.renderer.read()
                return [image] if drawn(image).sum() > 1000 else None

            image = wait_until(drawn_cube, timeout=90, interval=0.0)[0]
        finally:
            probe.shutdown()
            node.shutdown()
    # the unit tesseract's section, face on: a solid square of the cube's size in its cells' colours
    assert node.view.view == "slice"
    assert box_pixels(drawn(image)) == pytest.approx((pixels_per_unit(),) * 2, abs=1.5)

"""Screenshots on a headless EGL context (Mesa llvmpipe), checked pixel by pixel, for both backends.

Flat, distinct colours on a black background, no multisampling, so colours are exact."""
from __future__ import annotations

import numpy as np
import pytest

from touch4d.geometry.projection import project
from touch4d.geometry.scene import parse_scene
from touch4d.geometry.visibility import facing_cells
from touch4d.messages import TactileField
from touch4d.render.camera import OrbitCamera
from touch4d.render.frame import Style, cell_color
from touch4d.render.hud import MOTOR_COLOR, TactileCube, amplitude_colors
from touch4d.render.offscreen import OffscreenRenderer
from touch4d.render.view import SceneView, Show
from touch4d.tactile.glove import load_glove

SIZE = (320, 320)
FRONT = Show(frame=False, hand=False, tactile=False, status=False)
FACE_ON = OrbitCamera(yaw=0.0, pitch=0.0, distance=4.0, target=np.zeros(3), ortho=True)


@pytest.fixture(scope="module", params=["gpu", "clip"])
def renderer(request):
    r = OffscreenRenderer(SIZE, samples=0, background=(0.0, 0.0, 0.0, 1.0), backend=request.param)
    assert r.backend.name == request.param
    yield r
    r.release()


def scene(objects, projection="orthographic"):
    return parse_scene({"projection": projection, "eye_distance": 3.0, "objects": objects})


def tesseract(position, size, color, rotation=None):
    obj = {"shape": "tesseract", "size": size, "position": position, "color": color}
    if rotation:
        obj["rotation"] = rotation
    return obj


def draw(renderer, objects, style, projection="orthographic", camera=FACE_ON):
    view = SceneView(None, style, FRONT)
    view.set_scene(scene(objects, projection))
    return view, renderer.render(view, camera)


def front_cells(view, index=0):
    """The local indices of the cells of object `index` that face the viewer (reference culling)."""
    scene = view.scene
    world = scene.objects[index].world_parts()[0]
    return np.nonzero(facing_cells(world, scene.perspective_eye))[0]


def pixel(image, camera, point):
    x, y = camera.to_pixels(np.array([point]), SIZE)[0]
    return image[int(y), int(x), :3].astype(int)


def count_color(image, rgb, tol=2):
    return int(np.all(np.abs(image[..., :3].astype(int) - np.round(np.asarray(rgb) * 255)) <= tol, axis=-1).sum())


def test_face_on_tesseract_is_a_square_outline_with_the_centre_copy_inside(renderer):
    style = Style(fill_alpha=0.25, centre_alpha=1.0)
    view, image = draw(renderer, [tesseract([0, 0, 0, 1.5], 1.0, [0, 1, 0, 1])], style)
    cells = front_cells(view)
    assert len(cells) == 1                                   # only the front cell faces the viewer
    centre_rgb = np.round(cell_color(cells[0]) * 255)
    # The centre copy: the cell scaled 0.3 about its centre, |x|, |y| <= 0.15, in the cell's colour.
    for p in ([0, 0, 0], [0.1, 0.1, 0], [-0.12, 0.05, 0]):
        assert np.abs(pixel(image, FACE_ON, p) - centre_rgb).max() <= 1
    # The outline: the front cell's edges, full green, along all four sides of the square.
    for t in np.linspace(-0.4, 0.4, 9):
        for p in ([t, 0.5, 0], [t, -0.5, 0], [0.5, t, 0], [-0.5, t, 0]):
            x, y = FACE_ON.to_pixels(np.array([p]), SIZE)[0]
            patch = image[int(y) - 1:int(y) + 2, int(x) - 1:int(x) + 2, :3].astype(int)
            assert (patch[..., 1] >= 250).any() and patch[..., 0].max() == 0 and patch[..., 2].max() == 0
    # Between outline and centre copy only the semi-transparent green fill; outside, background.
    for p in ([0.33, 0, 0], [-0.3, 0.3, 0], [0, -0.35, 0]):
        r, g, b = pixel(image, FACE_ON, p)
        assert r == 0 and b == 0 and 40 <= g <= 200
    for p in ([0.7, 0, 0], [0, -0.75, 0], [-0.7, 0.7, 0]):
        assert pixel(image, FACE_ON, p).tolist() == [0, 0, 0]


def test_turning_in_xw_shows_more_cells(renderer):
    style = Style(fill_alpha=0.25, centre_alpha=1.0)
    view0, face_on = draw(renderer, [tesseract([0, 0, 0, 1.5], 1.0, [0, 1, 0, 1])], style)
    view1, turned = draw(renderer, [tesseract([0, 0, 0, 1.5], 1.0, [0, 1, 0, 1], [["xw", 30]])], style)
    front = front_cells(view0)
    cells = front_cells(view1)
    assert len(cells) == 2 and set(front) < set(cells)
    for c in cells:                                          # each visible cell's centre copy shows
        assert count_color(turned, cell_color(c)) > 50
    (new,) = set(cells) - set(front)
    assert count_color(face_on, cell_color(new)) == 0


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_object_behind_is_clipped_where_covered(renderer, projection):
    objects = [tesseract([-0.2, 0, 0, 1.5], 0.6, [0, 1, 0, 1]), tesseract([0.2, 0.1, 0, 2.5], 0.6, [1, 0, 0, 1])]
    style = Style(centres=False, fill_alpha=0.3)
    view, image = draw(renderer, objects, style, projection)
    outline = project(view.scene.objects[0].world_parts()[0].vertices, projection, 3.0)
    lo, hi = outline.min(axis=0), outline.max(axis=0)       # the front object's outline, face-on: a box
    (x0, y1), (x1, y0) = FACE_ON.to_pixels(np.array([lo, hi]), SIZE)
    inside = np.zeros(image.shape[:2], bool)
    inside[int(y0) + 2:int(y1) - 1, int(x0) + 2:int(x1) - 1] = True
    red = image[..., 0] > 0
    assert (image[inside, 1] > 0).mean() > 0.99              # the silhouette is the front object's
    assert not red[inside].any()                             # nothing of the back object inside it
    assert red[~inside].sum() > 200                          # ... but it shows beside it
    _, unclipped = draw(renderer, objects, Style(centres=False, fill_alpha=0.3, clip=False), projection)
    assert (unclipped[..., 0] > 0)[inside].sum() > 200       # without clip units it would show through


def test_tactile_cube_colours_follow_the_field(renderer):
    glove = load_glove()
    cube = TactileCube()
    local = glove.samples
    h = np.where(local[:, 0] > np.median(local[:, 0]), 1.0, np.where(local[:, 1] > 0.05, 0.5, 0.0))
    field = TactileField(positions=np.zeros((len(h), 3)), l=np.ones(len(h)), s=h, h=h, alpha=3.0, beta=0.5, gamma=1.0)
    view = SceneView(glove, Style(), Show(frame=False, hand=False, tactile=True, status=False), cube)
    view.set_field(field)
    camera = OrbitCamera(yaw=0.0, pitch=0.0, distance=3.0, target=np.array(cube.center), ortho=True)
    image = renderer.render(view, camera)
    where = camera.to_pixels(cube.layout(local), SIZE)
    seen = image[where[:, 1].astype(int), where[:, 0].astype(int), :3].astype(int)
    assert np.abs(seen - np.round(amplitude_colors(h) * 255)).max() <= 2
    assert len(set(map(tuple, seen))) == 3
    # Motor samples are ringed in cyan.
    cyan = np.all(image[..., :3] == np.round(np.array(MOTOR_COLOR[:3]) * 255), axis=-1)
    for x, y in where[glove.motor_sample]:
        assert cyan[int(y) - 5:int(y) + 6, int(x) - 5:int(x) + 6].any()


def test_hand_is_drawn_where_its_pose_puts_it(renderer):
    from touch4d.messages import HandPose
    from touch4d.render.hud import HAND_COLOR
    from touch4d.tactile.pose import place

    glove = load_glove()
    view = SceneView(glove, Style(), Show(frame=False, hand=True, tactile=False, status=False))
    pose = HandPose(position=np.array([0.3, -0.2, 0.0]), orientation=np.array([0.0, 0.0, np.sin(0.3), np.cos(0.3)]),
                    valid=True)
    view.set_hand(pose)
    image = renderer.render(view, FACE_ON)
    where = FACE_ON.to_pixels(place(glove.samples, glove.units_per_metre, pose.position, pose.orientation), SIZE)
    seen = image[where[:, 1].astype(int), where[:, 0].astype(int), :3].astype(int)
    # The hand's colour at every sample (brighter where samples at several depths overlap, alpha 0.9).
    ratio = seen / (np.array(HAND_COLOR[:3]) * 255)
    assert ratio.min() >= HAND_COLOR[3] - 0.02 and ratio.max() <= 1.01
    assert np.ptp(ratio, axis=1).max() <= 0.02
    view.set_hand(HandPose(position=pose.position, orientation=pose.orientation, valid=False))
    assert renderer.render(view, FACE_ON)[..., :3].max() == 0          # tracking lost: no hand

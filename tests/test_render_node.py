"""The renderer node, headless (EGL), in-process on a test bus: it draws what is published and keeps
the last good scene through one it cannot build."""
from __future__ import annotations

import msgspec
import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import running_broker, wait_until
from touch4d.errors import ConfigError
from touch4d.geometry.scene import parse_scene
from touch4d.messages import SceneState, TactileField
from touch4d.nodes.renderer import RendererNode
from touch4d.render.camera import parse_camera
from touch4d.render.hud import TactileCube, amplitude_colors
from touch4d.tactile.glove import load_glove

SIZE = 320
BASE = {"headless": True, "width": SIZE, "height": SIZE, "samples": 0, "rate": 30.0, "show_status": False,
        "show_frame": False}


@pytest.fixture
def bus():
    with running_broker() as config:
        yield config


@pytest.fixture
def probe(bus):
    node = Node("probe", bus=bus, heartbeat=False)
    yield node
    node.shutdown()


def make_node(bus, **params):
    return RendererNode(params={**BASE, **params}, bus=bus, heartbeat=False)


def spin_until(node, predicate, publish=None, timeout=90.0):
    def check():
        if publish:
            publish()
        node.spin_once(0.05)
        return predicate()
    return wait_until(check, timeout=timeout, interval=0.0)


@pytest.mark.timeout(300)
def test_tactile_cube_follows_a_published_field(bus, probe):
    glove = load_glove()
    cube = TactileCube()
    camera_text = f"yaw=0,pitch=0,distance=3,target={cube.center[0]}:0:0,ortho"
    node = make_node(bus, camera=camera_text)
    try:
        local = glove.samples
        where = parse_camera(camera_text).to_pixels(cube.layout(local), (SIZE, SIZE)).astype(int)
        pub = probe.create_publisher("tactile/field", TactileField)
        for h in (np.where(local[:, 0] > np.median(local[:, 0]), 1.0, 0.0),
                  np.where(local[:, 1] > 0.03, 0.5, 0.0)):
            field = TactileField(positions=np.zeros((len(h), 3)), l=np.ones(len(h)), s=h, h=h,
                                 alpha=3.0, beta=0.5, gamma=1.0)
            expected = np.round(amplitude_colors(h) * 255)

            def shows_field():
                seen = node.renderer.read()[where[:, 1], where[:, 0], :3].astype(int)
                return np.abs(seen - expected).max() <= 2

            spin_until(node, shows_field, lambda: pub.publish(field))
        assert node.counts["bad_fields"] == 0 and node.counts["frames"] > 0
    finally:
        node.shutdown()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("backend", ["gpu", "clip"])
def test_keeps_the_last_good_scene_through_a_bad_one(bus, probe, tmp_path, backend):
    out = tmp_path / "frame.png"
    node = make_node(bus, camera="yaw=0,pitch=0,distance=4,target=0:0:0,ortho", show_tactile=False,
                     output=str(out), backend=backend)
    try:
        assert node.backend.name == backend
        pub = probe.create_publisher("scene/state", SceneState)
        good = parse_scene({"objects": [{"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5],
                                         "color": [0, 1, 0, 1]}]}).to_message()
        green = lambda: (node.renderer.read()[..., 1] > 200).sum() > 100    # noqa: E731 - the outline
        spin_until(node, green, lambda: pub.publish(good))
        spin_until(node, lambda: node._received["scene"] >= 5, lambda: pub.publish(good))
        assert node.counts["scenes_built"] == 1          # the repeated message is not built again
        # Half-spaces that bound nothing: the geometry cannot build it; the node says so and carries on.
        unbounded = np.array([[1.0, 0, 0, 0, 1], [-1, 0, 0, 0, 1], [0, 1, 0, 0, 1], [0, -1, 0, 0, 1], [0, 0, 1, 0, 1]])
        bad = SceneState(objects=[{**good.objects[0], "shape": "custom", "parts": [unbounded]}],
                         projection="orthographic", eye_distance=3.0, selected=0, revision=7)
        spin_until(node, lambda: node.counts["bad_scenes"] > 0, lambda: pub.publish(bad))
        frames = node.counts["frames"]
        spin_until(node, lambda: node.counts["frames"] > frames + 3)
        assert green()
        from PIL import Image
        last = sorted(tmp_path.glob("frame-*.png"))[-1]                   # numbered: frame-000042.png
        assert (np.asarray(Image.open(last))[..., 1] > 200).sum() > 100  # the PNG written is that frame
    finally:
        node.shutdown()


def test_bad_parameters_name_the_parameter(bus):
    with pytest.raises(ConfigError, match="rate"):
        make_node(bus, rate=0.0)
    with pytest.raises(ConfigError, match="camera.*zoom"):
        make_node(bus, camera="zoom=3")
    with pytest.raises(ConfigError, match="backend.*vulkan"):
        make_node(bus, backend="vulkan")


def test_view_builds_a_scenes_geometry_once_until_its_shapes_or_colours_change():
    """The scene node repeats `scene/state` for late joiners and turns objects at the controller's rate:
    a repeat changes nothing, a new pose only the transforms, a new colour (or shape) the geometry."""
    from touch4d.render.view import SceneView, Show

    msg = parse_scene({"objects": [{"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5],
                                    "color": [0, 1, 0, 1]}]}).to_message()
    view = SceneView(None, show=Show(frame=False, hand=False, tactile=False, status=False))
    assert view.set_scene(msg)
    layer = view.frame().scene
    assert not view.set_scene(msgspec.structs.replace(msg, revision=msg.revision + 1))
    assert view.frame().scene is layer and view.geometry_builds == 1
    moved = msgspec.structs.replace(msg, objects=[{**msg.objects[0], "position": np.array([0.1, 0, 0, 1.5])}])
    assert view.set_scene(moved)
    assert view.frame().scene is not layer and view.frame().scene.geometry is layer.geometry
    assert view.frame().scene.transforms[0, 4].tolist() == pytest.approx([0.1, 0, 0, 1.5])
    recoloured = msgspec.structs.replace(msg, objects=[{**msg.objects[0], "color": np.array([1.0, 0, 0, 1])}])
    assert view.set_scene(recoloured) and view.frame().scene.geometry is not layer.geometry
    assert view.geometry_builds == 2



@pytest.mark.timeout(300)
@pytest.mark.parametrize("output, first", [("shot.png", "shot-000000.png"), ("frames/", "frames/frame-000000.png"),
                                          ("f/{frame:03d}.png", "f/000.png")])
def test_headless_frames_are_numbered_files_not_one_overwritten(bus, tmp_path, output, first, caplog):
    caplog.set_level("INFO")
    node = make_node(bus, output=str(tmp_path / output) + ("/" if output.endswith("/") else ""), max_frames=3)
    try:
        spin_until(node, lambda: node.counts["frames"] >= 3)
    finally:
        node.shutdown()
    files = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*.png"))
    assert len(files) == 3 and files[0] == first
    assert str(tmp_path / first) in caplog.text       # the node says where its frames go


def test_headless_without_output_says_where_to_look(bus, caplog):
    with caplog.at_level("INFO"):
        node = make_node(bus)
        node.shutdown()
    assert "nothing is shown" in caplog.text and "renderer.output:=" in caplog.text and "xvfb-run" in caplog.text

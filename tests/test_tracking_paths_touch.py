"""The scripted paths do what their names promise against their scenes, through the tactile model:
the demo touches the (slowly spinning) hypercube and then leaves it; presses touch only at the target."""
import numpy as np
import pytest

from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.scene import load_scene
from touch4d.tactile.glove import load_glove
from touch4d.tactile.stimulus import compute_stimulus
from touch4d.tracking.config import CONFIG_DIR
from touch4d.tracking.paths import load_path

GLOVE = load_glove()


def motors(scene, sample):
    return compute_stimulus(GLOVE, scene.ray_caster(), sample.position, sample.orientation).V


@pytest.mark.parametrize("spin_deg", [0.0, 40.0, 110.0])
def test_demo_path_touches_the_hypercube_then_leaves_it(spin_deg):
    scene = load_scene(CONFIG_DIR / "scenes" / "hypercube.yaml")
    obj = scene.objects[0]
    obj.orientation = plane_rotation("xw", np.radians(spin_deg)) @ obj.orientation   # the demo's spin
    demo = load_path("demo")
    times = np.arange(0.0, demo.duration, 0.25)
    on = np.array([motors(scene, demo.sample(t)).max() for t in times])
    assert on[0] == 0.0 and on[-1] == 0.0                 # starts and ends with every motor off
    touching = times[on > 0]
    assert len(touching) >= 8                             # on for at least 2 s of the loop
    assert touching.min() > 1.0 and touching.max() < demo.duration - 1.0


@pytest.mark.parametrize("scene_name, path_name", [("hypercube-edge.yaml", "edge-press"),
                                                   ("hypercube-vertex.yaml", "vertex-press"),
                                                   ("hypercube-face.yaml", "face-sweep")])
def test_presses_and_sweeps_touch_only_on_the_object(scene_name, path_name):
    scene = load_scene(CONFIG_DIR / "scenes" / scene_name)
    path = load_path(path_name)
    times = np.linspace(0.0, path.duration, 33)
    on = np.array([motors(scene, path.sample(t)).max() for t in times])
    assert on[0] == 0.0 and on[-1] == 0.0
    assert (on > 0).sum() >= 4

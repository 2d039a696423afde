"""The tactile model on the GPU (touch4d.render.tactile: the renderer's own ray test of
halfspace.glsl, per glove sample) against the CPU tactile engine, on random scenes and hand poses:
every motor within 0.01 of full drive, for the 30-motor glove and the held controller."""
from __future__ import annotations

import numpy as np
import pytest

from gpu_tactile_cases import random_pose, random_scene
from touch4d.configfile import CONFIG_DIR
from touch4d.geometry.scene import parse_scene
from touch4d.render.tactile import GpuTactile
from touch4d.tactile import compute_stimulus, load_glove

GLOVES = {"glove": CONFIG_DIR / "glove.yaml", "controller": CONFIG_DIR / "gloves" / "quest-controller.yaml"}


@pytest.fixture(scope="module")
def gpu():
    g = GpuTactile()
    yield g
    g.release()


def assert_agrees(gpu, glove, rng, make_scene, check_touched) -> None:
    """12 scenes from `make_scene(k)`, 15 random poses each: the same samples touched (one may go
    either way at a boundary in float32), `check_touched(got, cpu, both)` on those, every motor within
    0.01 of full drive, and enough poses touching for the cases to prove something."""
    touching, worst = 0, 0.0
    for k in range(12):
        scene = make_scene(k)
        gpu.set_scene(scene.to_message())
        caster = scene.ray_caster()
        for _ in range(15):
            position, orientation = random_pose(rng)
            cpu = compute_stimulus(glove, caster, position, orientation)
            got = gpu.stimulus(glove, position, orientation)
            assert np.count_nonzero(cpu.touched != got.touched) <= 1
            check_touched(got, cpu, cpu.touched & got.touched)
            worst = max(worst, float(np.abs(got.V - cpu.V).max()))
            touching += bool(cpu.V.max() > 0.05)
    assert worst <= 0.01, f"a motor differs by {worst:.4f} of full drive"
    assert touching >= 40, f"only {touching} of 180 poses touch anything: the cases prove little"


@pytest.mark.parametrize("glove_name", sorted(GLOVES))
def test_gpu_touch_agrees_with_the_cpu_model_on_random_scenes_and_poses(gpu, glove_name):
    rng = np.random.default_rng(20261206)

    def same_depths(got, cpu, both):
        np.testing.assert_allclose(got.l[both], cpu.l[both], atol=1e-3)
        assert np.array_equal(got.hit[both], cpu.hit[both])

    assert_agrees(gpu, load_glove(GLOVES[glove_name]), rng, lambda k: random_scene(rng), same_depths)


def test_a_hand_outside_the_screen_or_before_any_object_feels_nothing(gpu):
    glove = load_glove(GLOVES["glove"])
    gpu.set_scene(parse_scene({"objects": [{"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5]}]})
                  .to_message())
    assert gpu.stimulus(glove, [3.0, 0, 0], [0, 0, 0, 1]).V.max() == 0
    st = gpu.stimulus(glove, [0.0, 0.0, 0.0], [0, 0, 0, 1])
    # the tesseract's front cell is flat along w at 1.0: every sample in it touches at l = 1
    inside = np.abs(st.positions).max(axis=1) < 0.5
    assert inside.any() and np.allclose(st.l[inside], 1.0, atol=1e-5)


@pytest.mark.parametrize("glove_name", sorted(GLOVES))
def test_in_a_slice_view_the_gpu_touches_the_cross_section_as_the_cpu_model(gpu, glove_name):
    """The slice view that touches its section: a sample whose point of the cut lies in an object
    touches it at l = 0 (touch4d.geometry.section.SectionCaster), cuts across the objects' w extent,
    orthographic and perspective (where the screen point stands for the world point scaled by
    (d + c) / d), and one cut in front of the screen."""
    rng = np.random.default_rng(20261207)

    def section_scene(k):
        scene = random_scene(rng, slice_w=-0.2 if k == 0 else float(rng.uniform(0.6, 2.8)))
        assert scene.touches_section
        return scene

    def pressed(got, cpu, both):   # in a section: l = 0, the same object
        assert np.all(got.l[both] == 0) and np.array_equal(got.hit[both], cpu.hit[both])

    assert_agrees(gpu, load_glove(GLOVES[glove_name]), rng, section_scene, pressed)


def test_a_cut_behind_the_eye_or_beside_every_object_touches_nothing(gpu):
    glove = load_glove(GLOVES["glove"])
    tesseract = {"shape": "tesseract", "size": 1.0, "position": [0, 0, 0, 1.5]}
    for spec in ({"slice_w": 1.5}, {"slice_w": 0.9}, {"slice_w": 2.1},
                 {"slice_w": -3.5, "projection": "perspective", "eye_distance": 3.0}):
        scene = parse_scene({"objects": [tesseract], "view": "slice", **spec})
        gpu.set_scene(scene.to_message())
        st = gpu.stimulus(glove, [0.0, 0.0, 0.0], [0, 0, 0, 1])
        inside = np.abs(st.positions).max(axis=1) < 0.5   # within the tesseract's x, y, z extent
        if spec["slice_w"] == 1.5:   # through the middle of its w extent (1 .. 2): every such sample at l = 0
            assert inside.any() and np.all(st.l[inside] == 0) and not st.touched[~inside].any()
        else:                        # beside its w extent, or behind the eye
            assert not st.touched.any() and st.V.max() == 0

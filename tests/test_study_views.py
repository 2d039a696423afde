"""The view as a study factor: conditions that set the slice view, their gate, the scene a trial
loads, and what a model observer of a slice sees and feels."""
import numpy as np
import pytest

from touch4d.errors import ConfigError
from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.geometry.section import SectionCaster
from touch4d.study.conditions import split_condition
from touch4d.study.design import load_study, parse_study
from touch4d.study.gate import allowed
from touch4d.study.observer import SLICE_OFFSETS, VIEW_GRID, ModelObserver, view_features
from touch4d.study.plan import plan_session
from touch4d.study.simulate import Timing, simulate_trial
from touch4d.study.stimuli import scene_mapping, trial_scene
from touch4d.tactile import load_glove


@pytest.fixture(scope="module")
def views():
    return load_study("config/studies/views.yaml")


def test_condition_names_carry_the_view():
    assert split_condition("visual") == ("visual", "projection")
    assert split_condition("slice-visual+touch") == ("visual+touch", "slice")
    assert split_condition("both-touch") == ("touch", "both")
    for bad in ("slice", "slice-", "side-visual", "slice-visual-touch"):
        with pytest.raises(ValueError, match="condition"):
            split_condition(bad)


def test_a_study_file_refuses_an_unknown_view(views):
    data = {"name": "x", "conditions": ["visual", "slice-sight"], "tasks": [
        {"id": "t", "kind": "tilt", "prompt": "?", "options": ["l", "r"], "scene": "config/scenes/hypercube.yaml",
         "angles_deg": [4]}]}
    with pytest.raises(ConfigError, match=r"conditions\[1\]"):
        parse_study(data, "study.yaml")
    assert views.conditions == ["visual", "visual+touch", "slice-visual", "slice-visual+touch"]


def test_the_gate_follows_the_modality_whatever_the_view():
    for view in ("", "slice-", "both-"):
        assert (allowed(f"{view}visual").objects, allowed(f"{view}visual").motors) == (True, False)
        assert (allowed(f"{view}touch").objects, allowed(f"{view}touch").motors) == (False, True)
        assert (allowed(f"{view}visual+touch").objects, allowed(f"{view}visual+touch").motors) == (True, True)
    assert allowed("slice-sight") == allowed("nonsense") and not allowed("slice-sight").motors


def test_a_slice_trial_loads_its_scene_in_the_slice_view(views):
    trials = plan_session(views, "P01")
    slice_trial = next(t for t in trials if t.condition == "slice-visual+touch")
    plain = next(t for t in trials if t.condition == "visual")
    assert scene_mapping(views, slice_trial)["view"] == "slice" and "view" not in scene_mapping(views, plain)
    scene = trial_scene(views, slice_trial)
    assert scene.view == "slice" and isinstance(scene.ray_caster(), SectionCaster)
    assert trial_scene(views, plain).view == "projection"


def test_a_slice_observer_sees_the_sections_at_the_cs_it_explores():
    obj = SceneObject(name="c", shape="tesseract", size=1.0, position=np.array([0, 0, 0, 1.5]))
    axis = np.linspace(-1, 1, VIEW_GRID)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    inside_cube = (np.abs(points) <= 0.5 + 1e-9).all(axis=1).astype(float)
    n = len(points)
    projection = view_features(Scene(objects=[obj]))
    assert np.array_equal(projection, inside_cube)               # the unit cube's projection
    # slice_w 1.8: the cuts at 1.5, 1.65, 1.8, 1.95 meet the tesseract (w 1 .. 2), the one at 2.1 does not
    seen = view_features(Scene(objects=[obj], view="slice", slice_w=1.8)).reshape(len(SLICE_OFFSETS), n)
    assert [bool(row.any()) for row in seen] == [True, True, True, True, False]
    assert np.array_equal(seen[0], inside_cube)
    both = view_features(Scene(objects=[obj], view="both", slice_w=1.8))
    assert np.array_equal(both, np.concatenate([projection, seen.ravel()]))


def test_a_slice_observer_feels_the_section_and_answers_from_it(views):
    glove = load_glove()
    observer = ModelObserver(glove, views, seed=1, lapse=0.0, train_scenes=4, train_positions=6, view_scenes=8)
    trial = next(t for t in plan_session(views, "P02") if t.condition == "slice-visual+touch" and not t.practice)
    result = simulate_trial(observer, glove, views, trial, seed=0, timing=Timing())
    assert result["response"] in trial.options
    # the touch it was trained on is the section's: contact (l = 0) where the hand is inside it
    scene = trial_scene(views, trial)
    assert isinstance(scene.ray_caster(), SectionCaster)
    assert isinstance(trial_scene(views, next(t for t in plan_session(views, "P02")
                                             if t.condition == "visual+touch")).ray_caster(), RayCaster)

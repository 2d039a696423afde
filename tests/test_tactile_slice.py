"""Touch in the slice view: the glove presses the cross-section at w = c as a solid (slice_touch:
section), or feels the paper's projection unchanged (slice_touch: projection, and the both view)."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import Delaunay

from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.geometry.section import SectionCaster
from touch4d.messages import HandPose
from touch4d.tactile.engine import TactileEngine
from touch4d.tactile.glove import load_glove

from test_geometry_section import independent_section, turn


def scene(view="slice", c=1.5, touch="section", projection="orthographic", objects=None):
    objects = objects or [SceneObject(name="cube", shape="tesseract", size=1.0, position=np.array([0, 0, 0, 1.5]),
                                      orientation=turn(np.random.default_rng(2)))]
    return Scene(objects=objects, view=view, slice_w=c, slice_touch=touch, projection=projection)


def test_the_section_caster_touches_exactly_the_cross_sections():
    rng = np.random.default_rng(4)
    objects = [SceneObject(name=f"o{i}", shape=s, size=0.8, position=np.array([x, 0.1, 0, 1.5]),
                           orientation=turn(rng))
               for i, (s, x) in enumerate([("24-cell", -0.5), ("16-cell", 0.5)])]
    s = scene(objects=objects, c=1.45)
    caster = s.ray_caster()
    assert isinstance(caster, SectionCaster)
    points = rng.uniform(-1, 1, (5000, 3))
    t, hit = caster.cast(points)
    expected = np.full(len(points), -1)
    for i, (_, part) in enumerate(s.world_parts()):
        vertices, _ = independent_section(part.vertices, 1.45)
        expected[Delaunay(vertices).find_simplex(points) >= 0] = i
    assert np.array_equal(hit, expected) and (expected == 0).sum() > 100 and (expected == 1).sum() > 20
    assert np.all(t[hit >= 0] == 0.0) and np.all(np.isnan(t[hit < 0]))


def test_in_perspective_the_touched_section_is_where_it_is_drawn():
    """The slice at w = c is drawn at d / (d + c) of its size: a unit tesseract's section, a cube of half
    width 0.5 d / (d + c) on the screen."""
    s = scene(c=1.5, projection="perspective", objects=[SceneObject(name="c", shape="tesseract",
                                                                      position=np.array([0, 0, 0, 1.5]))])
    half = 0.5 * 3 / 4.5
    _, hit = s.ray_caster().cast([[half - 1e-6, 0, 0], [half + 1e-6, 0, 0], [0, -half + 1e-6, half - 1e-6]])
    assert hit.tolist() == [0, -1, 0]


def test_the_projection_touch_stays_the_papers():
    for s in (scene(touch="projection"), scene(view="both"), scene(view="projection")):
        assert isinstance(s.ray_caster(), RayCaster)


def test_the_glove_feels_the_section_only_inside_it():
    glove = load_glove()
    engine = TactileEngine(glove)
    upright = [SceneObject(name="c", shape="tesseract", size=1.0, position=np.array([0, 0, 0, 1.5]))]
    engine.set_scene(scene(objects=upright).to_message())
    inside = engine.stimulus(HandPose(position=np.array([0.0, 0.0, 0.0]), valid=True))
    outside = engine.stimulus(HandPose(position=np.array([0.0, 0.0, 0.9]), valid=True))
    assert np.all(inside.hit[inside.inside & (np.abs(inside.positions) < 0.5).all(axis=1)] == 0)
    in_cube = (np.abs(inside.positions) < 0.5).all(axis=1)
    assert in_cube.any() and np.all(inside.h[in_cube] == inside.h.max()) and inside.h.max() > 0
    assert np.all(inside.h[~in_cube] == 0)
    far = (np.abs(outside.positions) > 0.5).any(axis=1)
    assert np.all(outside.h[far] == 0)
    # the same hand in the projection view: the paper's distance to the front along w
    engine.set_scene(replace(scene(objects=upright), view="projection").to_message())
    paper = engine.stimulus(HandPose(position=np.array([0.0, 0.0, 0.0]), valid=True))
    assert np.all(inside.l[in_cube] == 0.0) and paper.l[in_cube] == pytest.approx(np.ones(in_cube.sum()))


def test_moving_the_slice_rebuilds_the_touch():
    engine = TactileEngine(load_glove())
    assert engine.set_scene(scene(c=1.5).to_message())
    assert not engine.set_scene(scene(c=1.5).to_message())
    assert engine.set_scene(scene(c=1.6).to_message())


def test_a_cut_behind_the_perspective_eye_is_neither_seen_nor_touched():
    from touch4d.render.view import SceneView

    obj = SceneObject(name="c", shape="tesseract", size=8.0, position=np.array([0, 0, 0, 0.0]))
    s = scene(c=-3.5, projection="perspective", objects=[obj])           # the eye is at w = -3
    assert s.ray_caster().cast(np.zeros((1, 3)))[1].tolist() == [-1]
    view = SceneView()
    view.set_scene(s)
    assert len(view.section) == 0 and not view.frame().solids
    assert view.extent == pytest.approx((-4.0, 4.0))

"""The paper's §6 results (Fig. 17-21) with the catalog shapes and the default glove.

The hand keeps the identity orientation throughout (fingers +y, thumb +x, palm -z), as in the paper.
With alpha = 3 and beta = 0.5 (config/glove.yaml) a flat contact gives h = 0.5 everywhere.
"""
import numpy as np
import pytest

from touch4d.geometry.rotation import rotation_from_list
from touch4d.geometry.scene import Scene, SceneObject
from touch4d.tactile.glove import load_glove
from touch4d.tactile.stimulus import compute_stimulus

IDENTITY = [0.0, 0.0, 0.0, 1.0]
HAND_CENTRED = [-0.14, -0.18, 0.0]   # the hand's origin so that the whole hand is centred on x = y = 0
# Rotations that bring a 2-face, an edge (along y) and a vertex of the tesseract to the front (-w).
FACE = [["xw", 45]]
EDGE = [["xw", 45], ["zw", np.degrees(np.arctan(1 / np.sqrt(2)))]]
VERTEX = [["xw", 45], ["yw", np.degrees(np.arctan(1 / np.sqrt(2)))], ["zw", 30]]


@pytest.fixture(scope="module")
def glove():
    return load_glove()


def caster(shape, size, position, rotation=(), projection="orthographic", eye_distance=3.0):
    obj = SceneObject(name=shape, shape=shape, size=size, position=np.array(position, float),
                      orientation=rotation_from_list(rotation))
    return Scene(objects=[obj], projection=projection, eye_distance=eye_distance).ray_caster()


def stimulus(glove, shape, size, position, rotation=(), hand=HAND_CENTRED, **kwargs):
    return compute_stimulus(glove, caster(shape, size, position, rotation, **kwargs), hand, IDENTITY)


# ---- Fig. 17: a cell facing the viewer -----------------------------------------------------------


def test_fig17_cell_facing_the_viewer_gives_a_uniform_stimulus(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6])
    assert st.touched.all()
    np.testing.assert_allclose(st.l, 1.0)          # the front cell at w = 1.6 - 0.6
    np.testing.assert_allclose(st.h, 0.5)
    np.testing.assert_allclose(st.V, 0.5)


def test_fig17_the_same_magnitude_when_only_part_of_the_hand_touches(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6], hand=[0.4, -0.18, 0.0])
    beyond = st.positions[:, 0] > 0.6                # past the cell's edge: nothing behind
    assert 0 < beyond.sum() < len(beyond) / 2
    np.testing.assert_array_equal(st.touched, ~beyond)
    np.testing.assert_allclose(st.h[~beyond], 0.5)
    np.testing.assert_array_equal(st.h[beyond], 0.0)
    thumb = np.array([n.startswith("thumb") for n in glove.motor_names])
    np.testing.assert_array_equal(st.V[thumb], 0.0)
    np.testing.assert_allclose(st.V[~thumb], 0.5)


# ---- Fig. 18: the cell tilted ---------------------------------------------------------------------


def tilted(glove, degrees):
    """The front cell turned in the xw plane so that its +x side comes nearer; the hand over its middle."""
    middle = -0.6 * np.sin(np.radians(degrees))
    return stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6], [["xw", -degrees]],
                    hand=[middle - 0.14, -0.18, 0.0])


@pytest.mark.parametrize("degrees", [10, 20, 35])
def test_fig18_tilt_gives_the_linear_gradient_of_eq1(glove, degrees):
    st = tilted(glove, degrees)
    assert st.touched.all() and (st.hit == 0).all()
    x = st.positions[:, 0]
    depth = np.tan(np.radians(degrees)) * (x.max() - x)        # l - l_min across the tilted cell
    np.testing.assert_allclose(st.l - st.l.min(), depth, atol=1e-9)
    np.testing.assert_allclose(st.s, np.maximum(1 - glove.alpha * depth, 0), atol=1e-9)


def test_fig18_the_gradient_steepens_until_the_far_side_reaches_zero(glove):
    spans = []
    for degrees in (10, 20, 35):
        st = tilted(glove, degrees)
        x = st.positions[:, 0]
        right, left = st.h[x == x.max()], st.h[x == x.min()]
        assert (right > left.max()).all()                     # stronger on the near (+x) side
        spans.append(right.mean() - left.mean())
        if degrees < 27:
            assert st.s.min() > 0                            # the whole hand still feels the cell
        else:
            assert (st.s[x == x.min()] == 0).all()             # the far side has faded out
            assert (st.s == 0).sum() > 20
    assert spans[0] < spans[1] < spans[2]


# ---- Fig. 19: face, edge, vertex in front ---------------------------------------------------------


def test_fig19_face_in_front_gives_a_wall(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 2.0], FACE)
    assert st.touched.all()
    x = st.positions[:, 0]
    # The face projects to the plane x = 0 and both cells recede from it at 45 degrees.
    np.testing.assert_allclose(st.l - st.l.min(), np.abs(x) - np.abs(x).min(), atol=1e-9)
    for column in np.unique(np.round(x, 9)):                  # uniform over each plane x = const
        values = st.h[np.isclose(x, column)]
        assert np.ptp(values) < 1e-12
    assert st.h[np.argmin(np.abs(x))] == pytest.approx(st.h.max())


def test_fig19_edge_in_front_gives_a_line(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 2.0], EDGE)
    p = st.positions
    off_line = np.hypot(p[:, 0], p[:, 2])                     # the edge projects to the y axis
    for key in np.unique(np.round(p[:, [0, 2]], 9), axis=0):  # the same all along y
        along = np.all(np.isclose(p[:, [0, 2]], key), axis=1)
        assert np.ptp(st.h[along]) < 1e-12
    strongest = st.h >= st.h.max() - 1e-12
    assert len(np.unique(np.round(p[strongest, 1], 9))) >= 6      # a line along y, not a spot
    assert off_line[strongest].max() < 0.1
    assert np.corrcoef(off_line, st.h)[0, 1] < -0.9


def test_fig19_vertex_in_front_gives_a_point_fading_outward(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 2.0], VERTEX)
    r = np.linalg.norm(st.positions, axis=1)                  # the vertex projects to the origin
    strong = st.h >= 0.9 * st.h.max()
    assert r[strong].max() < 0.12 and strong.sum() <= 12
    bands = [st.h[(r >= lo) & (r < lo + 0.1)].mean() for lo in (0.0, 0.1, 0.2, 0.3)]
    assert bands[0] > bands[1] > bands[2] > bands[3] > 0
    assert (st.h[r > 0.4] == 0).all()


def test_fig19_sharper_contacts_are_stronger(glove):
    peaks = [stimulus(glove, "tesseract", 1.2, [0, 0, 0, 2.0], rot).h.max() for rot in (FACE, EDGE, VERTEX)]
    flat = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6]).h.max()
    assert flat == pytest.approx(0.5)
    assert flat < peaks[0] < peaks[1] < peaks[2]


# ---- Fig. 21: three look-alikes -------------------------------------------------------------------


def rings(st):
    r = np.linalg.norm(st.positions, axis=1)
    return [st.h[(r >= lo) & (r < hi)].mean() for lo, hi in ((0, 0.1), (0.1, 0.2), (0.2, 0.3), (0.4, 0.6))]


@pytest.fixture(scope="module")
def lookalikes(glove):
    # Size 1.6: the ball is 0.8 in radius, wider than the hand around its palm centre at the origin.
    return {name: compute_stimulus(glove, caster(name, 1.6, [0, 0, 0, 1.6]), [0, 0, 0], IDENTITY)
            for name in ("cone", "flat-front", "hollow-front")}


def test_fig21_lookalikes_cover_the_same_samples(lookalikes):
    for st in lookalikes.values():
        assert st.touched.all()


def test_fig21_convex_front_is_strong_at_the_centre_fading_outward(lookalikes):
    st = lookalikes["cone"]
    centre, inner, middle, outer = rings(st)
    assert centre > inner > middle and middle == 0 and outer == 0
    assert st.l.argmin() == np.linalg.norm(st.positions, axis=1).argmin()


def test_fig21_flat_front_is_uniform(lookalikes):
    np.testing.assert_allclose(lookalikes["flat-front"].h, 0.5)


def test_fig21_concave_front_is_weak_at_the_centre(lookalikes):
    st = lookalikes["hollow-front"]
    centre, inner, middle, outer = rings(st)
    assert centre == 0 and inner == 0 and outer > 0.5
    assert centre <= inner <= middle < outer


# ---- no contact, and perspective -----------------------------------------------------------------


def test_hand_outside_the_screen_feels_nothing(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6], hand=[0.0, 0.0, 1.3])
    assert not st.inside.any()
    assert np.isnan(st.l).all() and (st.V == 0).all()


def test_hand_beside_the_object_feels_nothing(glove):
    st = stimulus(glove, "tesseract", 0.5, [-0.7, 0, 0, 1.5], hand=[0.4, 0.0, 0.0])
    assert st.inside.all() and not st.touched.any()
    assert (st.h == 0).all() and (st.V == 0).all()


def test_perspective_distance_is_along_the_sight_line(glove):
    st = stimulus(glove, "tesseract", 1.2, [0, 0, 0, 1.6], projection="perspective", eye_distance=3.0)
    assert st.touched.all()
    # The front cell at w = 1: the sight line from (0,0,0,-3) through (p, 0) meets it 1 along w,
    # i.e. at distance sqrt(|p|^2 + 9) / 3 from the screen point (eq. 7).
    expected = np.sqrt((st.positions ** 2).sum(axis=1) + 9.0) / 3.0
    np.testing.assert_allclose(st.l, expected, atol=1e-9)
    assert st.h.argmax() == np.linalg.norm(st.positions, axis=1).argmin()


def test_the_fig18a_scene_is_tilted_to_the_left_and_felt_stronger_on_the_right(glove):
    # "If the cell is tilted slightly to the left, the stimulus becomes greater on the right" (Fig. 18a),
    # with the hand where the README's first picture has it
    from touch4d.geometry.scene import load_scene

    path = "config/scenes/hypercube-tilted.yaml"
    scene = load_scene(path)
    st = compute_stimulus(glove, scene.ray_caster(), [-0.2, 0.0, 0.2], [0, 0, 0, 1.0])
    assert st.touched.all()
    slope = np.polyfit(st.positions[:, 0], st.h, 1)[0]          # stimulus per screen unit toward +x
    assert slope > 0.1
    for text in (open(path).read(), open("README.md").read().split("## ", 1)[0]):   # the file and the picture
        assert "Fig. 18a" in text and "to the left" in text and "greater on the hand's right" in text

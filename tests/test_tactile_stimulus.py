"""The stimulus model (paper eq. 1-3) on small cases worked by hand, and poses placing the samples."""
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

from touch4d.tactile.glove import load_glove
from touch4d.tactile.pose import PoseError, check_pose, place
from touch4d.tactile.stimulus import (adjusted_strength, compute_stimulus, intensity, no_stimulus,
                                      relative_strength)

NAN = np.nan


class PlaneCaster:
    """A stand-in RayCaster: l = a + b . p where |p_x| <= half_width, a miss elsewhere; records calls."""

    def __init__(self, a, b=(0.0, 0.0, 0.0), half_width=np.inf):
        self.a, self.b, self.half_width = a, np.asarray(b, float), half_width
        self.calls = []

    def cast(self, points):
        self.calls.append(np.array(points))
        t = self.a + points @ self.b
        miss = np.abs(points[:, 0]) > self.half_width
        return np.where(miss, np.nan, t), np.where(miss, -1, 0)


@pytest.fixture(scope="module")
def glove():
    return load_glove()


# ---- eq. 1-3 by hand ---------------------------------------------------------------------------


def test_eq1_relative_strength_by_hand():
    l = np.array([1.0, 1.1, 1.5, NAN, 1.25])
    # l_min = 1; alpha = 2: 1 - 2 (l - 1) -> 1, 0.8, max(0, 0) = 0, untouched 0, 0.5
    np.testing.assert_allclose(relative_strength(l, 2.0), [1.0, 0.8, 0.0, 0.0, 0.5])


def test_eq1_nearest_touched_sample_is_one_and_alpha_sets_the_falloff():
    l = np.array([3.0, 2.5, 2.75])
    np.testing.assert_allclose(relative_strength(l, 1.0), [0.5, 1.0, 0.75])
    np.testing.assert_allclose(relative_strength(l, 4.0), [0.0, 1.0, 0.0])


def test_eq1_nothing_touched_gives_zeros():
    np.testing.assert_array_equal(relative_strength(np.full(4, NAN), 3.0), np.zeros(4))
    assert relative_strength(np.array([]), 3.0).shape == (0,)


def test_eq2_adjusted_strength_by_hand():
    s = np.array([1.0, 0.8, 0.0, 0.0])
    # N = 2 active, sum 1.8, beta 0.5: factor 1 - 0.5 * 0.9 = 0.55
    np.testing.assert_allclose(adjusted_strength(s, 0.5), [0.55, 0.44, 0.0, 0.0])


def test_eq2_uniform_contact_is_1_minus_beta_whatever_the_area():
    for count in (1, 7, 200):
        np.testing.assert_allclose(adjusted_strength(np.ones(count), 0.5), 0.5)
        np.testing.assert_allclose(adjusted_strength(np.ones(count), 0.2), 0.8)


def test_eq2_a_sharp_contact_is_stronger_than_a_flat_one():
    point = adjusted_strength(np.array([1.0, 0.1, 0.1, 0.1]), 0.5)
    assert point[0] == pytest.approx((1 - 0.5 * 1.3 / 4) * 1.0)
    assert point[0] > adjusted_strength(np.ones(4), 0.5)[0]


def test_eq2_beta_zero_keeps_s_and_nothing_active_gives_zeros():
    s = np.array([0.3, 1.0, 0.0])
    np.testing.assert_array_equal(adjusted_strength(s, 0.0), s)
    np.testing.assert_array_equal(adjusted_strength(np.zeros(3), 0.5), np.zeros(3))


def test_eq3_intensity_is_gamma_h():
    np.testing.assert_allclose(intensity(np.array([0.55, 0.44, 0.0]), 2.0), [1.1, 0.88, 0.0])


# ---- poses ---------------------------------------------------------------------------------------


def test_place_scales_metres_to_screen_units_rotates_and_translates():
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.25, 0.0]])
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])   # 90 degrees about z
    placed = place(points, 4.0, [0.5, 0.0, -0.5], q)
    np.testing.assert_allclose(placed, [[0.5, 0.0, -0.5], [0.5, 0.4, -0.5], [-0.5, 0.0, -0.5]], atol=1e-12)


@pytest.mark.parametrize("position, orientation, field, words", [
    ([0.0, np.nan, 0.0], [0, 0, 0, 1], "position", "finite"),
    ([0.0, 0.0], [0, 0, 0, 1], "position", "3 numbers"),
    ([0.0, 0.0, 0.0], [0, 0, 0, 0], "orientation", "unit quaternion"),
    ([0.0, 0.0, 0.0], [0, 0, 0, 2], "orientation", "unit quaternion"),
    ([0.0, 0.0, 0.0], [np.nan, 0, 0, 1], "orientation", "finite"),
    ([0.0, 0.0, 0.0], [np.inf, 0, 0, 1], "orientation", "finite"),
    ([0.0, 0.0, 0.0], [0, 0, 1], "orientation", "4 numbers"),
])
def test_bad_poses_are_rejected_naming_the_field(glove, position, orientation, field, words):
    with pytest.raises(PoseError, match=field) as info:
        compute_stimulus(glove, PlaneCaster(1.0), position, orientation)
    assert words in str(info.value)
    assert isinstance(info.value, ValueError)


def test_nearly_unit_quaternion_is_normalised():
    _, q = check_pose([0, 0, 0], [0, 0, 0, 1.0005])
    np.testing.assert_allclose(q, [0, 0, 0, 1.0])


# ---- compute_stimulus with a stand-in caster -----------------------------------------------------


def test_flat_contact_gives_every_sample_and_motor_1_minus_beta(glove):
    st = compute_stimulus(glove, PlaneCaster(0.7), [0.0, 0.0, 0.0], [0, 0, 0, 1])
    assert st.inside.all() and st.touched.all()
    np.testing.assert_allclose(st.l, 0.7)
    np.testing.assert_allclose(st.s, 1.0)
    np.testing.assert_allclose(st.h, 0.5)
    np.testing.assert_allclose(st.V, glove.gamma * 0.5)
    assert st.V.shape == (30,)


def test_sloped_contact_matches_the_equations_sample_by_sample(glove):
    caster = PlaneCaster(1.0, b=(-0.5, 0.0, 0.0))        # deeper toward -x
    st = compute_stimulus(glove, caster, [0.1, 0.0, 0.0], [0, 0, 0, 1], alpha=2.0, beta=0.25)
    x = glove.samples[:, 0] * 4.0 + 0.1
    l = 1.0 - 0.5 * x
    s = np.maximum(2.0 * (l.min() - l) + 1.0, 0.0)
    h = (1 - 0.25 * s.sum() / np.count_nonzero(s)) * s
    np.testing.assert_allclose(st.l, l)
    np.testing.assert_allclose(st.s, s)
    np.testing.assert_allclose(st.h, h)
    np.testing.assert_allclose(st.V, glove.gamma * h[glove.motor_sample])
    assert st.alpha == 2.0 and st.beta == 0.25


def test_samples_outside_the_screen_do_not_take_part(glove):
    # The hand's origin at x = 0.9: the fingers and thumb reach past x = 1.
    st = compute_stimulus(glove, PlaneCaster(0.5, b=(1.0, 0.0, 0.0)), [0.9, 0.0, 0.0], [0, 0, 0, 1])
    outside = st.positions[:, 0] > 1.0
    assert outside.any() and (~outside).any()
    np.testing.assert_array_equal(st.inside, ~outside)
    assert np.isnan(st.l[outside]).all() and (st.s[outside] == 0).all() and (st.h[outside] == 0).all()
    # l_min is over the samples inside the screen only.
    assert st.s[~outside].max() == pytest.approx(1.0)


def test_hand_wholly_outside_the_screen_casts_nothing_and_feels_nothing(glove):
    caster = PlaneCaster(0.5)
    st = compute_stimulus(glove, caster, [3.0, 0.0, 0.0], [0, 0, 0, 1])
    assert caster.calls == []
    assert not st.inside.any()
    assert (st.h == 0).all() and (st.V == 0).all()


def test_samples_whose_ray_misses_do_not_take_part(glove):
    st = compute_stimulus(glove, PlaneCaster(0.5, half_width=0.1), [0.0, 0.0, 0.0], [0, 0, 0, 1])
    miss = np.abs(st.positions[:, 0]) > 0.1
    assert np.isnan(st.l[miss]).all() and (st.hit[miss] == -1).all() and (st.hit[~miss] == 0).all()
    np.testing.assert_allclose(st.h[~miss], 0.5)
    assert (st.h[miss] == 0).all()


def test_orientation_moves_the_samples(glove):
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])   # fingers point to -x
    st = compute_stimulus(glove, PlaneCaster(0.5), [0.0, 0.0, 0.0], q)
    fingertips = glove.samples[:, 1] > 0.12
    assert (st.positions[fingertips, 0] < -0.45).all()


def test_no_stimulus_is_all_zero(glove):
    st = no_stimulus(glove)
    assert st.l.shape == (len(glove.samples),) and np.isnan(st.l).all()
    assert (st.V == 0).all() and (st.h == 0).all() and not st.inside.any()


# s from eq. 1 lies in [0, 1], beta in [0, 1]: the edges, the values next to them, and the rest.
_S = hs.one_of(hs.sampled_from([0.0, 1.0, float(np.nextafter(1.0, 0.0)), 5e-324]), hs.floats(0.0, 1.0))


@settings(max_examples=300, deadline=None)
@given(s=hs.lists(_S, min_size=1, max_size=40), beta=hs.one_of(hs.just(1.0), hs.floats(0.0, 1.0)))
def test_eq2_is_exact_and_never_negative_even_at_beta_one(s, beta):
    """h_i = (1 - beta sum_k s_k / N) s_i over the N samples with s > 0, checked against exact
    rational arithmetic: never negative, and no factor clipped or mis-counted."""
    h = adjusted_strength(np.array(s), beta)
    active = [Fraction(x) for x in s if x > 0]
    factor = 1 - Fraction(beta) * sum(active) / len(active) if active else Fraction(0)
    assert (h >= 0).all()
    np.testing.assert_allclose(h, [float(factor * Fraction(x)) for x in s], rtol=1e-12, atol=1e-15)


def test_eq2_at_beta_one_with_every_sample_at_full_strength_is_zero():
    s = np.array([1.0, 1.0, 1.0, 0.0])       # the mean over the active samples is exactly 1
    assert adjusted_strength(s, 1.0).tolist() == [0.0, 0.0, 0.0, 0.0]

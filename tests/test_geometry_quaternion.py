"""The numpy quaternion helpers: the matrix against Rodrigues' formula (a closed form from axis and
angle), the others against scipy's Rotation (the reference) on random rotations."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from touch4d.geometry import quaternion as qt

RNG = np.random.default_rng(11)
# rotations from angles the seeded generator picks (not scipy's random rotations, whose draws are scipy's)
PAIRS = [tuple(Rotation.from_euler("zyx", RNG.uniform(-180, 180, 3), degrees=True) for _ in range(2))
         for _ in range(50)]


@pytest.mark.parametrize("a, b", PAIRS[:20])
def test_multiply_conjugate_and_matrix_match_scipy(a, b):
    product = qt.multiply(a.as_quat(), b.as_quat())
    assert np.allclose(qt.to_matrix(product), (a * b).as_matrix())
    assert np.allclose(qt.to_matrix(qt.conjugate(a.as_quat())), a.inv().as_matrix())


@pytest.mark.parametrize("a, b", PAIRS[20:])
def test_rotvec_and_slerp_match_scipy(a, b):
    assert np.allclose(qt.to_rotvec(a.as_quat()), a.as_rotvec())
    assert np.allclose(qt.to_rotvec(-a.as_quat()), a.as_rotvec())
    for u in (0.0, 0.3, 1.0):
        expected = Slerp([0, 1], Rotation.concatenate([a, b]))([u]).as_matrix()[0]
        assert np.allclose(qt.to_matrix(qt.slerp(a.as_quat(), b.as_quat(), u)), expected)


def test_small_rotations_stay_exact_and_canonical_picks_w_positive():
    tiny = Rotation.from_rotvec([1e-10, -2e-10, 3e-10])
    assert np.allclose(qt.to_rotvec(tiny.as_quat()), [1e-10, -2e-10, 3e-10], rtol=1e-6, atol=0)
    assert np.allclose(qt.to_rotvec(qt.IDENTITY), 0.0)
    q = qt.canonical([0.0, 0.0, -0.6, -0.8])
    assert np.allclose(q, [0.0, 0.0, 0.6, 0.8])
    close = Rotation.from_rotvec([0, 0, 1e-3])
    assert np.allclose(qt.to_matrix(qt.slerp(qt.IDENTITY, close.as_quat(), 0.5)),
                       Rotation.from_rotvec([0, 0, 5e-4]).as_matrix())


@pytest.mark.parametrize("a, scale", [(a, k) for (a, _), k in zip(PAIRS[:10], (0.5, -2.0, 3.0, -0.1, 1.0) * 2)])
def test_canonical_is_scipys_unit_quaternion_with_w_positive(a, scale):
    expected = a.as_quat()
    expected = -expected if expected[3] < 0 else expected
    got = qt.canonical(scale * a.as_quat())
    assert np.allclose(got, expected, rtol=0, atol=1e-15) and got[3] >= 0
    assert np.allclose(qt.canonical(tuple(-got)), expected, rtol=0, atol=1e-15)   # a sequence too


def test_canonical_of_a_zero_or_nan_quaternion_is_nan():
    with np.errstate(invalid="ignore", divide="ignore"):
        assert np.isnan(qt.canonical([0.0, 0.0, 0.0, 0.0])).all()
        assert np.isnan(qt.canonical([np.nan, 0.0, 0.0, 1.0])).all()


def rodrigues(axis, angle: float) -> np.ndarray:
    """The rotation by `angle` about the unit `axis`: cos I + sin [k]x + (1 - cos) k k^T."""
    k = np.asarray(axis, dtype=float)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.cos(angle) * np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * np.outer(k, k)


def axis_angle_quaternion(axis, angle: float) -> np.ndarray:
    return np.r_[np.sin(angle / 2) * np.asarray(axis, dtype=float), np.cos(angle / 2)]


AXES_ANGLES = [(np.array(a) / np.linalg.norm(a), t) for a, t in
               [((1, 0, 0), 0.3), ((0, 1, 0), -1.2), ((0, 0, 1), np.pi / 2), ((1, 2, -2), 2.9), ((-3, 1, 5), np.pi),
                ((0.2, -0.7, 0.1), 1e-7)]]


def test_to_matrix_is_rodrigues_for_one_quaternion_and_for_stacks():
    for axis, angle in AXES_ANGLES:
        assert np.allclose(qt.to_matrix(axis_angle_quaternion(axis, angle)), rodrigues(axis, angle), atol=1e-14)
        assert np.allclose(qt.to_matrix(-axis_angle_quaternion(axis, angle)), rodrigues(axis, angle), atol=1e-14)
    stack = np.array([axis_angle_quaternion(a, t) for a, t in AXES_ANGLES])
    expected = np.array([rodrigues(a, t) for a, t in AXES_ANGLES])
    assert qt.to_matrix(stack).shape == (len(AXES_ANGLES), 3, 3)
    assert np.allclose(qt.to_matrix(stack), expected, atol=1e-14)
    grid = np.stack([stack, stack[::-1]])            # any leading shape
    assert np.allclose(qt.to_matrix(grid), np.stack([expected, expected[::-1]]), atol=1e-14)


def test_to_matrix_turns_x_to_y_at_90_degrees_about_z_and_scales_by_the_squared_norm():
    q = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    assert np.allclose(qt.to_matrix(q) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    assert np.array_equal(qt.to_matrix([0, 0, 0, 1]), np.eye(3))
    assert np.allclose(qt.to_matrix(2.0 * q), 4.0 * rodrigues([0, 0, 1], np.pi / 2), atol=1e-14)


@pytest.mark.parametrize("a, b", PAIRS[:10])
def test_the_float_forms_match_scipy(a, b):
    # product, unit and rotate: the per-pose path's Python-float forms of multiply, canonical and to_matrix @ v
    got = qt.product(a.as_quat().tolist(), b.as_quat().tolist())
    assert isinstance(got, tuple) and all(type(v) is float for v in got)
    assert np.allclose(Rotation.from_quat(got).as_matrix(), (a * b).as_matrix(), rtol=0, atol=1e-14)
    expected = a.as_quat() if a.as_quat()[3] >= 0 else -a.as_quat()
    assert np.allclose(qt.unit((-3.0 * a.as_quat()).tolist()), expected, rtol=0, atol=1e-15)
    v = RNG.uniform(-2, 2, 3)
    assert np.allclose(qt.rotate(a.as_quat().tolist(), v.tolist()), a.apply(v), rtol=0, atol=1e-14)


def test_unit_of_a_zero_or_nan_quaternion_is_nan():
    assert np.isnan(qt.unit((0.0, 0.0, 0.0, 0.0))).all() and np.isnan(qt.unit((np.nan, 0.0, 0.0, 1.0))).all()

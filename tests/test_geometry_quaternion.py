"""The numpy quaternion helpers agree with scipy's Rotation (the reference) on random rotations."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from touch4d.geometry import quaternion as qt

RNG = np.random.default_rng(11)
PAIRS = [(Rotation.random(random_state=RNG), Rotation.random(random_state=RNG)) for _ in range(50)]


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

"""Rotations, poses, the controller mapping and projection."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.geometry.projection import perspective_halfspaces, perspective_points, project
from touch4d.geometry.rotation import (Pose, controller_rotation, is_rotation, orthonormalize, plane_rotation,
                                       rotation_from_list)


def test_plane_rotation_sign_convention():
    r = plane_rotation("xw", np.radians(90))
    # x_a' = cos x_a - sin x_b, x_b' = sin x_a + cos x_b with (a, b) = (x, w).
    assert np.allclose(r @ [1, 0, 0, 0], [0, 0, 0, 1])
    assert np.allclose(r @ [0, 0, 0, 1], [-1, 0, 0, 0])
    theta = 0.3
    p = np.array([0.2, -0.4, 0.7, 1.1])
    q = plane_rotation("yz", theta) @ p
    assert np.allclose(q, [0.2, np.cos(theta) * -0.4 - np.sin(theta) * 0.7, np.sin(theta) * -0.4 + np.cos(theta) * 0.7, 1.1])
    assert np.allclose(plane_rotation("zx", theta), plane_rotation("xz", -theta))


def test_rotation_list_applies_in_order():
    r = rotation_from_list([["xw", 30], ["yz", 10]])
    assert np.allclose(r, plane_rotation("yz", np.radians(10)) @ plane_rotation("xw", np.radians(30)))


@pytest.mark.parametrize("plane", ["xx", "xq", "x", 3])
def test_bad_plane_names(plane):
    with pytest.raises(ValueError, match="rotation plane"):
        plane_rotation(plane, 0.1)


def test_a_million_compositions_stay_orthogonal_with_det_one():
    rng = np.random.default_rng(7)
    g = rng.normal(scale=0.5, size=(1000, 4, 4))
    pool = orthonormalize(np.eye(4) + g - np.swapaxes(g, 1, 2))      # 1000 random rotations
    chains, steps = 100, 10_000
    r = np.broadcast_to(np.eye(4), (chains, 4, 4)).copy()
    picks = rng.integers(0, len(pool), size=(steps, chains))
    for step in range(steps):
        r = pool[picks[step]] @ r
        if step % 100 == 99:
            r = orthonormalize(r)
    r = orthonormalize(r)
    # Unrepaired, these chains drift to ~4e-13 (det off by ~8e-13); repaired they stay at rounding.
    assert np.abs(r @ np.swapaxes(r, 1, 2) - np.eye(4)).max() < 1e-14
    assert np.abs(np.linalg.det(r) - 1).max() < 1e-14


def test_orthonormalize_repairs_drift_and_keeps_handedness():
    rng = np.random.default_rng(3)
    r = rotation_from_list([["xw", 40], ["yz", 20]])
    noisy = r + 1e-4 * rng.normal(size=(4, 4))
    fixed = orthonormalize(noisy)
    assert is_rotation(fixed, 1e-12) and np.abs(fixed - r).max() < 1e-3
    assert not is_rotation(noisy, 1e-9)


def test_controller_translation_turns_planes_with_w():
    for axis, plane in enumerate(["xw", "yw", "zw"]):
        d = np.zeros(3)
        d[axis] = 0.1
        assert np.allclose(controller_rotation(d, np.zeros(3), gains=(2.0, 1.0)), plane_rotation(plane, 0.2))


def test_controller_rotation_turns_xyz_like_the_controller():
    rotvec = np.array([0.2, -0.1, 0.3])
    r = controller_rotation(np.zeros(3), rotvec, gains=(1.0, 0.5))
    assert np.allclose(r[:3, :3], Rotation.from_rotvec(0.5 * rotvec).as_matrix())
    assert np.allclose(r[3], [0, 0, 0, 1]) and np.allclose(r[:, 3], [0, 0, 0, 1])
    assert np.allclose(controller_rotation(np.zeros(3), [0.1, 0, 0], 1.0), plane_rotation("yz", 0.1))
    assert is_rotation(controller_rotation([0.3, -0.2, 0.1], rotvec, (1.5, 1.0)))


def test_pose_compose_and_inverse():
    a = Pose([0, 0, 0, 2], rotation_from_list([["xw", 30]]))
    b = Pose([0.1, 0.2, 0, 0], rotation_from_list([["yz", 50]]))
    p = np.array([[0.3, -0.1, 0.2, 0.4]])
    assert np.allclose(a.compose(b).apply(p), a.apply(b.apply(p)))
    assert np.allclose(a.inverse().apply(a.apply(p)), p)
    spun = a.rotated(plane_rotation("zw", 0.4))
    assert np.allclose(spun.position, a.position) and is_rotation(spun.orientation)


def test_projection_orthographic_and_perspective():
    p = np.array([[0.3, -0.6, 0.9, 1.0], [0.5, 0.5, 0.5, 0.0]])
    assert np.allclose(project(p), p[:, :3])
    persp = project(p, "perspective", eye_distance=3.0)
    assert np.allclose(persp[0], p[0, :3] * 3 / 4)
    assert np.allclose(persp[1], p[1, :3])                    # points on the screen stay put
    # Collinear with the eye: the projection is the point where the sight line meets w = 0.
    eye = np.array([0, 0, 0, -3.0])
    assert np.allclose(np.r_[persp[0], 0] - eye, (p[0] - eye) * 3 / 4)
    with pytest.raises(ValueError, match="eye_distance"):
        project(p, "perspective")
    with pytest.raises(ValueError, match="projection"):
        project(p, "fisheye")


def test_perspective_map_keeps_half_spaces_and_sight_lines():
    rng = np.random.default_rng(5)
    n = rng.normal(size=(20, 4))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = rng.uniform(-1, 1, 20)
    x = np.c_[rng.uniform(-1, 1, (500, 3)), rng.uniform(-1, 4, 500)]
    m, k = perspective_halfspaces(n, c, 2.5)
    u = perspective_points(x, 2.5)
    assert np.array_equal(x @ n.T <= c, u @ m.T <= k)
    # Points on one sight line map to one line parallel to w, in the same order.
    line = np.array([0, 0, 0, -2.5]) + np.outer([0.5, 1, 2, 3], [0.4, -0.2, 0.1, 2.5])
    mapped = perspective_points(line, 2.5)
    assert np.allclose(mapped[:, :3], mapped[0, :3]) and np.all(np.diff(mapped[:, 3]) > 0)


def test_renormalize_repairs_small_drift_like_orthonormalize_and_falls_back_when_far():
    from touch4d.geometry.rotation import renormalize
    rng = np.random.default_rng(9)
    r = rotation_from_list([["xw", 40], ["yz", 20], ["zw", -70]])
    drifted = r + 1e-8 * rng.normal(size=(4, 4))
    fixed = renormalize(drifted)
    assert is_rotation(fixed, 1e-14) and np.abs(fixed - orthonormalize(drifted)).max() < 1e-14
    far = r + 0.05 * rng.normal(size=(4, 4))
    assert np.allclose(renormalize(far), orthonormalize(far), atol=1e-12)
    assert is_rotation(renormalize(np.diag([1.0, 1, 1, -1]) @ far))           # handedness kept +1

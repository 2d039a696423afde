"""Ray casting along +w (eq. 4-7): known values, grazing and parallel cases, and a brute-force reference."""
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.rotation import PLANES, plane_rotation
from touch4d.geometry.shapes import get_shape


def tesseract(position, size=1.0, orientation=None):
    return get_shape("tesseract").parts[0].transformed(orientation, position, size)


def test_front_cell_of_a_tesseract_is_felt_at_its_distance():
    caster = RayCaster([(0, tesseract([0, 0, 0, 1.5]))])
    t, hit = caster.cast([[0, 0, 0], [0.4, -0.3, 0.2], [0.6, 0, 0], [0, 0, -0.51]])
    assert np.allclose(t[:2], 1.0) and np.isnan(t[2:]).all()
    assert hit.tolist() == [0, 0, -1, -1]
    assert t.dtype == np.float64 and hit.shape == (4,)


def test_grazing_an_edge_and_running_along_a_parallel_cell():
    caster = RayCaster([(0, tesseract([0, 0, 0, 1.5]))])
    t, hit = caster.cast([[0.5, 0, 0], [0.5, 0.5, 0], [0.5, 0.5, 0.5], [0.5 + 1e-6, 0, 0]])
    assert np.allclose(t[:3], 1.0) and hit[3] == -1
    # Turned 45 degrees in xw: its extreme in x is a ridge at x = 1/sqrt2, met by the ray at w = 1.5.
    turned = tesseract([0, 0, 0, 1.5], orientation=plane_rotation("xw", np.pi / 4))
    caster = RayCaster([(0, turned)])
    edge = 1 / np.sqrt(2)
    t, hit = caster.cast([[edge, 0, 0], [edge + 1e-6, 0, 0], [0, 0, 0]])
    assert t[0] == pytest.approx(1.5) and hit[1] == -1
    assert t[2] == pytest.approx(1.5 - edge)                  # the front ridge at x = 0 is a vertex-edge


def test_inside_an_object_is_zero_and_behind_the_screen_is_nothing():
    caster = RayCaster([(0, tesseract([0, 0, 0, 0.2])), (1, tesseract([3, 0, 0, -2]))])
    t, hit = caster.cast([[0, 0, 0], [3, 0, 0]])
    assert t[0] == 0 and hit[0] == 0
    assert np.isnan(t[1]) and hit[1] == -1


def test_nearest_of_several_objects_and_unions():
    parts = [(0, tesseract([0, 0, 0, 3.0])), (1, tesseract([0.3, 0, 0, 1.5], 0.5))]
    parts += [(2, p.transformed(None, [-0.6, 0, 0, 1.0], 0.6)) for p in get_shape("hollow-front").parts]
    t, hit = RayCaster(parts).cast([[0, 0, 0], [0.3, 0, 0], [-0.6, 0, 0], [-0.6 + 0.29, 0, 0]])
    assert hit.tolist() == [0, 1, 2, 2]
    assert t[0] == pytest.approx(2.5) and t[1] == pytest.approx(1.25)
    # The hollow front: deepest (w = 1/4 of the local shape) at the centre, shallower toward the rim.
    assert t[2] == pytest.approx(1.0 + 0.6 * 0.25)
    assert t[3] < t[2]


def test_look_alikes_share_the_silhouette_and_differ_in_depth():
    points = np.c_[np.linspace(-0.6, 0.6, 49), np.zeros(49), np.zeros(49)]
    depth = {}
    for name in ("cone", "flat-front", "hollow-front"):
        parts = [(0, p.transformed(None, [0, 0, 0, 1.5])) for p in get_shape(name).parts]
        depth[name] = RayCaster(parts).cast(points)[0]
    hits = [~np.isnan(t) for t in depth.values()]
    assert np.array_equal(hits[0], hits[1]) and np.array_equal(hits[1], hits[2]) and 0 < hits[0].sum() < 49
    centre, off = 24, 30                                       # x = 0 and x = 0.15
    assert depth["cone"][centre] == pytest.approx(1.0) and depth["cone"][off] > 1.0
    assert np.allclose(depth["flat-front"][hits[0]], 1.0)
    assert depth["hollow-front"][centre] == pytest.approx(1.75) and depth["hollow-front"][off] < 1.75


def test_perspective_distance_is_measured_along_the_sight_line():
    d = 3.0
    caster = RayCaster([(0, tesseract([0, 0, 0, 1.5]))], eye_distance=d)
    p = np.array([[0, 0, 0], [0.3, 0.1, -0.2], [0.4, 0, 0]])
    t, hit = caster.cast(p)
    # The front cell w = 1: the sight line from (0,0,0,-d) through (p, 0) meets it after w / d of |(p, d)|.
    expected = np.sqrt((p ** 2).sum(axis=1) + d * d) / d
    assert np.allclose(t[:2], expected[:2])
    # (0.4, 0, 0) diverges: at w = 1 it is at x = 0.533, beyond the tesseract.
    assert hit.tolist() == [0, 0, -1] and np.isnan(t[2])
    # Off axis the eye sees the inner side cell x = 0.7 of a tesseract at x = 1.2: entered at w = 1.2.
    t, hit = RayCaster([(0, tesseract([1.2, 0, 0, 1.5]))], eye_distance=d).cast([[0.5, 0, 0]])
    assert hit[0] == 0 and t[0] == pytest.approx(np.sqrt(0.25 + d * d) * 1.2 / d)


def test_no_objects_no_points():
    t, hit = RayCaster([]).cast(np.zeros((5, 3)))
    assert np.isnan(t).all() and (hit == -1).all()
    enter, leave = RayCaster([]).intervals(np.zeros((5, 3)))
    assert enter.shape == leave.shape == (5, 0)
    t, hit = RayCaster([(0, tesseract([0, 0, 0, 1]))]).cast(np.zeros((0, 3)))
    assert t.shape == hit.shape == (0,)


# ---- property: equal to a brute-force reference --------------------------------------------------

SHAPES = [("tesseract", {}), ("5-cell", {}), ("16-cell", {}), ("24-cell", {}), ("pyramid", {}),
          ("hollow-front", {"subdivisions": 0})]
STEP = 2.5e-3
T_MAX = 3.5

objects = st.tuples(
    st.sampled_from(range(len(SHAPES))),
    st.floats(0.5, 1.2),
    st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.3, 2.5)),
    st.lists(st.floats(-np.pi, np.pi), min_size=6, max_size=6),
)


def build(scene):
    parts = []
    for index, (shape, size, position, angles) in enumerate(scene):
        r = np.eye(4)
        for plane, a in zip(PLANES, angles):
            r = plane_rotation(plane, a) @ r
        name, params = SHAPES[shape]
        parts += [(index, p.transformed(r, position, size)) for p in get_shape(name, **params).parts]
    return parts


def brute_force(parts, points, eye_distance):
    """First sample inside any part along each ray, stepping STEP; the object hit or -1."""
    ts = np.arange(0, T_MAX, STEP)
    if eye_distance is None:
        direction = np.tile([0, 0, 0, 1.0], (len(points), 1))
    else:
        direction = np.c_[points, np.full(len(points), eye_distance)]
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    start = np.c_[points, np.zeros(len(points))]
    samples = start[:, None, :] + ts[None, :, None] * direction[:, None, :]     # (N, T, 4)
    first = np.full(len(points), np.inf)
    who = np.full(len(points), -1)
    for index, poly in parts:
        inside = poly.contains(samples.reshape(-1, 4), tol=0).reshape(len(points), len(ts))
        k = np.where(inside.any(axis=1), inside.argmax(axis=1), len(ts))
        t = np.where(k < len(ts), ts[np.minimum(k, len(ts) - 1)], np.inf)
        better = t < first
        first, who = np.where(better, t, first), np.where(better, index, who)
    return first, who, start, direction


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=st.lists(objects, min_size=1, max_size=3), seed=st.integers(0, 2**31 - 1),
       perspective=st.booleans())
# a ray through a chord of the second object shorter than the reference's step (0.0025 screen units), which it skips
@example(scene=[(0, 1.0, (0.0, 0.0, 0.0, 1.0), [0.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
                (5, 0.84375, (0.296875, 0.0, -0.1171875, 1.0), [0.0, 0.625, 0.0, 3.140625, 0.625, 0.0])],
         seed=0, perspective=False)
def test_ray_casting_equals_brute_force(scene, seed, perspective):
    eye = 3.0 if perspective else None
    parts = build(scene)
    points = np.random.default_rng(seed).uniform(-0.6, 0.6, (40, 3))
    t, hit = RayCaster(parts, eye_distance=eye).cast(points)
    ref_t, ref_hit, start, direction = brute_force(parts, points, eye)
    seen = np.isfinite(ref_t)
    # Every hit reported is a point of the object it names (also thin chords the sampling skips).
    for i in np.nonzero(hit >= 0)[0]:
        q = start[i] + t[i] * direction[i]
        assert any(p.contains(q[None], tol=1e-7)[0] for k, p in parts if k == hit[i])
    # Where the reference finds an object, the caster finds one no later, and at most a step earlier
    # unless it entered a chord thinner than the reference's step (its point checked just above).
    assert np.all(np.isfinite(t[seen]))
    assert np.all(t[seen] <= ref_t[seen] + 1e-9)
    early = seen & (t < ref_t - STEP - 1e-9)
    for i in np.nonzero(early)[0]:
        inside = np.zeros(int(STEP / 1e-5))
        samples = start[i] + (t[i] + 1e-5 * np.arange(1, len(inside) + 1))[:, None] * direction[i]
        inside = np.any([p.contains(samples, tol=0) for k, p in parts if k == hit[i]], axis=0)
        assert inside.any() and not inside.all(), (i, t[i], ref_t[i])   # in, and out again within a step
    # Same object where the entry is not a near-tie between objects.
    clear = seen & (ref_hit == hit)
    assert clear.sum() >= 0.9 * seen.sum() - 1
    assert np.all(np.isnan(t[hit < 0]))

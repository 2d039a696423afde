"""Scripted hand paths: pure functions of time, the named paths of config/paths.yaml, bad entries."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.errors import ConfigError
from touch4d.tracking.paths import (Keyframe, Orbit, Waypoints, load_path, load_paths, looped,
                                    path_from_config, press, sweep)

NAMES = {"face-sweep", "edge-press", "vertex-press", "orbit", "grab-orbit", "hold", "demo"}


def test_every_named_path_loads_and_is_a_function_of_time():
    paths = load_paths()
    assert NAMES <= set(paths)
    again = load_paths()
    for name, path in paths.items():
        for t in np.linspace(0, path.duration, 37):
            a, b = path.sample(t), again[name].sample(t)
            assert np.array_equal(a.position, b.position) and np.array_equal(a.orientation, b.orientation)
            assert np.linalg.norm(a.orientation) == pytest.approx(1.0)


def test_sweep_goes_across_and_back_without_jumps():
    path = sweep([-0.8, 0, 0], [0.8, 0, 0], 6.0)
    assert np.allclose(path.sample(0).position, [-0.8, 0, 0])
    assert np.allclose(path.sample(3).position, [0.8, 0, 0])
    assert np.allclose(path.sample(6).position, [-0.8, 0, 0])
    xs = np.array([path.sample(t).position[0] for t in np.linspace(0, 6, 601)])
    assert np.abs(np.diff(xs)).max() < 0.01           # smooth: at most 1.6 units / 300 steps * 1.5
    assert np.all(np.diff(xs[:301]) >= 0) and np.all(np.diff(xs[300:]) <= 0)


def test_press_reaches_the_target_and_dwells():
    path = press([0.1, 0.2, 0.0], [0, 0, 1], 1.3, move_s=2.0, dwell_s=1.0)
    assert np.allclose(path.sample(0).position, [0.1, 0.2, 1.3])
    for t in (2.0, 2.5, 3.0):
        assert np.allclose(path.sample(t).position, [0.1, 0.2, 0.0])
    assert np.allclose(path.sample(5.0).position, [0.1, 0.2, 1.3])
    assert path.duration == 5.0


def test_demo_starts_outside_the_screen_enters_it_and_leaves():
    demo = load_path("demo")
    outside = lambda t: np.abs(demo.sample(t).position).max() > 1.5   # hand half-size < 0.5 units
    assert outside(0.0) and outside(demo.duration - 0.01)
    assert np.allclose(demo.sample(4.0).position, [0, 0, 0])
    assert not outside(4.0)


def test_orbit_circles_its_centre_and_carries_the_trigger():
    orbit = Orbit([0.1, 0, 0], 0.5, 4.0, "xz", trigger=1.0)
    for t in np.linspace(0, 4, 17):
        s = orbit.sample(t)
        assert np.hypot(s.position[0] - 0.1, s.position[2]) == pytest.approx(0.5)
        assert s.position[1] == 0 and s.trigger == 1.0
    assert np.allclose(orbit.sample(1.0).position, [0.1, 0, 0.5])
    assert load_path("grab-orbit").sample(0.3).trigger == 1.0


def test_waypoints_slerp_orientation_and_step_trigger_and_buttons():
    q1 = Rotation.from_euler("z", 90, degrees=True).as_quat()
    path = Waypoints([
        Keyframe(0.0, np.zeros(3), np.array([0, 0, 0, 1.0]), 0.0, ()),
        Keyframe(2.0, np.ones(3), q1, 1.0, ("menu",)),
        Keyframe(3.0, np.ones(3), q1, 0.0, ()),
    ])
    mid = path.sample(1.0)
    assert np.allclose(mid.position, 0.5)
    assert Rotation.from_quat(mid.orientation).magnitude() == pytest.approx(np.radians(45))
    assert mid.trigger == 0.0 and mid.buttons == ()
    assert path.sample(2.5).trigger == 1.0 and path.sample(2.5).buttons == ("menu",)
    assert path.sample(10.0).trigger == 0.0


def test_looped_wraps_at_the_end():
    path = sweep([0, 0, 0], [1, 0, 0], 2.0)
    assert np.allclose(looped(path, 2.5).position, path.sample(0.5).position)


@pytest.mark.parametrize("spec, key", [
    ({"kind": "spiral"}, "paths.p.kind"),
    ({"kind": "sweep", "start": [0, 0], "end": [1, 0, 0], "duration_s": 1}, "paths.p.start"),
    ({"kind": "orbit", "radius": 0.5, "period_s": 0}, "paths.p.period_s"),
    ({"kind": "hold", "position": [0, 0, 0], "trigger": 2}, "paths.p.trigger"),
    ({"kind": "waypoints", "keyframes": [{"t": 0, "position": [0, 0, 0]}, {"t": 0, "position": [1, 0, 0]}]},
     "paths.p"),
    ({"kind": "waypoints", "keyframes": [{"t": 0, "position": [0, 0, 0], "buttons": "menu"}]},
     "paths.p.keyframes[0].buttons"),
])
def test_bad_entries_name_the_key(spec, key):
    with pytest.raises(ConfigError) as err:
        path_from_config(spec, "paths.yaml", "paths.p.")
    assert err.value.key == key


def test_unknown_name_lists_what_exists():
    with pytest.raises(ConfigError, match="face-sweep"):
        load_path("no-such-path")

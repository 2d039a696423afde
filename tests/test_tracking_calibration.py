"""Room <-> screen calibration: units, axes, the hand held on the controller, bad files."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.errors import ConfigError
from touch4d.tracking.calibration import Calibration, load_calibration, rotation_from_steps


def make(center=(0.0, 1.2, -0.45), steps=(), edge=0.5, offset=(0.0, 0.0, 0.0), hand_steps=()):
    return Calibration(np.array(center, float), rotation_from_steps([list(s) for s in steps]), edge,
                       np.array(offset, float), rotation_from_steps([list(s) for s in hand_steps]))


def test_screen_centre_and_corners_map_to_screen_units():
    cal = make()
    assert np.allclose(cal.room_to_screen([0.0, 1.2, -0.45]), 0.0)
    # half an edge (0.25 m) from the centre is the screen's face at 1 unit
    assert np.allclose(cal.room_to_screen([0.25, 1.2 + 0.25, -0.45 - 0.25]), [1.0, 1.0, -1.0])
    assert cal.units_per_metre == pytest.approx(4.0)


def test_turned_screen_turns_axes_and_directions():
    cal = make(center=(0, 0, 0), steps=[("y", 90)])
    # the screen's +x axis points along the room's -z after a 90 degree turn about y
    assert np.allclose(cal.screen_to_room([1.0, 0, 0]), [0, 0, -0.25], atol=1e-12)
    assert np.allclose(cal.direction_to_screen([0, 0, -0.1]), [0.1, 0, 0], atol=1e-12)  # metres kept
    q_room = Rotation.from_euler("y", 90, degrees=True).as_quat()
    assert np.allclose(Rotation.from_quat(cal.orientation_to_screen(q_room)).as_matrix(), np.eye(3), atol=1e-12)


def test_points_round_trip_for_any_calibration():
    rng = np.random.default_rng(3)
    cal = make(center=(0.3, 1.0, -0.2), steps=[("x", 20), ("z", -35)], edge=0.8)
    pts = rng.uniform(-2, 2, (50, 3))
    assert np.allclose(cal.room_to_screen(cal.screen_to_room(pts)), pts)


def test_hand_offset_follows_the_controller():
    cal = make(center=(0, 0, 0), offset=(0.0, 0.0, 0.1), hand_steps=[("x", -90)])
    # controller at the screen centre, turned 90 degrees about y: the hand 0.1 m along its +z lies
    # along room +x, i.e. 0.4 screen units to the right
    q = Rotation.from_euler("y", 90, degrees=True).as_quat()
    pos, quat = cal.hand_from_controller([0, 0, 0], q)
    assert np.allclose(pos, [0.4, 0, 0], atol=1e-12)
    expected = Rotation.from_euler("y", 90, degrees=True) * Rotation.from_euler("x", -90, degrees=True)
    assert np.allclose(Rotation.from_quat(quat).as_matrix(), expected.as_matrix(), atol=1e-12)
    assert quat[3] >= 0


def test_controller_from_hand_inverts_hand_from_controller():
    cal = load_calibration()
    rng = np.random.default_rng(5)
    for _ in range(20):
        pos = rng.uniform(-1, 1, 3)
        quat = Rotation.from_euler("zyx", rng.uniform(-180, 180, 3), degrees=True).as_quat()
        c_pos, c_quat = cal.controller_from_hand(pos, quat)
        back_pos, back_quat = cal.hand_from_controller(c_pos, c_quat)
        assert np.allclose(back_pos, pos)
        assert np.allclose(Rotation.from_quat(back_quat).as_matrix(), Rotation.from_quat(quat).as_matrix())


def test_default_file_loads_with_the_glove_screen_size():
    import yaml

    from touch4d.tracking.config import CONFIG_DIR

    cal = load_calibration()
    glove = yaml.safe_load((CONFIG_DIR / "glove.yaml").read_text())
    assert cal.edge_m == glove["screen_edge_m"]


@pytest.mark.parametrize("text, key", [
    ("screen: {center_m: [0, 1], edge_m: 0.5}", "screen.center_m"),
    ("screen: {center_m: [0, 1, 0], edge_m: -1}", "screen.edge_m"),
    ("screen: {center_m: [0, 1, 0], edge_m: 0.5, rotation_deg: [[q, 10]]}", "screen.rotation_deg[0][0]"),
    ("hand_in_controller: {}", "screen"),
    ("screen: [1, 2]", "screen"),
])
def test_bad_files_name_the_key(tmp_path, text, key):
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_calibration(path)
    assert err.value.key == key and str(path) in str(err.value)


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="existing calibration file.*looked in"):
        load_calibration(tmp_path / "nope.yaml")


@pytest.mark.parametrize("value", [0.0, -90.0, float("nan"), float("inf"), 1500.0, True, "90"])
def test_node_rates_must_be_finite_and_in_range(value):
    from touch4d.bus.params import Param
    from touch4d.tracking.config import MAX_TRACKER_RATE
    rate = Param(90.0, "poses per second", unit="Hz", above=0, max=MAX_TRACKER_RATE)
    with pytest.raises(ValueError) as err:
        rate.check(value)
    assert str(err.value) == "a finite number > 0 and <= 1000 (Hz)" and err.value.got is value
    assert rate.check(1000) == 1000.0 and isinstance(rate.check(1000), float)


def test_hand_from_controller_is_scipys_composition_for_any_calibration():
    # independent: scipy's Rotation composes the frames, numpy maps the point
    rng = np.random.default_rng(8)
    cal = make(center=(0.3, 1.1, -0.4), steps=[("y", 35), ("x", -10)], edge=0.6, offset=(0.02, -0.03, 0.1),
               hand_steps=[("x", -90), ("z", 20)])
    for _ in range(20):
        position = rng.uniform(-1, 2, 3)
        controller = Rotation.from_euler("zyx", rng.uniform(-180, 180, 3), degrees=True)
        pos, quat = cal.hand_from_controller(position, controller.as_quat() * rng.choice([-1.0, 1.0]))
        hand_room = position + controller.apply([0.02, -0.03, 0.1])
        expected_pos = cal.screen_rotation.inv().apply(hand_room - cal.center_m) * (2.0 / 0.6)
        expected = cal.screen_rotation.inv() * controller * cal.hand_rotation
        assert isinstance(pos, np.ndarray) and pos.shape == (3,) and quat.shape == (4,)
        np.testing.assert_allclose(pos, expected_pos, rtol=0, atol=1e-12)
        np.testing.assert_allclose(Rotation.from_quat(quat).as_matrix(), expected.as_matrix(), rtol=0, atol=1e-12)
        assert quat[3] >= 0 and abs(np.linalg.norm(quat) - 1.0) < 1e-15

"""The scene node's pure logic: controller motion -> 4D rotation planes (§4.4), commands, drift."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.errors import ConfigError
from touch4d.geometry.rotation import controller_rotation, is_rotation
from touch4d.geometry.scene import load_scene
from touch4d.tracking.calibration import Calibration, load_calibration, rotation_from_steps
from touch4d.tracking.config import CONFIG_DIR
from touch4d.tracking.scene_control import ControlConfig, SceneControl

SCENES = CONFIG_DIR / "scenes"
I4 = np.eye(4)
AXIS = {"x": 0, "y": 1, "z": 2, "w": 3}


def control(scene="hypercube.yaml", cal=None, **config):
    return SceneControl(load_scene(SCENES / scene), cal or load_calibration(), ControlConfig(**config))


def turned_planes(before, after, tol=1e-9):
    """The coordinate planes a world rotation D = after @ before^T mixes (pairs of axes it couples)."""
    d = after @ before.T
    planes = set()
    for a in range(4):
        for b in range(a + 1, 4):
            if abs(d[a, b]) > tol or abs(d[b, a]) > tol:
                planes.add("xyzw"[a] + "xyzw"[b])
    return planes, d


def drive(ctl, positions, quats=None, trigger=1.0, buttons=()):
    changed = []
    for i, p in enumerate(positions):
        q = quats[i] if quats is not None else [0, 0, 0, 1.0]
        changed.append(ctl.on_controller(np.asarray(p, float), np.asarray(q, float), trigger, list(buttons)))
    return changed


@pytest.mark.parametrize("axis, plane", [("x", "xw"), ("y", "yw"), ("z", "zw")])
def test_translation_with_trigger_turns_only_the_matching_w_plane(axis, plane):
    ctl = control(translation_gain=5.0)
    before = ctl.scene.objects[0].orientation.copy()
    start = np.array([0.0, 1.2, -0.45])
    step = np.zeros(3)
    step[AXIS[axis]] = 0.01
    changed = drive(ctl, [start + k * step for k in range(11)])       # 10 cm in 10 steps
    assert changed == [False] + [True] * 10
    planes, d = turned_planes(before, ctl.scene.objects[0].orientation)
    assert planes == {plane}
    a, b = AXIS[plane[0]], AXIS[plane[1]]
    assert np.arctan2(d[b, a], d[a, a]) == pytest.approx(5.0 * 0.1)   # gain x distance, turning a toward b
    assert ctl.scene.revision == 10


@pytest.mark.parametrize("axis, plane", [("z", "xy"), ("x", "yz"), ("y", "xz")])
def test_controller_rotation_turns_a_plane_without_w(axis, plane):
    ctl = control(rotation_gain=1.0)
    before = ctl.scene.objects[0].orientation.copy()
    quats = [Rotation.from_euler(axis, 3.0 * k, degrees=True).as_quat() for k in range(11)]   # a 30 degree roll
    drive(ctl, [[0.0, 1.2, -0.45]] * 11, quats)
    planes, d = turned_planes(before, ctl.scene.objects[0].orientation)
    assert planes == {plane}
    assert np.allclose(d[3], [0, 0, 0, 1]) and np.allclose(d[:, 3], [0, 0, 0, 1])
    # the xyz block turns as the controller did
    assert np.allclose(d[:3, :3], Rotation.from_euler(axis, 30, degrees=True).as_matrix())


def test_without_the_trigger_nothing_turns():
    ctl = control()
    before = ctl.scene.copy()
    steps = [[0.01 * k, 1.2, -0.45] for k in range(20)]
    quats = [Rotation.from_euler("z", 5 * k, degrees=True).as_quat() for k in range(20)]
    assert not any(drive(ctl, steps, quats, trigger=0.3))           # below the 0.5 threshold
    assert np.array_equal(ctl.scene.objects[0].orientation, before.objects[0].orientation)
    assert ctl.scene.revision == before.revision


def test_invalid_tracking_and_releasing_the_trigger_drop_the_grab():
    ctl = control(translation_gain=5.0)
    before = ctl.scene.objects[0].orientation.copy()
    ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 1.0, [])
    ctl.on_controller([0.5, 1.2, -0.45], [0, 0, 0, 1.0], 1.0, [], valid=False)   # a tracking glitch
    ctl.on_controller([0.5, 1.2, -0.45], [0, 0, 0, 1.0], 1.0, [])                # re-anchors here
    ctl.on_controller([0.5, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, [])
    ctl.on_controller([0.0, 1.2, -0.45], [0, 0, 0, 1.0], 1.0, [])                # moved while released
    assert np.array_equal(ctl.scene.objects[0].orientation, before)


def test_motion_is_read_in_the_screen_axes():
    # the screen turned 90 degrees about the room's y: its +x is the room's -z
    base = load_calibration()
    cal = Calibration(base.center_m, rotation_from_steps([["y", 90]]), base.edge_m, base.hand_offset_m,
                      base.hand_rotation)
    ctl = control(cal=cal)
    before = ctl.scene.objects[0].orientation.copy()
    drive(ctl, [[0, 1.2, -0.01 * k] for k in range(5)])
    planes, _ = turned_planes(before, ctl.scene.objects[0].orientation)
    assert planes == {"xw"}


def test_whole_scene_turns_about_its_centre():
    ctl = control("multi-object.yaml", rotate="scene")
    assert ctl.scene.selected == -1
    before = ctl.scene.copy()
    drive(ctl, [[0.02 * k, 1.2, -0.45] for k in range(6)])
    centre = np.mean([o.position for o in before.objects], axis=0)
    d = ctl.scene.objects[0].orientation @ before.objects[0].orientation.T
    for old, new in zip(before.objects, ctl.scene.objects):
        assert np.allclose(new.position, centre + d @ (old.position - centre))
        assert np.allclose(new.orientation, d @ old.orientation)
    assert turned_planes(before.objects[1].orientation, ctl.scene.objects[1].orientation)[0] == {"xw"}


def test_only_the_selected_object_turns():
    ctl = control("multi-object.yaml")
    ctl.command("select", "back-24-cell")
    before = ctl.scene.copy()
    drive(ctl, [[0.0, 1.2 + 0.02 * k, -0.45] for k in range(6)])
    assert np.array_equal(ctl.scene.objects[0].orientation, before.objects[0].orientation)
    assert turned_planes(before.objects[1].orientation, ctl.scene.objects[1].orientation)[0] == {"yw"}
    assert all(np.array_equal(a.position, b.position) for a, b in zip(before.objects, ctl.scene.objects))


def test_orientation_stays_orthogonal_after_100k_updates():
    """100k compositions of real controller deltas (a pool of random §4.4 motions) stay a rotation."""
    ctl = control()
    rng = np.random.default_rng(7)
    pool = [controller_rotation(rng.normal(0, 0.005, 3), rng.normal(0, 0.02, 3), (6.0, 1.0)) for _ in range(256)]
    order = rng.integers(0, len(pool), 100_000)
    for k in order:
        ctl.rotate(pool[k])
    o = ctl.scene.objects[0].orientation
    # Unrepaired, these compositions drift to ~2e-13; repaired after each update they stay at rounding.
    assert is_rotation(o, tol=1e-14)
    assert not np.allclose(o, I4, atol=0.1)   # it did turn
    assert ctl.scene.revision == 100_000


def test_buttons_act_on_press_not_while_held():
    ctl = control("multi-object.yaml")
    assert ctl.scene.selected == 0
    held = [ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, ["menu"]) for _ in range(5)]
    assert held == [True, False, False, False, False] and ctl.scene.selected == 1
    ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, [])
    ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, ["menu"])
    assert ctl.scene.selected == 2
    ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, ["trackpad"])
    assert ctl.scene.projection == "perspective"
    ctl.on_controller([0, 1.2, -0.45], [0, 0, 0, 1.0], 0.0, ["grip"])
    assert ctl.scene.selected == 0 and ctl.scene.projection == "orthographic"


def test_next_cycles_objects_then_the_whole_scene():
    ctl = control("multi-object.yaml")
    seen = [ctl.scene.selected]
    for _ in range(4):
        assert ctl.command("next")
        seen.append(ctl.scene.selected)
    assert seen == [0, 1, 2, -1, 0]
    single = control()
    assert not single.command("next") and single.scene.selected == 0


def test_select_reset_and_projection_commands():
    ctl = control("multi-object.yaml")
    initial = ctl.scene.copy()
    assert ctl.command("select", "2") and ctl.scene.selected == 2
    assert ctl.command("select", "scene") and ctl.scene.selected == -1
    assert not ctl.command("select", "-1")
    with pytest.raises(ValueError, match="front-cube"):
        ctl.command("select", "no-such")
    with pytest.raises(ValueError, match="0..2"):
        ctl.command("select", "7")
    assert ctl.command("projection", "") and ctl.scene.projection == "perspective"
    assert not ctl.command("projection", "perspective")
    assert ctl.command("projection", "orthographic")
    with pytest.raises(ValueError, match="toggle"):
        ctl.command("projection", "fisheye")
    with pytest.raises(ValueError, match="unknown scene command"):
        ctl.command("explode")
    drive(ctl, [[0.02 * k, 1.2, -0.45] for k in range(4)])
    revision = ctl.scene.revision
    assert ctl.command("reset")
    assert ctl.scene.revision == revision + 1
    assert ctl.scene.selected == initial.selected and ctl.scene.projection == "orthographic"
    for a, b in zip(initial.objects, ctl.scene.objects):
        assert np.array_equal(a.orientation, b.orientation) and np.array_equal(a.position, b.position)


def test_spin_turns_at_its_rate_in_its_plane():
    ctl = control(spin_plane="xw", spin_deg_per_s=10.0)
    before = ctl.scene.objects[0].orientation.copy()
    for _ in range(90):
        assert ctl.advance(1 / 30)
    planes, d = turned_planes(before, ctl.scene.objects[0].orientation)
    assert planes == {"xw"} and np.degrees(np.arctan2(d[3, 0], d[0, 0])) == pytest.approx(30.0)
    assert not control().advance(1.0)


def test_message_carries_the_scene():
    ctl = control("multi-object.yaml")
    ctl.command("next")
    msg = ctl.message()
    msg.validate()
    assert msg.selected == 1 and msg.revision == 1 and len(msg.objects) == 3


@pytest.mark.parametrize("kwargs, key", [
    ({"gains": {"translation": "fast"}}, "gains.translation"),
    ({"gains": {"twist": 1.0}}, "gains.twist"),
    ({"trigger_threshold": 0.0}, "trigger_threshold"),
    ({"buttons": {"menu": "explode"}}, "buttons.menu"),
    ({"buttons": {"grip": "select"}}, "buttons.grip"),
    ({"rotate": "world"}, "rotate"),
    ({"spin": {"plane": "xq"}}, "spin.plane"),
])
def test_bad_parameters_name_the_key(kwargs, key):
    params = {"gains": {}, "trigger_threshold": 0.5, "buttons": {}, "rotate": "object", "spin": {}, **kwargs}
    with pytest.raises(ConfigError) as err:
        ControlConfig.from_params(**params, source="launch.yaml")
    assert err.value.key == key

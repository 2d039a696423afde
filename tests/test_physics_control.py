"""The controller and a physics scene's static bodies: a static floor is never the controller's object."""
import numpy as np
import pytest

from touch4d.cli import main
from touch4d.geometry.scene import load_scene
from touch4d.physics.config import load_physics
from touch4d.physics.session import PhysicsSession
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.scene_control import ControlConfig, SceneCommandError

pytestmark = pytest.mark.timeout(600)     # the first test may compile the step (numba; cached afterwards)

CENTER = np.array([0.0, 1.2, -0.45])       # the default calibration's screen centre (room, metres)
Q = np.array([0.0, 0.0, 0.0, 1.0])


def session(path):
    return PhysicsSession(load_scene(path), load_physics(path), load_calibration(None), ControlConfig())


def turn(s, samples=6):
    """Hold the trigger and move the controller sideways: a turn in the xw and yw planes."""
    for k in range(samples):
        s.on_controller(CENTER + [0.02 * k, 0.01 * k, 0.0], Q, 1.0, [], True)


@pytest.mark.parametrize("path", ["config/scenes/physics-drop.yaml", "config/scenes/physics-stack.yaml"])
def test_the_default_object_is_the_first_that_moves_and_the_floor_never_turns(path):
    s = session(path)
    floor = s.control.scene.objects[0]
    assert floor.name == "floor" and s.world.static[0] and not s.world.static[1]
    assert s.control.scene.selected == 1
    before = [o.orientation.copy() for o in s.control.scene.objects]
    turn(s)
    after = [o.orientation for o in s.control.scene.objects]
    np.testing.assert_array_equal(after[0], before[0])
    assert not np.allclose(after[1], before[1])
    np.testing.assert_array_equal(np.asarray(s.message().objects[0]["orientation"]), before[0])


def test_next_passes_the_floor_by_select_refuses_it_and_the_whole_scene_turns_without_it():
    s = session("config/scenes/physics-stack.yaml")
    count = len(s.control.scene.objects)
    seen = []
    for _ in range(count + 1):
        s.command("next")
        seen.append(s.control.scene.selected)
    assert 0 not in seen and set(seen) == set(range(1, count)) | {-1}
    with pytest.raises(SceneCommandError, match="'floor' \\(object 0\\) is static"):
        s.command("select", "floor")
    s.command("select", "scene")
    floor = s.control.scene.objects[0].orientation.copy(), s.control.scene.objects[0].position.copy()
    turn(s)
    np.testing.assert_array_equal(s.control.scene.objects[0].orientation, floor[0])
    np.testing.assert_array_equal(s.control.scene.objects[0].position, floor[1])
    s.command("reset")
    assert s.control.scene.selected == 1


def test_a_loaded_scene_with_a_floor_first_selects_its_first_moving_body():
    s = session("config/scenes/physics-spin.yaml")
    s.command("load", open("config/scenes/physics-drop.yaml").read())
    assert s.control.scene.selected == 1


def test_scene_check_names_the_object_the_controller_turns(capsys):
    assert main(["scene", "check", "config/scenes/physics-drop.yaml"]) == 0
    assert "the controller turns object 1 (tesseract); never the static 'floor'" in capsys.readouterr().out

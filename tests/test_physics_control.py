"""The controller and a physics scene's static bodies: a static floor is never the controller's object."""
import re

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


# ---- touch4d physics pause | play | step | reset: said and shown ---------------------------------------


def journal(*entries):
    from touch4d.messages import PhysicsInput

    return [PhysicsInput(step=step, kind=kind, args=args) for step, kind, args in entries]


def command(name, argument=""):
    return {"command": name, "argument": argument}


def test_the_outcome_of_a_command_is_read_from_the_journal_after_it():
    from touch4d.commands.physics import command_outcome

    before = journal((90, "run", {"steps": 10}))
    paused = before + journal((100, "command", command("pause")))
    assert command_outcome("pause", "", before, final=True) is None                  # not taken: none came
    assert command_outcome("pause", "", paused, final=False) is None                 # steps may yet follow
    assert command_outcome("pause", "", paused, final=True) == "paused at step 100 (pause again or play to go on)"
    resumed = paused + journal((100, "run", {"steps": 16}))
    assert "running again from step 100" in command_outcome("pause", "", resumed, final=False)
    stepped = journal((100, "command", command("step", "5")), (100, "run", {"steps": 5}))
    assert command_outcome("step", "5", stepped[:1], final=False) is None
    assert command_outcome("step", "5", stepped, final=False) == "ran 5 step(s) from step 100: paused at step 105"
    assert command_outcome("step", "3", stepped, final=True) is None                 # another command's entry
    assert command_outcome("play", "", journal((7, "command", command("play")), (7, "run", {"steps": 3})),
                           final=False) == "running from step 7"
    assert "(step 0)" in command_outcome("reset", "", journal((4000, "command", command("reset"))), final=False)


def test_the_plain_scene_node_refuses_pause_naming_the_physics_node():
    from touch4d.tracking.scene_control import SceneControl

    control = SceneControl(load_scene("config/scenes/tesseract.yaml"), load_calibration(None), ControlConfig())
    for name in ("pause", "play", "step"):
        with pytest.raises(SceneCommandError, match=f"'{name}' is a physics command.*scene:=physics"):
            control.command(name)
    with pytest.raises(SceneCommandError, match="unknown scene command 'jump'"):
        control.command("jump")


def test_physics_commands_on_the_bus_are_logged_and_shown_and_none_taken_is_said(monkeypatch, capsys):
    from touch4d.bus.config import ENV_VAR
    from touch4d.bus.testing import node_process, running_broker

    with running_broker() as bus:
        monkeypatch.setenv(ENV_VAR, bus.to_json())
        assert main(["physics", "pause", "--wait", "1"]) == 1                          # nobody runs physics
        assert "no physics node took pause within 1 s" in capsys.readouterr().err
        with node_process("physics", bus, params={"scene": "config/scenes/physics-drop.yaml"}) as proc:
            assert proc.started, proc.text
            assert main(["physics", "pause", "--wait", "20"]) == 0
            out = capsys.readouterr().out
            assert re.search(r"physics node: paused at step \d+", out), out
            assert main(["physics", "step", "5", "--wait", "20"]) == 0
            step = re.search(r"ran 5 step\(s\) from step (\d+): paused at step (\d+)", capsys.readouterr().out)
            assert step and int(step.group(2)) == int(step.group(1)) + 5
            assert main(["physics", "reset", "--wait", "20"]) == 0
            assert "every body back where the scene file has it" in capsys.readouterr().out
        log = proc.text
    assert re.search(r"scene/command pause at step \d+: paused at step \d+", log), log
    assert re.search(r"scene/command step 5 at step \d+: paused at step \d+, 5 single steps due", log), log
    last = [line for line in log.splitlines() if "steps run" in line][-1]
    assert len(re.findall(r"\d+ steps", last)) == 1 and re.search(r"\d+ steps run \(\d+ more dropped", last), last


def test_the_plain_scene_node_never_turns_a_static_floor_either():
    from touch4d.bus.testing import running_broker
    from touch4d.nodes.scene import SceneNode

    with running_broker() as bus:
        node = SceneNode(bus=bus, params={"scene": "config/scenes/physics-drop.yaml"}, heartbeat=False)
        try:
            assert node.control.scene.selected == 1 and node.control.fixed == {0}
        finally:
            node.shutdown()


def test_a_scene_loaded_into_the_plain_scene_node_keeps_its_floor_static():
    from touch4d.bus.testing import running_broker
    from touch4d.messages import SceneCommand
    from touch4d.nodes.scene import SceneNode

    with running_broker() as bus:
        node = SceneNode(bus=bus, params={"scene": "config/scenes/hypercube.yaml"}, heartbeat=False)
        try:
            node.on_command(SceneCommand(command="load", argument=open("config/scenes/physics-drop.yaml").read()))
            assert [o.name for o in node.control.scene.objects] == ["floor", "tesseract"]
            assert node.control.scene.selected == 1 and node.control.fixed == {0}
            with pytest.raises(SceneCommandError, match="static"):
                node.control.command("select", "floor")
        finally:
            node.shutdown()

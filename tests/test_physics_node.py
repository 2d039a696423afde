"""The physics node's logic (controller, commands, journal replay) and the node as a process on the bus."""
import json

import numpy as np
import pytest

from touch4d.errors import ConfigError

from touch4d.bus import Node
from touch4d.bus.config import ENV_VAR
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.cli import main
from touch4d.geometry.scene import load_scene, parse_scene
from touch4d.messages import ControllerState, Heartbeat, PhysicsContacts, PhysicsInput, SceneCommand, SceneState
from touch4d.physics.config import load_physics, parse_physics
from touch4d.physics.session import PhysicsSession, replay, split_buttons
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.scene_control import ControlConfig, SceneControl

pytestmark = pytest.mark.timeout(600)     # the first test may compile the step (numba; cached afterwards)

DROP = "config/scenes/physics-drop.yaml"
CENTER = np.array([0.0, 1.2, -0.45])       # the default calibration's screen centre (room, metres)
Q = np.array([0.0, 0.0, 0.0, 1.0])


def session(path=DROP, **kwargs):
    scene_buttons, physics_buttons = split_buttons({"menu": "next", "grip": "reset", "thumbstick": "pause",
                                                    "a": "step"})
    config = ControlConfig(buttons=scene_buttons)
    return PhysicsSession(load_scene(path), load_physics(path), load_calibration(None), config, physics_buttons,
                          **kwargs)


def test_the_controller_turns_the_selected_body_as_the_scene_node_does():
    data = {"physics": {"gravity": [0, 0, 0, 0]}, "objects": [{"name": "t", "shape": "tesseract", "position": [0, 0, 0, 1.5]}]}
    calibration = load_calibration(None)
    s = PhysicsSession(parse_scene(data), parse_physics(data), calibration, ControlConfig())
    plain = SceneControl(parse_scene(data), calibration, ControlConfig())
    for k in range(6):
        sample = (CENTER + [0.01 * k, 0.004 * k, 0.0], Q, 1.0, [], True)
        s.on_controller(*sample)
        plain.on_controller(*sample)
        s.advance(5)                                             # free, at rest: the physics keeps the pose
    turned = plain.scene.objects[0].orientation
    assert not np.allclose(turned, np.eye(4))
    np.testing.assert_allclose(s.message().objects[0]["orientation"], turned, atol=1e-12)


def test_pause_step_play_and_reset():
    s = session()
    y0 = s.message().objects[1]["position"][1]
    s.command("pause")
    s.advance(100)
    assert s.state.steps == 0 and s.message().objects[1]["position"][1] == y0
    s.command("step", "3")
    s.advance(100)
    assert s.state.steps == 3 and s.paused
    s.on_controller(CENTER, Q, 0.0, ["thumbstick"])              # the pause button toggles: running again
    s.advance(100)
    assert s.state.steps == 103 and s.message().objects[1]["position"][1] < y0
    s.command("reset")
    assert s.state.steps == 0 and s.message().objects[1]["position"][1] == y0
    with pytest.raises(ValueError, match="step"):
        s.command("step", "many")


def test_a_journal_replays_to_the_same_bytes():
    s = session()
    rng = np.random.default_rng(7)
    for k in range(12):
        trigger = 1.0 if 3 <= k < 8 else 0.0
        s.on_controller(CENTER + rng.normal(scale=0.02, size=3), Q, trigger, ["menu"] if k == 9 else [])
        s.advance(int(rng.integers(5, 40)))
        if k == 10:
            s.command("projection", "perspective")
    again = replay(load_scene(DROP), load_physics(DROP), load_calibration(None), s.control.config,
                   s.physics_buttons, s.journal)
    assert again.state.steps == s.state.steps > 0
    assert again.state.digest() == s.state.digest()
    assert again.message().objects[1]["orientation"].tobytes() == s.message().objects[1]["orientation"].tobytes()


def test_bad_buttons_are_named():
    with pytest.raises(ConfigError) as info:
        split_buttons({"menu": "explode"}, "launch.yaml")
    assert info.value.key == "buttons.menu" and info.value.got == "explode" and "pause" in info.value.expected


def test_loading_another_scene_builds_its_world():
    s = session()
    s.advance(50)
    s.command("load", "physics: {gravity: [0, 0, 0, -2]}\nobjects:\n  - {name: ball, shape: 24-cell, size: 0.3, "
                      "position: [0, 0, 0, 1.5], physics: {velocity: [0.5, 0, 0, 0]}}\n")
    assert s.world.names == ("ball",) and s.state.steps == 0
    s.advance(100)
    np.testing.assert_allclose(s.message().objects[0]["position"], [0.05, 0, 0, 1.5 - 0.01], atol=1e-12)
    with pytest.raises(ConfigError):
        s.command("load", "objects: [{shape: tesseract, physics: {mass: -1}}]")
    assert s.world.names == ("ball",)                      # a bad scene changes nothing


def test_the_node_drops_the_body_publishes_contacts_and_obeys_pause(tmp_path, capsys, monkeypatch):
    with running_broker() as bus:
        with node_process("physics", bus, params={"scene": DROP, "publish_rate": 50.0}) as proc:
            probe = Node("probe", bus=bus)
            try:
                states = collect(probe, "scene/state", SceneState)
                hits = collect(probe, "physics/contacts", PhysicsContacts)
                journal = collect(probe, "physics/journal", PhysicsInput)
                beats = collect(probe, "node/heartbeat", Heartbeat)
                commands = probe.create_publisher("scene/command", SceneCommand)
                controller = probe.create_publisher("controller/state", ControllerState)
                try:
                    wait_until(lambda: hits, timeout=30, spin=probe)      # it fell and struck the floor
                except TimeoutError:
                    raise AssertionError(f"physics node output:\n{proc.text}") from None
                hit = hits[0]
                assert hit.names == ["floor", "tesseract"] and set(hit.a) | set(hit.b) == {0, 1}
                assert (hit.speeds > 1.0).all() and (hit.impulses > 0).all()
                np.testing.assert_allclose(hit.normals[:, 1], 1.0, atol=1e-9)     # the floor's top, up
                assert states[-1].objects[1]["position"][1] < 0.45
                # the node's counters ride on its heartbeat
                mine = lambda: [b.stats for b in beats if b.kind == "physics" and b.stats.get("contact_events", 0) > 0]  # noqa: E731
                wait_until(mine, timeout=10, spin=probe)
                assert mine()[-1]["steps"] > 0 and mine()[-1]["late_steps"] >= 0 and mine()[-1]["bad_commands"] == 0
                for k in range(6):                                   # the trigger turns the tesseract as it lies
                    controller.publish(ControllerState(position=CENTER + [0.01 * k, 0, 0], orientation=Q, trigger=1.0,
                                                       buttons=[], valid=True))
                    probe.spin(0.03)
                monkeypatch.setenv(ENV_VAR, bus.to_json())          # the command line, as in a launched stack
                assert main(["physics", "pause"]) == 0
                probe.spin(0.3)
                frozen = states[-1].revision
                probe.spin(0.3)
                assert states[-1].revision == frozen
                commands.publish(SceneCommand(command="reset"))
                wait_until(lambda: states[-1].revision > frozen, timeout=10, spin=probe)
                assert states[-1].objects[1]["position"][1] == pytest.approx(0.45)
                assert main(["physics", "step", "25"]) == 0
                wait_until(lambda: any(e.kind == "run" and e.args["steps"] > 0 for e in journal[-3:]), timeout=10,
                           spin=probe)
                probe.spin(0.3)
            finally:
                probe.shutdown()
    # the recorded session (journal and states) replays to the same bytes
    from touch4d.log.writer import LogWriter
    from touch4d.messages import encode

    log = tmp_path / "session.mcap"
    with LogWriter(log) as writer:
        for t, msg in enumerate([("physics/journal", m) for m in journal] + [("scene/state", m) for m in states]):
            writer.write(msg[0], encode(msg[1]), t)
    capsys.readouterr()
    assert main(["physics", "replay", str(log), "--json"]) == 0            # the set-up from the journal
    report = json.loads(capsys.readouterr().out)
    assert report["identical"] and report["max_difference"] == 0.0
    assert report["steps"] == 25 and report["states_compared"] > 10      # every state before and after the reset


def test_released_the_controller_throws_the_body_at_its_last_turning_rate():
    from touch4d.physics import bivector as bv

    data = {"physics": {"gravity": [0, 0, 0, 0]}, "objects": [{"name": "t", "shape": "tesseract", "position": [0, 0, 0, 1.5]}]}
    calibration = load_calibration(None)
    s = PhysicsSession(parse_scene(data), parse_physics(data), calibration, ControlConfig())
    plain = SceneControl(parse_scene(data), calibration, ControlConfig())
    orientations = []
    for k in range(8):                                         # 0.2 m/s sideways, a sample every 10 ms
        sample = (CENTER + [0.002 * k, 0.0, 0.0], Q, 1.0, [], True)
        s.on_controller(*sample)
        plain.on_controller(*sample)
        orientations.append(plain.scene.objects[0].orientation.copy())
        s.advance(10)
        np.testing.assert_allclose(s.message().objects[0]["orientation"], orientations[-1], atol=1e-12)  # held
    s.on_controller(CENTER + [0.014, 0.0, 0.0], Q, 0.0, [], True)        # released
    rate = bv.vee(orientations[-1] @ orientations[-2].T) / 0.01
    assert abs(rate[2]) > 1.0                                  # the xw plane (paper §4.4: x motion turns xw)
    released = s.state.r[0].copy()
    s.advance(500)
    from touch4d.physics.world import angular_velocity
    np.testing.assert_allclose(angular_velocity(s.world, s.state)[0], rate, atol=1e-9)
    np.testing.assert_allclose(s.state.r[0], bv.exp(rate * 0.5) @ released, atol=1e-9)


def test_the_nodes_states_keep_max_rate_spacing_the_steady_ones_too():
    """A falling body changes at every 50 Hz tick; with max_rate 10 its states, the steady 7 Hz ones for late
    joiners among them, are at least 0.1 s apart by their stamps (when each went out, not when a loaded
    machine delivered it), yet they keep coming while it falls."""
    with running_broker() as bus:
        params = {"scene": DROP, "publish_rate": 50.0, "rate": 7.0, "max_rate": 10.0}
        with node_process("physics", bus, params=params) as proc:
            probe = Node("probe", bus=bus)
            try:
                states = collect(probe, "scene/state", SceneState)
                try:
                    wait_until(lambda: len({s.revision for s in states}) >= 2, timeout=30, spin=probe)
                except TimeoutError:
                    raise AssertionError(f"physics node output:\n{proc.text}") from None
                first = len(states)            # from the first move on
                probe.spin(1.5)
            finally:
                probe.shutdown()
    stamps = np.array([s.stamp for s in states])
    assert np.diff(stamps).min() >= 0.1 - 1e-3, np.diff(stamps)
    moved = {s.revision for s in states[first:]}
    assert len(moved) >= 5, np.diff(stamps)          # about 1.5 s at 10 Hz while it falls and tumbles

"""The scene node with a scripted tracker, its automatic spin, and bad parameters."""
import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker, wait_until
from touch4d.messages import SceneState

pytestmark = pytest.mark.timeout(180)


def coupled_planes(d, tol=1e-9):
    return {"xyzw"[a] + "xyzw"[b] for a in range(4) for b in range(a + 1, 4) if abs(d[a, b]) > tol or abs(d[b, a]) > tol}


def watch_scene(bus, scene_params, tracker_params=None, until=None):
    probe = Node("probe", bus=bus)
    try:
        states = collect(probe, "scene/state", SceneState)
        with node_process("scene", bus, params=scene_params) as scene:
            tracker = node_process("scripted_tracker", bus, params=tracker_params) if tracker_params else None
            try:
                if tracker:
                    with tracker:
                        wait_until(lambda: states and until(states), timeout=60, spin=probe)
                else:
                    wait_until(lambda: states and until(states), timeout=60, spin=probe)
            except TimeoutError:
                raise AssertionError(scene.text) from None
        return states
    finally:
        probe.shutdown()


def test_a_scripted_grab_orbit_turns_the_hypercube_in_the_xw_and_yw_planes():
    """Small circles in the screen's xy plane with the trigger held: only xw and yw turn (§4.4)."""
    with running_broker() as bus:
        states = watch_scene(bus, {"scene": "config/scenes/hypercube.yaml"},
                             {"path": "grab-orbit", "rate": 90.0}, until=lambda s: s[-1].revision >= 40)
    first = states[0].objects[0]["orientation"]
    d = states[-1].objects[0]["orientation"] @ first.T
    assert coupled_planes(d) <= {"xw", "yw", "xy"}
    # xw and yw rotations compose with a small xy part (they do not commute), but nothing in z
    assert np.allclose(d[2], [0, 0, 1, 0]) and np.allclose(d[:, 2], [0, 0, 1, 0])
    assert abs(d[0, 3]) > 1e-3 or abs(d[1, 3]) > 1e-3


def test_spin_parameter_turns_the_scene_slowly_in_its_plane():
    with running_broker() as bus:
        states = watch_scene(bus, {"scene": "config/scenes/hypercube.yaml", "spin": {"plane": "zw", "deg_per_s": 20.0}},
                             until=lambda s: len(s) >= 10)
    first, last = states[0], states[-1]
    d = last.objects[0]["orientation"] @ first.objects[0]["orientation"].T
    assert coupled_planes(d) == {"zw"}
    assert last.revision > first.revision


@pytest.mark.parametrize("params, key", [
    ({"scene": "config/scenes/no-such.yaml"}, "no-such.yaml"),
    ({"gains": {"translation": "fast"}}, "gains.translation"),
    ({"spin": {"plane": "xq"}}, "spin.plane"),
])
def test_bad_parameters_stop_the_node_with_the_key_named(params, key):
    with running_broker() as bus:
        with node_process("scene", bus, params=params) as proc:
            wait_until(lambda: proc.proc.poll() is not None, timeout=60)
        assert proc.returncode == 2
        assert key in proc.text and "Traceback" not in proc.text


@pytest.mark.parametrize("params, said", [
    ({}, "the controller turns the selected object"),
    ({"rotate": "none"}, "the controller turns nothing"),
    ({"rotate": "none", "spin": {"plane": "xw", "deg_per_s": 6.0}},
     "the controller turns nothing; spinning the selected object in xw at 6 deg/s"),
    ({"rotate": "scene"}, "the controller turns the whole scene"),
])
def test_the_node_says_what_turns_the_scene(params, said, caplog):
    """The start-up line names what the controller turns (nothing, with rotate: none) and the spin."""
    import logging

    from touch4d.nodes.scene import SceneNode

    with running_broker() as bus, caplog.at_level(logging.INFO, logger="scene"):
        node = SceneNode(params={"scene": "config/scenes/multi-object.yaml", **params}, bus=bus)
        node.shutdown()
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("scene "))
    assert line.endswith(f"3 object(s); {said}") and "rotating" not in line, line

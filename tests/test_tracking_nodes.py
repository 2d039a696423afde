"""Tracker nodes as processes: the scripted tracker is deterministic, the desktop tracker follows
`ui/input`, the openvr tracker fails clearly without SteamVR, and every tracker fits the launch role."""
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import REPO, collect, launch_process, node_process, running_broker, wait_until
from touch4d.messages import ControllerState, HandPose, InputEvents, SceneState
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.outputs import from_hand
from touch4d.tracking.paths import load_path, looped

pytestmark = pytest.mark.timeout(240)
TRACKERS_LAUNCH = "tests/data/launch/trackers.yaml"


def record_tracker(bus, params, count, module="scripted_tracker"):
    """Run a tracker process and return (hand poses, controller states) until `count` of each arrived."""
    probe = Node("probe", bus=bus)
    try:
        hands = collect(probe, "hand/pose", HandPose)
        controllers = collect(probe, "controller/state", ControllerState)
        with node_process(module, bus, params=params) as proc:
            try:
                wait_until(lambda: len(hands) >= count and len(controllers) >= count, timeout=60, spin=probe)
            except TimeoutError:
                raise AssertionError(f"{module} output:\n{proc.text}") from None
        return hands, controllers
    finally:
        probe.shutdown()


def test_scripted_tracker_publishes_the_same_poses_on_every_run():
    params = {"path": "face-sweep", "rate": 200.0}
    with running_broker() as bus:
        first = record_tracker(bus, params, 80)
        second = record_tracker(bus, params, 80)
    path = load_path("face-sweep")
    cal = load_calibration()
    runs = []
    for hands, controllers in (first, second):
        by_seq = {m.seq: m for m in hands}
        ctrl_by_seq = {m.seq: m for m in controllers}
        runs.append((by_seq, ctrl_by_seq))
        for seq, msg in by_seq.items():   # pose k is the path at k / rate, exactly
            expected_hand, expected_ctrl = from_hand(looped(path, seq / 200.0), cal)
            assert np.array_equal(msg.position, expected_hand.position)
            assert np.array_equal(msg.orientation, expected_hand.orientation)
            if seq in ctrl_by_seq:
                assert np.array_equal(ctrl_by_seq[seq].position, expected_ctrl.position)
                assert ctrl_by_seq[seq].trigger == 0.0
    common = set(runs[0][0]) & set(runs[1][0])
    assert len(common) >= 40
    for seq in common:
        assert np.array_equal(runs[0][0][seq].position, runs[1][0][seq].position)
    moved = [runs[0][0][s].position[0] for s in sorted(runs[0][0])]
    assert np.ptp(moved) > 0.01   # the hand really sweeps


def test_scripted_tracker_stops_at_the_end_without_loop():
    with running_broker() as bus:
        probe = Node("probe", bus=bus)
        try:
            hands = collect(probe, "hand/pose", HandPose)
            with node_process("scripted_tracker", bus, params={"path": "hold", "rate": 50.0, "loop": False}) as proc:
                proc.wait_for_line("path finished", timeout=60)
                probe.spin(0.5)
                seen = len(hands)
                probe.spin(0.5)
                assert len(hands) == seen
            assert hands and max(m.seq for m in hands) == 50   # t = 0 .. 1 s at 50 Hz
        finally:
            probe.shutdown()


def test_scripted_tracker_rejects_an_unknown_path():
    with running_broker() as bus:
        with node_process("scripted_tracker", bus, params={"path": "nowhere"}) as proc:
            wait_until(lambda: proc.proc.poll() is not None, timeout=60)
        assert proc.returncode == 2
        assert "paths.nowhere" in proc.text and "face-sweep" in proc.text and "Traceback" not in proc.text


def test_desktop_tracker_moves_the_hand_with_keys_and_holds_the_trigger_with_space():
    with running_broker() as bus:
        probe = Node("probe", bus=bus)
        try:
            hands = collect(probe, "hand/pose", HandPose)
            controllers = collect(probe, "controller/state", ControllerState)
            keys = probe.create_publisher("ui/input", InputEvents)
            with node_process("desktop_tracker", bus, params={"home": [0.0, 0.0, 0.0], "move_speed": 1.0}) as proc:
                try:
                    wait_until(lambda: hands and controllers, timeout=60, spin=probe)
                except TimeoutError:
                    raise AssertionError(proc.text) from None
                assert np.allclose(hands[-1].position, 0.0) and controllers[-1].trigger == 0.0
                for _ in range(20):
                    keys.publish(InputEvents(keys_down=["d", "space"]))
                    probe.spin(0.03)
                wait_until(lambda: hands[-1].position[0] > 0.1 and controllers[-1].trigger == 1.0, timeout=30, spin=probe)
                assert abs(hands[-1].position[1]) < 1e-12 and abs(hands[-1].position[2]) < 1e-12
                keys.publish(InputEvents(keys_down=[]))
                wait_until(lambda: controllers[-1].trigger == 0.0, timeout=30, spin=probe)
                x = hands[-1].position[0]
                probe.spin(0.3)
                assert hands[-1].position[0] == x   # released: the hand stays
        finally:
            probe.shutdown()


def test_desktop_tracker_without_a_display_says_there_is_no_window_and_how_to_get_one(monkeypatch, caplog):
    from touch4d.nodes.desktop_tracker import DesktopTracker

    monkeypatch.delenv("DISPLAY", raising=False)
    with running_broker() as bus:
        DesktopTracker(bus=bus, heartbeat=False).shutdown()
    text = caplog.text
    assert "no window" in text and "xvfb-run" in text and "display" in text
    assert "steer the hand from the renderer window" not in text


def test_desktop_tracker_warns_once_when_no_window_sends_input(monkeypatch, caplog):
    from touch4d.nodes.desktop_tracker import DesktopTracker

    monkeypatch.setenv("DISPLAY", ":99")     # a display, but no renderer window publishing ui/input
    with running_broker() as bus:
        node = DesktopTracker(bus=bus, params={"input_timeout": 0.2}, heartbeat=False)
        try:
            node.spin(0.6)
        finally:
            node.shutdown()
    warnings = [r for r in caplog.records if "no ui/input" in r.getMessage()]
    assert len(warnings) == 1 and "headless" in warnings[0].getMessage()


def run_openvr_tracker(extra_path=None):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if extra_path:
        env["PYTHONPATH"] = str(extra_path)
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "touch4d.bus", "openvr_tracker", "--name", "tracker"],
                          capture_output=True, text=True, timeout=120, env=env, cwd=REPO)
    return done, time.monotonic() - start


def test_openvr_tracker_without_steamvr_exits_with_its_message():
    done, _ = run_openvr_tracker()
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert "touch4d[vr]" in done.stderr and "SteamVR" in done.stderr


FAKE_OPENVR = textwrap.dedent("""
    # A stand-in for the openvr package: no SteamVR (INIT_FAILS) or one right-hand controller.
    import os
    VRApplication_Background = 3
    TrackedControllerRole_LeftHand, TrackedControllerRole_RightHand = 1, 2
    k_unTrackedDeviceIndexInvalid = 0xFFFFFFFF
    k_unMaxTrackedDeviceCount = 64
    TrackingUniverseStanding = 1

    class InitError(Exception):
        pass

    class _Axis:
        def __init__(self, x): self.x, self.y = x, 0.0

    class _State:
        rAxis = [_Axis(0.0), _Axis(0.75), _Axis(0.0), _Axis(0.0), _Axis(0.0)]
        ulButtonPressed = 1 << 2   # grip

    class _Pose:
        bPoseIsValid = True
        # turned 90 degrees about y, 0.1 m right of the screen centre
        mDeviceToAbsoluteTracking = [[0.0, 0.0, 1.0, 0.1], [0.0, 1.0, 0.0, 1.2], [-1.0, 0.0, 0.0, -0.45]]

    class _System:
        def getTrackedDeviceIndexForControllerRole(self, role):
            return 3 if role == TrackedControllerRole_RightHand else k_unTrackedDeviceIndexInvalid
        def getDeviceToAbsoluteTrackingPose(self, universe, seconds, count):
            return [_Pose() for _ in range(count)]
        def getControllerState(self, index):
            return True, _State()

    def init(kind):
        if os.environ.get("FAKE_OPENVR_INIT_FAILS"):
            raise InitError("VRInitError_Init_NoServerForBackgroundApp")
        return _System()

    def shutdown():
        pass
""")


def test_openvr_tracker_without_a_running_steamvr_says_so(tmp_path, monkeypatch):
    (tmp_path / "openvr.py").write_text(FAKE_OPENVR)
    monkeypatch.setenv("FAKE_OPENVR_INIT_FAILS", "1")
    done, _ = run_openvr_tracker(tmp_path)
    assert done.returncode == 1 and "Traceback" not in done.stderr
    assert "SteamVR is not running" in done.stderr and "NoServerForBackgroundApp" in done.stderr


def test_openvr_tracker_publishes_the_controller_and_the_hand_it_holds(tmp_path, monkeypatch):
    (tmp_path / "openvr.py").write_text(FAKE_OPENVR)
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    with running_broker() as bus:
        hands, controllers = record_tracker(bus, {"rate": 50.0}, 3, module="openvr_tracker")
    ctrl = controllers[-1]
    assert np.allclose(ctrl.position, [0.1, 1.2, -0.45]) and ctrl.trigger == 0.75 and ctrl.buttons == ["grip"]
    expected_pos, expected_q = load_calibration().hand_from_controller(ctrl.position, ctrl.orientation)
    assert hands[-1].valid and np.allclose(hands[-1].position, expected_pos)
    assert np.allclose(hands[-1].orientation, expected_q)


def write_tracker_log(path, seconds=3.0, rate=90.0):
    """A recorded session of the scripted demo path, as the recorder would write it."""
    from touch4d.log.writer import LogWriter

    demo, cal = load_path("orbit"), load_calibration()
    t0 = time.time_ns()
    with LogWriter(path) as log:
        for k in range(int(seconds * rate)):
            hand, controller = from_hand(looped(demo, k / rate), cal, stamp=t0 / 1e9 + k / rate)
            hand.seq = controller.seq = k
            at = t0 + int(k / rate * 1e9)
            log.write("hand/pose", hand.encode(), at)
            log.write("controller/state", controller.encode(), at)


@pytest.mark.parametrize("tracker", ["scripted", "desktop", "replay"])
def test_every_tracker_fits_the_tracker_role_of_one_launch_file(tracker, tmp_path):
    args = [TRACKERS_LAUNCH, f"tracker:={tracker}"]
    if tracker == "replay":
        log = tmp_path / "session.mcap"
        write_tracker_log(log)
        args += [f"tracker.file:={log}", "tracker.loop:=true"]
    with launch_process(args) as run:
        try:
            bus = run.wait_ready(timeout=60)
        except (TimeoutError, RuntimeError):
            raise AssertionError(run.text) from None
        probe = Node("probe", bus=bus)
        try:
            hands = collect(probe, "hand/pose", HandPose)
            states = collect(probe, "scene/state", SceneState)
            try:
                wait_until(lambda: len(hands) >= 5 and states, timeout=60, spin=probe)
            except TimeoutError:
                raise AssertionError(run.text) from None
            assert all(m.valid for m in hands)
        finally:
            probe.shutdown()
        assert run.stop() == 0, run.text

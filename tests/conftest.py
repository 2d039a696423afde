"""Test set-up shared by every test module."""
import touch4d  # noqa: F401  first: it caps BLAS thread pools (tiny matrices, busy 2-core machines)

import random  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# Property tests draw the same examples every run (each test's own seed, no example database): the suite
# on a clean clone passes or fails alike every time; a wider search is a deliberate run
# (`--hypothesis-profile=explore`).
settings.register_profile("touch4d", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("touch4d")


@pytest.fixture
def can_group():
    """A CAN channel two processes share: python-can's udp_multicast on a group of this test's own.

    Every group shares one UDP port, and Linux hands a socket the datagrams of every group joined
    on the machine: tests of concurrent runs (several checkouts on one machine) would hear each
    other's boards. So a lock file lets one such test run at a time. Skipped where this machine
    cannot send multicast (a container without a multicast route)."""
    import fcntl
    import tempfile

    import can

    group = f"239.{random.randrange(1, 255)}.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    with open(Path(tempfile.gettempdir()) / "touch4d-udp-multicast-tests.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            with can.Bus(interface="udp_multicast", channel=group) as a, \
                    can.Bus(interface="udp_multicast", channel=group) as b:
                a.send(can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False))
                if b.recv(2.0) is None:
                    raise OSError("nothing came back")
        except (OSError, can.CanError) as exc:
            pytest.skip(f"no multicast CAN between processes here (python-can udp_multicast: {exc})")
        yield group


# ---- markers: `./dev test -m "not slow"` runs the fast part (in-process tests) in about a minute ----------

# What a module's source says it does, by the names it uses.
BROWSER_WORDS = ("chromium(",)
PROCESS_WORDS = ("subprocess", "node_process(", "LaunchRun", "launch_run(", "Popen", "LocalCluster", "run_session(",
                 "run_simulation(", "multiprocessing")
# Tests that take seconds on the 2-core machine (numba compilations, simulations, floods, launches the
# words above miss): measured with --durations, over 3 s a test or 5 s a file there.
SLOW_TESTS = ("test_study_power.py", "test_study_fanout.py", "test_study_fit.py", "test_study_glove_design.py",
              "test_study_views.py", "test_study_observer.py", "test_scene_files.py::test_any_wrong_value",
              "test_motors_node.py::test_send_faults", "test_log_record.py::test_10k", "test_physics_shapes.py",
              "test_boards_freeze.py", "test_boards_duty.py::test_the_thermal_limit", "test_log_replay.py",
              "test_stuck_consumers.py", "test_web_flood.py", "test_physics_node.py", "test_scene_node_bus.py",
              "test_foxglove_node.py", "test_packaging.py", "test_wheel.py", "test_study_analysis.py",
              "test_study_check.py", "test_physics.py", "test_launch_run.py", "test_motors_node.py",
              "test_bus_container.py", "test_render_backends.py", "test_physics_stages.py", "test_web_limits.py",
              "test_geometry_section.py", "test_launch_namespace.py", "test_messages_checks.py",
              "test_launch_group.py", "test_geometry_polytope.py", "test_fuzz.py")
_sources: dict[str, str] = {}


def _source(item) -> str:
    path = str(item.fspath)
    if path not in _sources:
        _sources[path] = Path(path).read_text(errors="replace")
    return _sources[path]


def pytest_collection_modifyitems(config, items):
    """Mark each test `browser` (drives Chromium), `process` (starts processes) and `slow` (either, or
    measured slow in process), so a contributor can run the fast part alone."""
    for item in items:
        text = _source(item)
        browser = any(word in text for word in BROWSER_WORDS)
        process = any(word in text for word in PROCESS_WORDS)
        if browser:
            item.add_marker(pytest.mark.browser)
        if process:
            item.add_marker(pytest.mark.process)
        name = f"{Path(str(item.fspath)).name}::{item.name}"
        if browser or process or any(name.startswith(s) for s in SLOW_TESTS):
            item.add_marker(pytest.mark.slow)

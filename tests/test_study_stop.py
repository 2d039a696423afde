"""However `study run` ends (SIGTERM, SIGHUP, SIGINT, an exception, SIGKILL), its stack ends with it:
each stop signal raises Stopped in the run (no process needed), and with real processes a simulated
session is stopped in the middle by each way out that takes another path (a signal, an exception, a
kill the run cannot catch), then no process it started survives, trials.csv stops growing, the motor
node's last status has every motor off, and the session folder is free for the run that resumes it."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from touch4d.bus import Node
from touch4d.bus.config import BusConfig
from touch4d.bus.testing import collect, wait_until
from touch4d.messages import MotorStatus
from touch4d.study.lock import claim_session
from touch4d.study.session import STOP_SIGNALS, Stopped, stop_on_signals

# A `study run --simulate --quick` of one participant in its own process, writing its bus to a file once
# the stack runs; with "exception" the run itself fails (an error raised wherever it is) once the test
# writes the file `fail` in its folder.
RUNNER = textwrap.dedent("""
    import signal, sys
    from pathlib import Path
    from touch4d.study.session import SessionOptions, Stopped, run_session

    def ready(bus):
        Path(sys.argv[3]).write_text(bus.to_json())
        if sys.argv[2] == "exception":
            signal.signal(signal.SIGALRM, fail)
            signal.setitimer(signal.ITIMER_REAL, 0.1, 0.1)

    def fail(*_):
        if (Path(sys.argv[1]) / "fail").exists():
            signal.setitimer(signal.ITIMER_REAL, 0)
            raise RuntimeError("the run failed")

    try:
        code = run_session("config/studies/paper.yaml", "P01", sys.argv[1], ["tracker.pace:=0.1"],
                           options=SessionOptions(simulate=True, quick=True, seed=1),
                           echo=lambda line: None, on_ready=ready)
    except Stopped as exc:
        code = exc.code
    sys.exit(code)
""")


def descendants(pid: int) -> set[int]:
    """Every process below `pid` (from /proc's parent links)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parent = int(stat.rpartition(")")[2].split()[1])
            children.setdefault(parent, []).append(int(entry.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except OSError:
        return False
    return state != "Z"


def rows(path: Path) -> int:
    return max(len(path.read_text().splitlines()) - 1, 0) if path.exists() else 0


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=lambda sig: sig.name)
def test_each_stop_signal_raises_stopped_once_then_the_old_handler_is_back(sig):
    before = signal.getsignal(sig)
    caught = []
    with stop_on_signals():
        try:
            signal.raise_signal(sig)
        except Stopped as exc:
            caught.append(exc)
            signal.raise_signal(sig)       # a second signal while the stack stops is ignored
    assert [exc.code for exc in caught] == [128 + sig]
    assert signal.getsignal(sig) is before


WAYS = ["SIGTERM", "exception", "SIGKILL"]   # SIGINT and SIGHUP take SIGTERM's path (the test above)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One run per way out, started together: their stacks start up side by side, not one after another."""
    runners = {}
    try:
        for how in WAYS:
            folder = tmp_path_factory.mktemp(how)
            with open(folder / "run.log", "w") as log:
                runners[how] = folder, subprocess.Popen([sys.executable, "-c", RUNNER, str(folder), how,
                                                         str(folder / "bus.json")], stdout=log,
                                                        stderr=subprocess.STDOUT, start_new_session=True)
        yield runners
    finally:
        for _, runner in runners.values():
            stop(runner, set())


def stop(runner: subprocess.Popen, started: set[int]) -> None:
    """Kill whatever is left of a run and the processes it started."""
    for pid in descendants(runner.pid) | started:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    if runner.poll() is None:
        runner.kill()
    runner.wait()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("how", WAYS)
def test_every_way_study_run_ends_ends_its_stack_with_the_motors_off(runs, how):
    folder, runner = runs[how]
    table = folder / "P01" / "trials.csv"
    bus = folder / "bus.json"
    started: set[int] = set()
    probe = None
    try:
        wait_until(lambda: bus.exists() and bus.stat().st_size, timeout=120)
        probe = Node("test-probe", bus=BusConfig.from_json(bus.read_text()), heartbeat=False)
        status = collect(probe, "motors/status", MotorStatus)
        wait_until(lambda: rows(table) >= 1 and status, timeout=180, spin=probe)   # a session under way
        started = descendants(runner.pid)
        assert len(started) >= 6                    # the launcher and its nodes
        before = len(status)
        if how == "exception":
            (folder / "fail").touch()
        else:
            runner.send_signal(getattr(signal, how))
        code = runner.wait(60)
        assert code == {"exception": 1, "SIGKILL": -signal.SIGKILL}.get(how, 128 + getattr(signal, how, 0))
        wait_until(lambda: not any(alive(p) for p in started), timeout=20)
        written = rows(table)
        time.sleep(1.0)
        assert rows(table) == written               # nothing writes on
        claim_session(folder / "P01").release()     # no writer left: a run again resumes the session
        probe.spin_once(0.5)
        assert len(status) > before
        last = status[-1]
        assert last.duty.size and not last.duty.any()   # the motor node stopped them on its way out
    finally:
        if probe is not None:
            probe.shutdown()
        stop(runner, started)

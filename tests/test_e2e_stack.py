"""The whole system from one command: the demo stack, Ctrl+C at any moment, replay.

Each test runs `touch4d launch` as a process group on free loopback ports, watches the bus from
this process, and checks what the glove got: duties while the hand touched, zero after it left,
zero after a stop, and no process left behind.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.launchfile import load_launch
from touch4d.bus.testing import collect, launch_process, wait_until
from touch4d.log.reader import LogReader
from touch4d.messages import Heartbeat, HandPose, MotorCommand, MotorStatus, decode

REPO = Path(__file__).resolve().parents[1]
HEADLESS = ["renderer.headless:=true"]
# The demo path (config/paths.yaml `demo`) keeps the hand at x = -1.9 before and after the touch;
# the hand is ~0.6 screen units wide, so at x < -1.5 every sample lies outside the screen cube.
OUT_X = -1.5


def group_processes(pgid: int) -> list[int]:
    """Live (non-zombie) processes of a process group."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            found.append(int(stat.parent.name))
    return found


class Watcher:
    """An in-process node on the launch's bus, collecting what the test needs."""

    def __init__(self, bus):
        self.node = Node("e2e-watcher", bus=bus, heartbeat=False)
        self.poses = collect(self.node, "hand/pose", HandPose)
        self.commands = collect(self.node, "tactile/motors", MotorCommand)
        self.status = collect(self.node, "motors/status", MotorStatus)
        self.heartbeats = collect(self.node, "node/heartbeat", Heartbeat)

    def spin_while(self, run, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and run.proc.poll() is None:
            self.node.spin_once(0.05)

    def spin_until_exit(self, run, timeout: float) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and run.proc.poll() is None:
            self.node.spin_once(0.05)
        for _ in range(20):  # what was already queued
            self.node.spin_once(0.01)

    def pids(self) -> set[int]:
        return {hb.pid for hb in self.heartbeats}


@pytest.mark.timeout(120)
def test_demo_runs_headless_and_the_glove_follows_the_hand():
    with launch_process(["--duration", "22", *HEADLESS]) as run:
        watcher = Watcher(run.wait_ready(60))
        try:
            watcher.spin_until_exit(run, 90)
            code = run.proc.wait(10)
        finally:
            watcher.node.shutdown()
        pgid = run.proc.pid
    assert code == 0, run.text
    for role in ("tracker", "scene", "tactile", "motors", "renderer", "monitor"):
        assert f"[{role}]" in run.text, f"{role} printed nothing:\n{run.text}"
    assert "boards 4/4 online" in run.text, run.text  # the monitor's status line

    poses = [p for p in watcher.poses if p.valid]
    status = watcher.status
    # the 22 s include the stack's start, which a loaded machine stretches: a few hundred poses at least
    assert len(poses) > 200 and len(status) > 50, (len(poses), len(status))
    inside = np.array([p.position[0] > OUT_X for p in poses])
    stamps = np.array([p.stamp for p in poses])
    assert inside.any() and (~inside).any(), "the demo path should enter and leave the screen"

    # While the hand is on the hypercube, the glove buzzes.
    touching = [c for c in watcher.commands if c.intensity.max() > 0]
    assert touching, "the tactile node never commanded a motor"
    duties = np.array([s.duty for s in status])
    assert duties.max() > 0.2, "no motor duty reached the boards while the hand touched"

    # After the hand left (every pose for 0.5 s before the status out of the screen), all is off.
    quiet = []
    for s in status:
        recent = (stamps > s.stamp - 0.5) & (stamps <= s.stamp)
        if recent.sum() >= 10 and not inside[recent].any():
            quiet.append(s)
    after_touch = [s for s in quiet if s.stamp > touching[0].stamp]
    assert len(after_touch) >= 5, "the demo path should leave the screen after touching"
    for s in after_touch:
        assert not s.duty.any(), f"motor left on after the hand left: {s.duty}"

    # The last word of the motor node is everything off; nothing is left running.
    assert not status[-1].duty.any()
    assert group_processes(pgid) == []
    assert all(not Path(f"/proc/{pid}").exists() or "Z" in Path(f"/proc/{pid}/stat").read_text().split()[2]
               for pid in watcher.pids())


@pytest.mark.timeout(90)
@pytest.mark.parametrize("moment", [0.3, 1.5, "touching"])
def test_ctrl_c_at_any_moment_leaves_no_process_and_every_motor_off(moment):
    with launch_process(["renderer:=none", "monitor:=none"]) as run:
        if moment != "touching":
            time.sleep(moment)  # while the launcher, then its nodes, are still starting
            watcher = None
        else:
            watcher = Watcher(run.wait_ready(60))
            wait_until(lambda: watcher.node.spin_once(0.05) is not None and any(
                c.intensity.max() > 0 for c in watcher.commands), timeout=40)
        os.killpg(run.proc.pid, signal.SIGINT)  # Ctrl+C in a terminal reaches the whole group
        t0 = time.monotonic()
        if watcher:
            watcher.spin_until_exit(run, 15)
            watcher.node.shutdown()
        code = run.proc.wait(15)
        stopped_in = time.monotonic() - t0
        pgid = run.proc.pid
    # Ctrl+C before the command's own code runs (the interpreter starting, or importing touch4d) ends
    # it by the signal (-SIGINT, perhaps with Python's KeyboardInterrupt traceback): the launcher had
    # said nothing, so no broker and no node had started; from then on a stop is clean and exits 0.
    assert code == 0 or (moment != "touching" and code == -signal.SIGINT and "[launch]" not in run.text), run.text
    assert stopped_in < 5.0, f"stop took {stopped_in:.1f} s"
    assert group_processes(pgid) == [], run.text
    if watcher:
        assert watcher.status, "the motor node never reported"
        assert not watcher.status[-1].duty.any(), "the motor node's last status still had a motor on"
        assert "stop" in run.text.lower()


@pytest.mark.timeout(150)
def test_replay_of_a_recorded_demo_drives_the_motors_with_the_same_commands_and_true_latency(tmp_path):
    live = tmp_path / "live.mcap"
    again = tmp_path / "replayed.mcap"
    with launch_process(["--duration", "16", "renderer:=none", "monitor:=none", "+recorder:=recorder",
                         f"recorder.file:={live}"]) as run:
        assert run.proc.wait(60) == 0, run.text
    # The replay's defaults: fresh stamps (the recorded ones kept in recorded_stamp), so the motor
    # node's stale-command guard lets the glove buzz and the monitor measures this run's latency.
    with launch_process([str(REPO / "launch/replay.yaml"), "--duration", "18", "renderer:=none",
                         f"tracker.file:={live}", "+recorder:=recorder", f"recorder.file:={again}",
                         "recorder.topics:=[tactile/motors,hand/pose,motors/status,motors/trace]"]) as run:
        assert run.proc.wait(60) == 0, run.text

    def messages(path, topic):
        return [decode(record.data) for record in LogReader(str(path)).messages(topics={topic})]

    recorded = {m.source_stamp: m.intensity for m in messages(live, "tactile/motors")}
    live_poses = {m.stamp for m in messages(live, "hand/pose")}
    # A replayed pose names the recorded pose it replays; a command names its pose by source_stamp.
    replayed_poses = {m.source_stamp: m.recorded_stamp for m in messages(again, "hand/pose")}
    assert replayed_poses and set(replayed_poses.values()) <= live_poses
    replayed = {replayed_poses[m.source_stamp]: m.intensity for m in messages(again, "tactile/motors")
                if m.source_stamp in replayed_poses}

    touched = [k for k, v in recorded.items() if v.max() > 0]
    assert len(recorded) > 300 and len(touched) > 50, (len(recorded), len(touched))
    common = sorted(set(recorded) & set(replayed))
    # Both tactile runs skip a pose now and then (latest-only); every pose both handled must match.
    assert len(common) > 0.8 * len(recorded), (len(common), len(recorded))
    same = [np.allclose(recorded[k], replayed[k], atol=1e-9) for k in common]
    assert np.mean(same) > 0.97, f"{np.mean(same):.3f} of the commands equal"
    for k in common:
        np.testing.assert_allclose(recorded[k], replayed[k], atol=0.05)
    assert sum(recorded[k].max() > 0 for k in common) > 50

    # The replayed session drives the motors, and latency is that of this run, not the log's age.
    assert max(s.duty.max() for s in messages(again, "motors/status")) > 0.2
    traces = messages(again, "motors/trace")
    latencies = np.concatenate([t.frame_times - t.source_stamps for t in traces])
    # enough traced commands to judge (a loaded machine traces fewer in the fixed 18 s)
    assert len(latencies) >= 50 and 0 <= latencies.min() and latencies.max() < 1.0, latencies.max()
    p99s = [float(v) for v in re.findall(r"pose->CAN p50 [0-9.]+ ms p99 ([0-9.]+) ms", run.text)]
    assert p99s and max(p99s) < 1000.0, p99s


def test_every_launch_file_loads_and_the_two_machine_configs_parse(tmp_path):
    for path in sorted((REPO / "launch").glob("*.yaml")):
        assert load_launch(path), path
    from touch4d.bus.config import load_bus_config

    for name in ("bus-vive-pc.yaml", "bus-vive-pi.yaml"):
        shutil.copy(REPO / "config" / name, tmp_path / name)
    for key in ("broker", "pc", "pi"):
        subprocess.run([sys.executable, "-m", "touch4d.cli", "bus", "keygen", key, "--dir", str(tmp_path / "keys")],
                       check=True, capture_output=True)
    (tmp_path / "keys" / "clients").mkdir()
    for key in ("pc", "pi"):
        shutil.copy(tmp_path / "keys" / f"{key}.key", tmp_path / "keys" / "clients" / f"{key}.key")
    pc = load_bus_config(tmp_path / "bus-vive-pc.yaml")
    pi = load_bus_config(tmp_path / "bus-vive-pi.yaml")
    assert pc.curve is not None and pi.curve is not None

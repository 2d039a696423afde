"""The disk fills while recording: the recorder says so at once, naming the file and how to recover
it; the part written before is readable (`touch4d log recover`); the rest of the stack keeps
running. The disk is a 1 MB tmpfs where this machine lets the test mount one (root), else the
recorder's file size limit (RLIMIT_FSIZE: the same failed write, as EFBIG)."""
from __future__ import annotations

import resource
import subprocess
import sys
import time

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.testing import collect, launch_process, wait_until
from touch4d.log.reader import LogReader
from touch4d.messages import HandPose, Heartbeat, TactileField, decode

pytestmark = pytest.mark.timeout(120)
LIMIT = 1 << 20
N = 1000   # samples per field: ~50 kB of random numbers per message, which zstd cannot shrink


@pytest.fixture
def small_disk(tmp_path):
    """(folder on a 1 MB disk, or None when the recorder's file size is to be limited instead)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={LIMIT}", "tmpfs", str(disk)],
                             capture_output=True).returncode == 0
    try:
        yield disk, mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(disk)], check=False)


def field(i: int, rng) -> TactileField:
    return TactileField(positions=rng.random((N, 3)), l=rng.random(N), s=np.full(N, float(i)), h=rng.random(N),
                        alpha=3.0, beta=0.5, gamma=1.0)


def test_a_full_disk_stops_the_recorder_with_a_clear_error_and_the_log_before_it_is_recoverable(small_disk, tmp_path):
    disk, mounted = small_disk
    log = disk / "rec.mcap"
    launch = tmp_path / "l.yaml"
    launch.write_text("nodes:\n"
                      f"  recorder: {{node: recorder, params: {{file: {log}, topics: [big/field, example/pose]}}}}\n"
                      "  talker: {node: example_talker, params: {rate: 50.0}}\n")
    with launch_process([str(launch)]) as run:
        with Node("probe", bus=run.bus, heartbeat=False) as probe:
            poses = collect(probe, "example/pose", HandPose)
            beats = collect(probe, "node/heartbeat", Heartbeat)
            run.wait_for_line(r"\[recorder\].*recording", timeout=60)
            if not mounted:
                assert wait_until(lambda: (probe.spin_once(0.01), any(b.node == "recorder" for b in beats))[-1], 30)
                pid = next(b.pid for b in beats if b.node == "recorder")
                resource.prlimit(pid, resource.RLIMIT_FSIZE, (LIMIT, LIMIT))
            fields = probe.create_publisher("big/field", TactileField)
            rng = np.random.default_rng(7)
            sent = 0
            deadline = time.monotonic() + 60
            while "recording stopped" not in run.text and time.monotonic() < deadline:
                fields.publish(field(sent, rng))
                sent += 1
                probe.spin_once(0.01)
            error = run.wait_for_line(r"\[recorder\].*ERROR", timeout=10)
            assert f"writing {log}: no room left" in error and f"`touch4d log recover {log}`" in error, error
            # The rest of the stack goes on: the talker's poses keep arriving, the launch keeps running.
            before = len(poses)
            wait_until(lambda: (probe.spin_once(0.01), len(poses) >= before + 25)[-1], timeout=20)
            assert len(poses) >= before + 25 and run.proc.poll() is None
        assert run.stop() == 0
    # Its end-of-recording report went out whole (no traceback from a half-written file).
    assert "Traceback" not in run.text and "recorded " in run.text and "[recorder] " in run.text
    # The part written before the disk filled: a prefix of what was sent, every message whole.
    out = tmp_path / "recovered.mcap"
    done = subprocess.run([sys.executable, "-m", "touch4d.cli", "log", "recover", str(log), "-o", str(out)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    got = [decode(m.data, TactileField) for m in LogReader(out).messages({"big/field"})]
    assert 5 <= len(got) < sent
    assert [int(m.s[0]) for m in got] == list(range(len(got)))
    assert all(np.all(m.s == m.s[0]) and m.positions.shape == (N, 3) for m in got)

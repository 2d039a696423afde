"""`touch4d record` on a live bus: zero loss at 10k msg/s, crash safety under SIGKILL, gap reports."""
from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from touch4d.bus.broker import Broker
from touch4d.bus.config import ENV_VAR, BusConfig
from touch4d.errors import Touch4dError
from touch4d.log.reader import LogReader
from touch4d.log.recorder import Recorder
from touch4d.log.replay import BusSender
from touch4d.messages import HandPose, encode


@pytest.fixture
def bus():
    broker = Broker(BusConfig(pub_port=0, sub_port=0, hwm=10000))
    cfg = broker.start()
    try:
        yield cfg
    finally:
        broker.stop()


class Proc:
    """A `touch4d` sub-command in a child process, killed at the end whatever happens."""

    def __init__(self, cfg: BusConfig, *args: str):
        env = dict(os.environ, **{ENV_VAR: cfg.to_json()})
        self.p = subprocess.Popen([sys.executable, "-m", "touch4d.cli", *args], env=env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def wait_for_stderr(self, text: str, timeout: float = 30.0) -> str:
        seen = ""
        deadline = time.monotonic() + timeout
        while text not in seen:
            left = deadline - time.monotonic()
            assert left > 0 and self.p.poll() is None, f"never printed {text!r}; got {seen!r}"
            if select.select([self.p.stderr], [], [], min(left, 0.5))[0]:
                seen += self.p.stderr.readline()
        return seen

    def finish(self, sig=signal.SIGINT, timeout: float = 30.0) -> tuple[int, str, str]:
        self.p.send_signal(sig)
        out, err = self.p.communicate(timeout=timeout)
        return self.p.returncode, out, err

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.communicate()


@pytest.fixture
def procs():
    started: list[Proc] = []
    yield started
    for proc in started:
        proc.kill()


def poses(n: int, skip=()) -> list[bytes]:
    return [encode(HandPose(position=np.array([i * 1e-3, 0.0, 0.5]), orientation=np.array([0.0, 0.0, 0.0, 1.0]),
                            valid=True, stamp=time.time(), seq=i,
                            source_stamp=time.time())) for i in range(n) if i not in skip]


def paced_send(send, payloads: list[bytes], rate: float, topic: str = "hand/pose") -> list[float]:
    """Send at `rate` msg/s in 2 ms bursts; returns the wall-clock send time of each payload."""
    sent_at = []
    t0 = time.perf_counter()
    burst = max(1, int(rate * 0.002))
    for start in range(0, len(payloads), burst):
        due = t0 + start / rate
        delay = due - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        now = time.time()
        for payload in payloads[start:start + burst]:
            send(topic, payload)
            sent_at.append(now)
    return sent_at


def record_while_sending(bus, procs, path, payloads: list[bytes], rate: float) -> tuple[int, str, str]:
    """`touch4d record -o PATH hand/pose` while `payloads` go out at `rate`; stopped with Ctrl+C."""
    rec = Proc(bus, "record", "-o", str(path), "hand/pose")
    procs.append(rec)
    rec.wait_for_stderr("recording hand/pose")
    sender = BusSender(bus)
    try:
        paced_send(sender, payloads, rate)
    finally:
        sender.close()
    time.sleep(1.0)
    return rec.finish(signal.SIGINT)


@pytest.mark.timeout(120)
def test_10k_messages_per_second_for_5_s_recorded_without_loss(bus, procs, tmp_path):
    path = tmp_path / "fast.mcap"
    payloads = poses(50_000)
    code, out, err = record_while_sending(bus, procs, path, payloads, 10_000)
    assert code == 0, err
    assert "recorded 50000 messages" in out and "seq gaps: none" in out
    got = list(LogReader(path).messages())
    assert len(got) == 50_000
    assert [m.data for m in got] == payloads  # every message, in order, bytes as sent


@pytest.mark.timeout(120)
def test_sigkilled_recorder_leaves_everything_older_than_1_s_recoverable(bus, procs, tmp_path):
    path = tmp_path / "killed.mcap"
    rec = Proc(bus, "record", "-o", str(path))
    procs.append(rec)
    rec.wait_for_stderr("recording all topics")
    payloads = poses(3000)
    sender = BusSender(bus)
    try:
        sent_at = paced_send(sender, payloads, 1000)  # 3 s
    finally:
        sender.close()
    killed_at = time.time()
    rec.p.send_signal(signal.SIGKILL)
    rec.p.communicate(timeout=30)
    with pytest.raises(Exception, match="truncated"):
        LogReader(path)
    got = [m.data for m in LogReader(path, recover=True).messages()]
    old = [p for p, t in zip(payloads, sent_at) if t < killed_at - 1.0]
    assert len(old) > 1500
    assert got[:len(old)] == old
    assert got == payloads[:len(got)]  # what is there is in order, nothing garbled


@pytest.mark.timeout(60)
def test_gaps_and_missing_topics_reported_on_sigterm(bus, procs, tmp_path):
    path = tmp_path / "gaps.mcap"
    rec = Proc(bus, "record", "-o", str(path), "hand/pose", "controller/state")
    procs.append(rec)
    rec.wait_for_stderr("recording hand/pose, controller/state")
    sender = BusSender(bus)
    try:
        for payload in poses(20, skip={3, 4, 5, 12}):
            sender("hand/pose", payload)
        sender("hand/pose_other", poses(1)[0])  # shares the prefix of a recorded topic: not recorded
    finally:
        sender.close()
    time.sleep(1.0)
    code, out, err = rec.finish(signal.SIGTERM)
    assert code == 0, err
    assert "hand/pose: 16, 4 lost (seq gaps)" in out
    assert "seq gaps: 4 message(s) lost before the recorder" in out
    assert "no messages on: controller/state" in out
    reader = LogReader(path)
    assert reader.topics() == {"hand/pose": "HandPose"}
    assert reader.metadata["touch4d.recording"]["lost"] == '{"hand/pose": 4}'


@pytest.mark.timeout(60)
def test_record_duration_stops_by_itself_and_bad_durations_are_rejected(bus, tmp_path, monkeypatch, capsys):
    from touch4d.cli import main as touch4d_main
    monkeypatch.setenv(ENV_VAR, bus.to_json())
    path = tmp_path / "short.mcap"
    switch = sys.getswitchinterval()
    try:
        assert touch4d_main(["record", "-o", str(path), "--duration", "0.5"]) == 0
    finally:
        sys.setswitchinterval(switch)   # the record command tunes it for its own process
    reader = LogReader(path)
    list(reader.records())   # metadata is read along with the records
    assert reader.complete and float(reader.metadata["touch4d.recording"]["duration"]) >= 0.5
    for bad in ("0", "-1", "nan", "inf"):
        assert touch4d_main(["record", "-o", str(tmp_path / "bad.mcap"), "--duration", bad]) == 2
        assert "--duration must be a finite number of seconds > 0" in capsys.readouterr().err


def reported_bytes(text: str, what: str) -> float:
    """The size printed before `what` (e.g. "on disk"), in bytes: "512 B", "6.1 kB", "0.51 MB", "1.02 GB"."""
    match = re.search(rf"([0-9.]+) (B|kB|MB|GB) {what}", text)
    assert match, f"no size {what!r} in {text!r}"
    return float(match.group(1)) * {"B": 1, "kB": 1e3, "MB": 1e6, "GB": 1e9}[match.group(2)]


@pytest.mark.timeout(60)
def test_report_gives_the_bytes_on_disk_and_the_uncompressed_payload_separately(bus, procs, tmp_path):
    path = tmp_path / "size.mcap"
    # Poses of a hand at rest compress well: the file is much smaller than the messages in it.
    payloads = [encode(HandPose(position=np.array([0.1, 0.0, 0.5]), orientation=np.array([0.0, 0.0, 0.0, 1.0]),
                                valid=True, stamp=1700000000.0, seq=i, source_stamp=1700000000.0))
                for i in range(3000)]
    code, out, err = record_while_sending(bus, procs, path, payloads, 5000)
    assert code == 0, err
    assert "recorded 3000 messages" in out
    on_disk, payload = os.path.getsize(path), sum(map(len, payloads))
    assert on_disk < payload / 3
    assert reported_bytes(out, "on disk") == pytest.approx(on_disk, rel=0.01)
    assert reported_bytes(out, "of messages") == pytest.approx(payload, rel=0.01)


def test_no_broker_is_a_clear_error(tmp_path):
    dead = BusConfig(pub_port=1, sub_port=1)
    with pytest.raises(Touch4dError, match="no bus broker forwarded messages at tcp://127.0.0.1:1"):
        Recorder(dead, tmp_path / "none.mcap").start(timeout=0.3)
    assert list(tmp_path.iterdir()) == []   # no empty log left behind (`touch4d record` exits 2, no file)


def test_unwritable_output_is_a_clear_error(tmp_path):
    for path in ("/dev/full", str(tmp_path / "no" / "such" / "dir.mcap")):
        with pytest.raises(Touch4dError, match=f"{path}: cannot write a log here"):
            Recorder(BusConfig(pub_port=1, sub_port=1), path).start(timeout=0.3)

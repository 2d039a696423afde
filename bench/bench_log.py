"""Log benchmarks: recording throughput (messages/s, MB/s) beside the bare mcap writer, same run.

1. file layer: `LogWriter.write_many` (the recorder's path: header peek, seq gaps, channel per topic,
   zstd chunks) and `LogWriter.write` against `mcap.writer.Writer.add_message` writing the same
   payloads to the same kind of file; CPU seconds of the writing thread (a loaded machine steals
   wall time from both sides unevenly), in rounds that run the three back to back, the ratio the
   median of the rounds' ratios;
2. end to end: messages published as fast as one process can through a broker into a `Recorder`
   (subscriber thread + writer thread), against the same bare mcap writer baseline;
3. replay timing: a 250 Hz log of 2 s replayed through a broker into a recorder; the error of each
   inter-message interval (p50, p99; target p99 < 2 ms), beside a plain sleep-then-send loop over
   the same schedule in the same run;
4. replay start-up: a ~1 GB log (smaller when the disk is short) built in a temporary folder; the
   time from opening it to the first message sent (target < 1 s), for `touch4d replay` and for the
   replay node (the tracker role), beside the bare mcap reader's first message of the same file.
The mix is the live stack's: hand poses, tactile fields (242 samples), motor commands (30 motors).
Run: .venv/bin/python bench/bench_log.py
"""
from __future__ import annotations

import os
import shutil
import statistics
import sys
import tempfile
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from touch4d.bus.testing import running_broker
from touch4d.log.recorder import Recorder
from touch4d.log.reader import LogReader
from touch4d.log.replay import BusSender, Plan, Replayer, ReplayOptions
from touch4d.log.writer import LogWriter
from touch4d.messages import HandPose, MotorCommand, TactileField, encode

N = 50_000


def mix(n: int) -> list[tuple[str, bytes]]:
    """The stack's topics in proportion: per hand pose, one tactile field and one motor command."""
    rng = np.random.default_rng(0)
    out = []
    for i in range(n // 3):
        stamp = time.time()
        out.append(("hand/pose", encode(HandPose(position=rng.uniform(-1, 1, 3), valid=True, stamp=stamp, seq=i,
                                                 orientation=np.array([0.0, 0.0, 0.0, 1.0]), source_stamp=stamp))))
        out.append(("tactile/field", encode(TactileField(positions=rng.uniform(-1, 1, (242, 3)), l=rng.uniform(0, 1, 242),
                                                         s=rng.uniform(0, 1, 242), h=rng.uniform(0, 1, 242), alpha=1.0,
                                                         beta=0.5, gamma=1.0, stamp=stamp, seq=i, source_stamp=stamp))))
        out.append(("tactile/motors", encode(MotorCommand(names=[f"m{k}" for k in range(30)], intensity=rng.uniform(0, 1, 30),
                                                          stamp=stamp, seq=i, source_stamp=stamp))))
    return out


def bare_mcap(path: str, messages: list[tuple[str, bytes]]) -> tuple[float, float]:
    """Baseline: the mcap writer alone, one channel per topic, no header peek; (CPU, wall) seconds."""
    t0, wall0 = time.thread_time(), time.perf_counter()
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start()
        schema = w.register_schema("any", "jsonschema", b"{}")
        channels: dict[str, int] = {}
        for k, (topic, payload) in enumerate(messages):
            channel = channels.get(topic) or channels.setdefault(topic, w.register_channel(topic, "msgpack", schema))
            now = time.time_ns()
            w.add_message(channel, log_time=now, publish_time=now, sequence=k, data=payload)
        w.finish()
    return time.thread_time() - t0, time.perf_counter() - wall0


def log_writer(path: str, messages: list[tuple[str, bytes]], batch: int) -> float:
    """`LogWriter.write_many` in batches as the recorder's writer thread calls it (batch 1: `write`)."""
    t0 = time.thread_time()
    w = LogWriter(path)
    if batch == 1:
        for topic, payload in messages:
            w.write(topic, payload, time.time_ns())
    else:
        for start in range(0, len(messages), batch):
            w.write_many((topic, payload, time.time_ns()) for topic, payload in messages[start:start + batch])
    w.close()
    return time.thread_time() - t0


def recorder_end_to_end(path: str, messages: list[tuple[str, bytes]]) -> float:
    """Seconds from the first publish until the recorder has written every message and closed the file."""
    with running_broker() as bus:
        recorder = Recorder(bus, path)
        recorder.start()
        sender = BusSender(bus)
        t0 = time.perf_counter()
        for topic, payload in messages:
            sender(topic, payload)
        deadline = time.monotonic() + 120
        while recorder.received < len(messages) and time.monotonic() < deadline:
            time.sleep(0.005)
        report = recorder.stop()
        elapsed = time.perf_counter() - t0
        sender.close()
    if report.total != len(messages):
        sys.exit(f"recorder lost messages: {report.total} of {len(messages)}")
    return elapsed


def replay_timing(tmp: str, plain: bool) -> tuple[float, float]:
    """(p50, p99) seconds of inter-message timing error, replaying a 250 Hz hand-pose log once."""
    log, out = os.path.join(tmp, "timing.mcap"), os.path.join(tmp, f"timing-out-{plain}.mcap")
    times = [1_700_000_000_000_000_000 + i * 4_000_000 for i in range(500)]
    with LogWriter(log) as w:
        for i, t in enumerate(times):
            w.write("hand/pose", encode(HandPose(position=np.array([i * 1e-3, 0.0, 0.5]), valid=True, seq=i)), t)
    with running_broker() as bus:
        recorder = Recorder(bus, out)
        recorder.start()
        sender = BusSender(bus)
        if plain:
            payloads = [m.data for m in LogReader(log).messages()]
            t0 = time.perf_counter()
            for t, payload in zip(times, payloads):
                delay = t0 + (t - times[0]) / 1e9 - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                sender("hand/pose", payload)
        else:
            reader, options = LogReader(log), ReplayOptions()
            Replayer(reader, Plan(reader, options), options, sender).run()
        time.sleep(0.2)
        recorder.stop()
        sender.close()
    got = np.diff([m.log_time for m in LogReader(out).messages()]) / 1e9
    error = np.abs(got - 0.004)
    return tuple(np.percentile(error, [50, 99]))


def big_log(path: str, target: int) -> int:
    """A log of about `target` bytes of the stack's mix at 1 kHz (payloads repeat; they barely compress)."""
    messages = mix(3000)
    t = 1_700_000_000_000_000_000
    with LogWriter(path) as w:
        while w.bytes < target:
            for topic, payload in messages:
                w.write(topic, payload, t)
                t += 1_000_000
    return os.path.getsize(path)


def first_message(path: str, node: bool) -> float:
    """Seconds from opening the log to the first message handed to the sender, as `touch4d replay`
    does it (or the replay node, which also picks the tracker topics the log has)."""
    box: dict = {}

    def send(topic: str, payload: bytes) -> None:
        box.setdefault("t", time.perf_counter())
        replayer.stop()

    t0 = time.perf_counter()
    reader = LogReader(path)
    options = ReplayOptions(realtime=False)
    if node:
        available = reader.topics()
        options.topics = [t for t in ("hand/pose", "controller/state") if t in available]
    replayer = Replayer(reader, Plan(reader, options), options, send)
    replayer.run()
    return box["t"] - t0


def bare_first_message(path: str) -> float:
    """Baseline: the mcap library's indexed reader, opening the file and reading its first message."""
    t0 = time.perf_counter()
    with open(path, "rb") as f:
        next(iter(make_reader(f).iter_messages()))
    return time.perf_counter() - t0


def main() -> None:
    messages = mix(N)
    n = len(messages)
    mb = sum(len(p) for _, p in messages) / 1e6
    print(f"{n} messages, {mb:.1f} MB of payload (hand/pose, tactile/field with 242 samples, tactile/motors)")
    with tempfile.TemporaryDirectory() as tmp:
        # Rounds on a slice of the mix, each running the three writers back to back in a rotating
        # order: the ratio of each round is taken under one load, and the median of those is kept.
        part = messages[:12_000]
        part_mb = sum(len(p) for _, p in part) / 1e6
        times: dict[str, list[float]] = {"bare": [], "bare wall": [], "many": [], "one": []}
        for i in range(11):
            for which in ("bare", "many", "one")[i % 3:] + ("bare", "many", "one")[:i % 3]:
                path = os.path.join(tmp, f"{which}.mcap")
                if which == "bare":
                    cpu, wall = bare_mcap(path, part)
                    times["bare"].append(cpu)
                    times["bare wall"].append(wall * len(messages) / len(part))
                else:
                    times[which].append(log_writer(path, part, 2000 if which == "many" else 1))
        e2e = min(recorder_end_to_end(os.path.join(tmp, f"rec{i}.mcap"), messages) for i in range(2))
    rows = [("bare mcap Writer.add_message (baseline)", "bare"), ("LogWriter.write_many (recorder)", "many"),
            ("LogWriter.write, one at a time", "one")]
    for name, key in rows:
        best = min(times[key])
        ratio = statistics.median(b / t for b, t in zip(times["bare"], times[key]))
        print(f"{name:<42} {len(part) / best:>9.0f} msg/s  {part_mb / best:>7.1f} MB/s  "
              f"ratio to baseline {ratio:.2f}  (CPU time; median of 11 rounds)")
    base_wall = min(times["bare wall"])
    print(f"{'Recorder via broker, end to end':<42} {n / e2e:>9.0f} msg/s  {mb / e2e:>7.1f} MB/s  "
          f"ratio to baseline {base_wall / e2e:.2f}  (wall time, both; sender, broker and recorder in one process)")
    with tempfile.TemporaryDirectory() as tmp:
        plain = replay_timing(tmp, plain=True)
        ours = replay_timing(tmp, plain=False)
    for name, (p50, p99) in (("plain sleep-then-send loop (baseline)", plain), ("Replayer", ours)):
        print(f"{name:<42} timing error p50 {p50 * 1e3:6.3f} ms  p99 {p99 * 1e3:6.3f} ms  "
              f"p99 ratio to baseline {p99 / plain[1]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        target = min(1 << 30, int(shutil.disk_usage(tmp).free * 0.4))
        path = os.path.join(tmp, "big.mcap")
        size = big_log(path, target)
        base = min(bare_first_message(path) for _ in range(3))
        rows = [("bare mcap reader, first message (baseline)", base),
                ("touch4d replay, first message", min(first_message(path, False) for _ in range(2))),
                ("replay node, first message", min(first_message(path, True) for _ in range(2)))]
    print(f"replay start-up on a {size / 1e9:.2f} GB log (target: first message < 1 s)")
    for name, seconds in rows:
        print(f"{name:<42} {seconds * 1e3:9.1f} ms  ratio to baseline {seconds / base:.1f}")


if __name__ == "__main__":
    main()

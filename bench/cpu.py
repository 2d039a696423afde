"""CPU time of processes and their threads, from /proc (Linux), for the benchmarks."""
from __future__ import annotations

import os
from pathlib import Path

CLK_TCK = os.sysconf("SC_CLK_TCK")


def _seconds(stat: str) -> float:
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK   # utime + stime


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (all its threads), seconds."""
    return _seconds(Path(f"/proc/{pid}/stat").read_text())


def thread_seconds(pid: int) -> dict[str, float]:
    """utime + stime of a process's threads, seconds: "main" (the Python main thread), "zmq" (the
    ZeroMQ I/O threads) and "other" (the other threads, e.g. a board emulator's)."""
    out = {"main": 0.0, "zmq": 0.0, "other": 0.0}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            seconds = _seconds((task / "stat").read_text())
        except OSError:   # a thread that ended meanwhile
            continue
        kind = "main" if task.name == str(pid) else "zmq" if name.startswith("ZMQbg") else "other"
        out[kind] += seconds
    return out

"""One writer per session folder: an exclusive `flock` on its `.lock` file, held while a run writes
the folder. The kernel drops the lock when the holding process ends, however it ends, so a dead
writer never holds a folder; the file keeps the holder's pid and command for the refusal."""
from __future__ import annotations

import fcntl
import json
import os
import sys
import time
from pathlib import Path

from .store import SessionError

LOCK = ".lock"


class SessionLock:
    """`with SessionLock(folder):` the folder's one writer, or a SessionError that names the folder and
    the process writing it. Not inherited by child processes (the fd is close-on-exec)."""

    def __init__(self, directory):
        self.directory = Path(directory)
        self.path = self.directory / LOCK
        self._fd: int | None = None

    def acquire(self) -> "SessionLock":
        self.directory.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise SessionError(f"{self.directory}: another run writes this session folder ({holder}); one writer "
                               "at a time: wait for it to end or stop it, or use another --out") from None
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "command": " ".join(sys.argv),
                                 "since": time.strftime("%Y-%m-%dT%H:%M:%S%z")}).encode() + b"\n")
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)          # closing the only descriptor drops the lock
            self._fd = None

    def __enter__(self) -> "SessionLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _holder(fd: int) -> str:
    """The locking process as its lock file says: pid, command and since when."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        info = {}
    if not info.get("pid"):
        return "a process that has not written its name yet"
    return f"pid {info['pid']}: {info.get('command', '?')}, since {info.get('since', '?')}"

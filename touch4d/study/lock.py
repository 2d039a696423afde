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
WRITER_ENV = "TOUCH4D_SESSION_WRITER"   # pid of the run that holds the lock for the stack it launched


class SessionLock:
    """`with SessionLock(folder):` the folder's one writer, or a SessionError that names the folder and
    the process writing it. Not inherited by child processes (the fd is close-on-exec)."""

    def __init__(self, directory):
        self.directory = Path(directory)
        self.path = self.directory / LOCK
        self._fd: int | None = None

    def acquire(self, holder_ok: int | None = None) -> "SessionLock":
        """Take the lock, or raise SessionError naming its holder. `holder_ok`: a pid whose lock is
        this process's too (the study run that launched this node): then nothing is taken."""
        self.directory.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _info(fd)
            os.close(fd)
            if holder_ok is not None and info.get("pid") == holder_ok:
                return self
            holder = _holder(info)
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


def writer_pid() -> int | None:
    """The pid of the run that launched this process and holds its session folder (WRITER_ENV), if any."""
    text = os.environ.get(WRITER_ENV, "")
    return int(text) if text.isdigit() else None


def _info(fd: int) -> dict:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _holder(info: dict) -> str:
    """The locking process as its lock file says: pid, command and since when."""
    if not info.get("pid"):
        return "a process that has not written its name yet"
    return f"pid {info['pid']}: {info.get('command', '?')}, since {info.get('since', '?')}"

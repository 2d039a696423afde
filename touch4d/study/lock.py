"""One writer per session folder, with exclusive `flock`s the kernel drops when their process ends,
however it ends (a dead writer never holds a folder); each lock file keeps its holder's pid and
command for the refusal.

- `.lock`: the run writing the folder (`touch4d study run`, an offline simulation) holds it for
  its whole run: a second run is refused at once.
- `.serve`: the study server serving an output folder (`touch4d study serve`) holds it there: a second
  server on the same folder is refused, naming the first.
- `.writer`: the study node appending trials.csv holds it. It outlives a run killed outright
  (SIGKILL) whose stack ran on: `claim_session` checks it is free, so a new run is refused, naming
  the node still writing, rather than starting a second writer.

A folder the run's lock created and left empty (a refused run) is removed with its lock files.
"""
from __future__ import annotations

import fcntl
import json
import os
import sys
import time
from pathlib import Path

from .store import SessionError

LOCK = ".lock"
WRITER = ".writer"
SERVE = ".serve"
# What the holder of each lock does, for a refusal; and what to do about it.
DOING = {LOCK: "writes this session folder", WRITER: "writes this session's trials.csv",
         SERVE: "serves this folder (touch4d study serve)"}
ADVICE = {SERVE: "one server per folder: stop it, or serve another --out"}


class SessionLock:
    """`with SessionLock(folder):` holds the folder's lock file `name`, or raises a SessionError that
    names the folder and the process holding it. Not inherited by child processes (close-on-exec)."""

    def __init__(self, directory, name: str = LOCK, mode: int = 0o777):
        self.directory = Path(directory)
        self.mode = mode          # of the folder, when the lock makes it (less the umask)
        self.path = self.directory / name
        self._fd: int | None = None
        self._created = False     # this lock made the folder: it removes it on release if nothing else came

    def acquire(self) -> "SessionLock":
        while True:
            created = not self.directory.exists()
            self.directory.mkdir(mode=self.mode, parents=True, exist_ok=True)
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except FileNotFoundError:
                continue    # the folder went (an empty one, released) between mkdir and open
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(fd)
                os.close(fd)
                advice = ADVICE.get(self.path.name, "one writer at a time: wait for it to end or stop it, "
                                                                    "or use another --out")
                raise SessionError(f"{self.directory}: another process {DOING[self.path.name]} ({holder}); "
                                   f"{advice}") from None
            if _is_file(fd, self.path):
                break
            os.close(fd)    # its holder removed it (and its empty folder) between our open and flock: anew
        self._created = created
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"pid": os.getpid(), "command": " ".join(sys.argv),
                                 "since": time.strftime("%Y-%m-%dT%H:%M:%S%z")}).encode() + b"\n")
        self._fd = fd
        return self

    @property
    def created(self) -> bool:
        """Whether this lock made its folder (a refused start removes what it made)."""
        return self._created

    def release(self) -> None:
        if self._fd is not None:
            if self._created and self.path.name in (LOCK, SERVE):
                _remove_if_empty(self.directory)     # still holding the lock: no other run is in there
            os.close(self._fd)          # closing the only descriptor drops the lock
            self._fd = None

    def __enter__(self) -> "SessionLock":
        return self if self._fd is not None else self.acquire()     # claim_session's lock is already held

    def __exit__(self, *exc) -> None:
        self.release()


def claim_session(directory) -> SessionLock:
    """The run's hold on a session folder: its `.lock`, taken, after checking that no study node
    still writes there (`.writer` free). Release it (or use it as a context manager) when the run ends."""
    run = SessionLock(directory).acquire()
    try:
        SessionLock(directory, WRITER).acquire().release()
    except SessionError:
        run.release()
        raise
    return run


def _is_file(fd: int, path: Path) -> bool:
    """Whether the open file `fd` is still the file at `path` (not one removed since it was opened)."""
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False


def _remove_if_empty(directory: Path) -> None:
    """Remove a session folder that holds nothing but its lock files (a refused run made it)."""
    if {p.name for p in directory.iterdir()} - {LOCK, WRITER, SERVE}:
        return
    writer = SessionLock(directory, WRITER)
    try:
        writer.acquire()
    except SessionError:
        return                                   # a study node writes there after all
    try:
        for name in (WRITER, LOCK, SERVE):
            (directory / name).unlink(missing_ok=True)
    finally:
        writer.release()
    try:
        directory.rmdir()
    except OSError:
        pass                                     # something came in meanwhile: it stays


def _holder(fd: int) -> str:
    """The locking process as its lock file says: pid, command and since when."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        info = {}
    if not isinstance(info, dict) or not info.get("pid"):
        return "a process that has not written its name yet"
    return f"pid {info['pid']}: {info.get('command', '?')}, since {info.get('since', '?')}"

"""The bus's log files, written for clients they do not trust (a study's participants): each capped
in size (LOG_CAP, one older file kept) and opened without following a symlink. A container's group
writes its log through `GroupLog`; the pool copies each container's output with `CappedLog`.
"""
from __future__ import annotations

import logging
import logging.handlers
import os
import threading
from pathlib import Path

log = logging.getLogger("container")

# bytes of one log file (a container's NAME.log, a group's `log`): past it the file becomes NAME.log.1
# (the one before goes) and a new one begins, so a log costs at most twice this of disk, whatever a
# client makes a node write.
LOG_CAP = 8 << 20


def open_log(path, mode: str = "a", **kwargs):
    """`path` opened to append to ("a" or "ab"), created 0600, never through a symlink (OSError ELOOP:
    one planted there, say in a participant's folder, would have the server write where it points)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    try:
        return os.fdopen(fd, mode, **kwargs)
    except BaseException:
        os.close(fd)
        raise


class GroupLog(logging.handlers.RotatingFileHandler):
    """A group's log lines (its `log` file): capped at LOG_CAP, one older file kept, opened by open_log."""

    def __init__(self, path):
        super().__init__(path, maxBytes=LOG_CAP, backupCount=1, encoding="utf-8")

    def _open(self):
        return open_log(self.baseFilename, "a", encoding=self.encoding)


class CappedLog:
    """A container's output: what its pipe carries, copied into `path` by a thread of its own until
    the file holds `cap` bytes; then it becomes PATH.1 (the one before goes) and a new one begins."""

    def __init__(self, path, cap: int | None = None):
        self.path, self.cap = Path(path), LOG_CAP if cap is None else cap
        self.file = open_log(self.path, "ab")
        self.size = os.fstat(self.file.fileno()).st_size
        self.thread: threading.Thread | None = None

    def follow(self, pipe) -> None:
        """Copy what `pipe` carries until its end (the container and whatever inherited it exited)."""
        self.thread = threading.Thread(target=self._copy, args=(pipe,), name=f"log {self.path.name}", daemon=True)
        self.thread.start()

    def _copy(self, pipe) -> None:
        try:
            while chunk := os.read(pipe.fileno(), 1 << 16):
                chunk = chunk[-self.cap:]   # one read over the cap: its end kept
                if self.size and self.size + len(chunk) > self.cap:
                    self.file.close()
                    os.replace(self.path, self.path.with_name(self.path.name + ".1"))
                    self.file, self.size = open_log(self.path, "ab"), 0
                self.file.write(chunk)
                self.file.flush()
                self.size += len(chunk)
        except (OSError, ValueError) as exc:   # the file gone, or closed by close() after its wait
            log.error("%s: no longer written: %s", self.path, exc)
        finally:
            pipe.close()

    def close(self, timeout: float = 5.0) -> None:
        if self.thread is not None:
            self.thread.join(timeout)
        self.file.close()

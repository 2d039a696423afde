"""Files written whole or not at all, and never through a planted symlink: a new file beside the
target (O_EXCL | O_NOFOLLOW, under a random name, created with its final mode, so no moment exists
where others may read it), flushed to disk, then renamed over the target (`os.replace` replaces a
symlink itself, never the file it points to), and the folder flushed so the rename survives a crash.
A reader sees the old file or the new one, never half of either.
"""
from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path


def write_atomic(path, data: bytes | str, mode: int | None = None, *, durable: bool = True) -> None:
    """Replace `path` with `data`; `mode` None keeps the permissions of the file replaced (0644 for a new one).
    durable=False skips the two fsyncs (the file still appears whole; a crash may lose it): for output
    that is cheap to make again and written often, such as rendered frames."""
    path = Path(path)
    if mode is None:
        try:
            mode = stat.S_IMODE(os.lstat(path).st_mode)
        except FileNotFoundError:
            mode = 0o644
    if isinstance(data, str):
        data = data.encode()
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(8)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), mode)   # the umask may have narrowed it
            f.write(data)
            f.flush()
            if durable:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        fsync_dir(path.parent)


def fsync_dir(path) -> None:
    """Flush a folder's entries (a file created or renamed in it) to disk; a folder that cannot be opened
    or flushed (some file systems) is left as it is."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

"""Standard output whose reader went away (`touch4d shape list | head`): the exit status and the
quiet stop every command shares (the `touch4d` command and the launcher both use it)."""
from __future__ import annotations

import os
import signal
import sys

# The status a Unix tool killed by SIGPIPE has.
EXIT_PIPE_CLOSED = 128 + signal.SIGPIPE


def silence_stdout() -> None:
    """Point standard output at /dev/null after its reader left, so no later write or flush fails."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)

"""Every command that prints stops quietly when its reader goes away (`touch4d shape list | head`)."""
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from touch4d.bus.testing import wait_until


REPO = Path(__file__).resolve().parents[1]

COMMANDS = [
    ["shape", "list"],
    ["shape", "info", "tesseract"],
    ["config", "list"],
    ["glove", "dbc"],
    ["glove", "busload"],
    ["tactile", "probe", "--scene", "config/scenes/hypercube.yaml", "--position", "0", "0", "0"],
]


@pytest.mark.timeout(120)
@pytest.mark.parametrize("args", COMMANDS, ids=lambda a: " ".join(a[:2]))
def test_a_closed_pipe_ends_the_command_quietly(args, tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "touch4d.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, cwd=REPO)
    proc.stdout.close()          # the reader is gone before the first line is written (| head -0)
    _, err = proc.communicate(timeout=100)
    assert err.decode() == "" and proc.returncode == 141   # 128 + SIGPIPE, as `yes | head` gives


@pytest.mark.timeout(120)
def test_a_launch_whose_output_closes_stops_its_nodes_cleanly(tmp_path):
    bus = tmp_path / "bus.yaml"
    bus.write_text("broker: {bind: 127.0.0.1, pub_port: 0, sub_port: 0}\n")
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "touch4d.cli", "launch", "launch/example.yaml", "--bus", str(bus),
                             "--duration", "60", "--ready-file", str(ready)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO, start_new_session=True)
    try:
        proc.stdout.close()
        _, err = proc.communicate(timeout=60)           # long before its 60 s are up
        assert err.decode() == "" and proc.returncode == 141
        wait_until(lambda: not group_alive(proc.pid), timeout=10)     # its nodes stopped with it
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)         # whatever is left of its process group
        except ProcessLookupError:
            pass


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False

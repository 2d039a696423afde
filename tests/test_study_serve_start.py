"""Starting `touch4d study serve` where it cannot serve, and `touch4d study run` given a bad id: one
line saying why, exit status 2, nothing left behind (no second server on one folder, no folder made
for a refused start, no session written outside --out)."""
from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from touch4d.bus.testing import wait_until
from touch4d.cli import main as cli_main

pytestmark = pytest.mark.timeout(120)

REPO = Path(__file__).resolve().parents[1]


def _serve(out: Path, *args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "study", "serve", "paper", "--out", str(out),
                             *args], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    for sig in (signal.SIGINT, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
            proc.wait(30)
            return
        except ProcessLookupError:
            return
        except subprocess.TimeoutExpired:
            continue


def test_a_served_folder_is_its_owners_a_second_server_is_refused_and_the_glove_is_checked(tmp_path):
    """One server (started once for three checks, each a server start of a few seconds): its new OUT
    is 0700; a second `study serve` on it exits 2 naming the first (pid, command), and `serve.json` still
    names the first's address; and its terminal says which tasks the served glove cannot tell: each
    session touches with --glove's default, a held controller (one motor), to which the tilt task's 8
    tilts are all but the same (about 0.03 of 3 bits), so only tilt is named."""
    out = tmp_path / "out"
    first = _serve(out, "--port", "0")
    try:
        lines = []
        wait_until(lambda: lines.append(first.stdout.readline()) or "experimenter page:" in lines[-1]
                   or first.poll() is not None, timeout=60)
        assert oct(out.stat().st_mode & 0o777) == "0o700"
        served = json.loads((out / "serve.json").read_text())
        second = subprocess.run([sys.executable, "-m", "touch4d.cli", "study", "serve", "paper", "--out", str(out),
                                 "--port", "0"], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert second.returncode == 2
        said = second.stderr.strip().splitlines()
        assert len(said) == 1 and "Traceback" not in second.stderr, second.stderr
        assert f"pid {first.pid}" in said[0] and "study serve" in said[0] and str(out) in said[0]
        # the first server's address stands: `study invite` still prints links to a port that listens
        assert json.loads((out / "serve.json").read_text()) == served
        assert first.poll() is None
        wait_until(lambda: any("warning: task" in line for line in lines) or lines.append(first.stdout.readline())
                   or first.poll() is not None, timeout=90)
        warned = [line for line in lines if "warning: task" in line]
        assert len(warned) == 1 and "task tilt:" in warned[0] and "quest-controller.yaml (1 motor)" in warned[0]
        assert re.search(r"tells 0\.0\d of 3\.00 bits", warned[0])
    finally:
        _stop(first)


def test_a_busy_port_is_one_line_exit_2_and_leaves_no_folder(tmp_path):
    taken = socket.create_server(("127.0.0.1", 0))
    port = taken.getsockname()[1]
    out = tmp_path / "new"
    try:
        proc = subprocess.run([sys.executable, "-m", "touch4d.cli", "study", "serve", "paper", "--out", str(out),
                               "--port", str(port)], cwd=REPO, capture_output=True, text=True, timeout=60)
    finally:
        taken.close()
    assert proc.returncode == 2
    said = proc.stderr.strip().splitlines()
    assert len(said) == 1 and "--port" in said[0] and str(port) in said[0] and "in use" in said[0], proc.stderr
    assert "Unclosed" not in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()       # no invites.json, no lock file, no folder


def test_study_run_keeps_a_participant_inside_out(tmp_path, capsys):
    out = tmp_path / "X"
    assert cli_main(["study", "run", "paper", "--participant", "../etc", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--participant" in err and "'../etc'" in err
    assert not (tmp_path / "etc").exists() and not out.exists()
    # the library refuses it too, whoever asks
    from touch4d.study.store import SessionError, session_dir
    with pytest.raises(SessionError, match=re.escape("'../etc'")):
        session_dir(out, "../etc")


def test_study_runs_bus_flag_reaches_the_stack(tmp_path, capfd):
    """The busy-bus hint advises `--bus FILE`: `study run` takes it, and the stack launches with that bus."""
    taken = socket.create_server(("127.0.0.1", 0))
    port = taken.getsockname()[1]
    bus = tmp_path / "bus.yaml"
    bus.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {port}, sub_port: 0}}\nconnect: 127.0.0.1\n")
    try:
        code = cli_main(["study", "run", "paper", "--participant", "P01", "--out", str(tmp_path / "out"),
                         "--quick", "--bus", str(bus), "renderer:=none", "monitor:=none"])
    finally:
        taken.close()
    assert code != 0
    err = capfd.readouterr().err
    assert str(bus) in err and "broker.pub_port" in err and str(port) in err

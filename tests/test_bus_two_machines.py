"""docs/bus.md's PC + Pi set-up ("Two machines") end to end, on loopback: `touch4d bus keygen`, the key folders, the
two bus config files, and two `touch4d launch` processes (the PC with the broker, the Pi without),
with the bus files named by relative and by absolute paths."""
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from touch4d.bus import Node
from touch4d.bus.config import load_bus_config
from touch4d.bus.testing import REPO, collect, free_port, launch_process, wait_until
from touch4d.messages import MotorStatus

pytestmark = pytest.mark.timeout(150)


def checkout(folder: Path) -> Path:
    """A machine's copy of the repository's config/ and launch/ (no keys)."""
    folder.mkdir()
    shutil.copytree(REPO / "config", folder / "config", ignore=shutil.ignore_patterns("keys"))
    shutil.copytree(REPO / "launch", folder / "launch")
    return folder


def touch4d(cwd: Path, *args: str) -> str:
    run = subprocess.run([sys.executable, "-m", "touch4d.cli", *args], cwd=cwd, capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    return run.stdout


def on_loopback(path: Path, pub: int, sub: int) -> None:
    """The LAN address of docs/bus.md's files -> loopback, on free ports."""
    text = path.read_text().replace("192.168.50.1", "127.0.0.1")
    assert "pub_port" not in text and text.count("broker:\n") == 1    # the default ports, which the tests avoid
    path.write_text(text.replace("broker:\n", f"broker:\n  pub_port: {pub}\n  sub_port: {sub}\n"))


@pytest.mark.parametrize("pc_paths", ["relative", "absolute"])
def test_the_pc_and_pi_recipe_runs_on_two_launches(tmp_path, pc_paths):
    pc, pi = checkout(tmp_path / "pc"), checkout(tmp_path / "pi")
    # Keys, as docs/bus.md says: three key pairs made on the PC; the Pi gets the broker's public key
    # and its own pair; the PC's clients/ folder holds the public keys allowed to connect.
    for name in ("broker", "pc", "pi"):
        touch4d(pc, "bus", "keygen", name)
    keys = pc / "config" / "keys"
    (keys / "clients").mkdir()
    for name in ("pc.key", "pi.key"):
        shutil.copy(keys / name, keys / "clients" / name)
    (pi / "config" / "keys").mkdir()
    for name in ("broker.key", "pi.key", "pi.key_secret"):
        shutil.copy(keys / name, pi / "config" / "keys" / name)
    ports = free_port(), free_port()
    on_loopback(pc / "config" / "bus-vive-pc.yaml", *ports)
    on_loopback(pi / "config" / "bus-vive-pi.yaml", *ports)

    def bus_arg(machine: Path, name: str, form: str) -> str:
        return f"config/{name}" if form == "relative" else str(machine / "config" / name)

    pi_paths = "absolute" if pc_paths == "relative" else "relative"
    channel = f"two-machines-{uuid.uuid4().hex}"
    # No VR tracker or window here: a scripted hand held in the hypercube; the Pi's motor node on a
    # virtual CAN bus with the board emulator instead of the HAT's can0.
    with launch_process(["launch/vive.yaml", "tracker:=scripted", "tracker.path:=hold", "renderer:=none"],
                        bus_config=bus_arg(pc, "bus-vive-pc.yaml", pc_paths), cwd=pc) as pc_run:
        assert pc_run.wait_ready(60).curve is not None
        with launch_process(["launch/pi.yaml", "--no-broker", "motors.interface:=virtual",
                             f"motors.channel:={channel}", "motors.emulate:=true"],
                            bus_config=bus_arg(pi, "bus-vive-pi.yaml", pi_paths), cwd=pi) as pi_run:
            pi_run.wait_ready(60)
            # A third peer with the Pi's keys hears the Pi's motor node drive the glove from the
            # PC's tactile commands: duty above zero for the touched motors.
            with Node("probe", bus=load_bus_config(pi / "config" / "bus-vive-pi.yaml"), heartbeat=False) as probe:
                status = collect(probe, "motors/status", MotorStatus)
                wait_until(lambda: any(np.any(s.duty > 0) for s in status), timeout=60, spin=probe)
            assert pi_run.stop(timeout=30) == 0
        assert pc_run.stop(timeout=30) == 0
    assert "(CURVE)" in pc_run.text and "Invalid certificate" not in pc_run.text + pi_run.text

"""The broker killed in the middle of a touch (the two-machine set-up: the motor node's launch uses a
broker that runs elsewhere, `--no-broker`): the motors are off within 100 ms (the motor node sees the
broker's connection close), and the launch stops,
exits non-zero and names the broker. The boards run in this process on a CAN bus shared with the
launched motor node (python-can's udp_multicast on loopback)."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml

from touch4d.boards.config import load_glove_can
from touch4d.boards.emulator import make_glove_emulator
from touch4d.bus import Node
from touch4d.bus.config import load_bus_config
from touch4d.bus.testing import REPO, ProcessOutput, free_port, launch_process, wait_until
from touch4d.messages import MotorCommand

pytestmark = pytest.mark.timeout(120)


def test_a_killed_broker_turns_the_motors_off_and_stops_the_launch_naming_it(tmp_path, can_group):
    group = can_group
    sub_port = free_port()
    bus_file = tmp_path / "bus.yaml"
    bus_file.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {free_port()}, sub_port: {sub_port}}}\n"
                        "connect: 127.0.0.1\n")
    data = yaml.safe_load((REPO / "config" / "glove.yaml").read_text())
    data["can"].update(interface="udp_multicast", channel=group)
    glove = tmp_path / "glove.yaml"
    glove.write_text(yaml.safe_dump(data))
    cfg = load_glove_can(glove)
    emu = make_glove_emulator("python", cfg).start()
    broker = ProcessOutput(subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "bus", "broker", "--bus",
                                             str(bus_file)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True))
    try:
        broker.wait_for_line("broker: publishers connect", timeout=30)
        with launch_process(["launch/pi.yaml", "--no-broker", f"motors.glove:={glove}", "motors.interface:=",
                             "motors.channel:="], bus_config=str(bus_file)) as run, \
                Node("tester", bus=load_bus_config(bus_file), heartbeat=False) as tester:
            cmd = tester.create_publisher("tactile/motors", MotorCommand)
            names = list(cfg.motor_names)

            def touch():
                cmd.publish(MotorCommand(names=names, intensity=np.full(len(names), 0.7)))
                time.sleep(0.005)
                return all(emu.motor_levels())

            assert wait_until(touch, timeout=60, interval=0.0), run.text
            broker.proc.send_signal(signal.SIGKILL)
            killed_at = time.monotonic()
            while any(emu.motor_levels()) and time.monotonic() < killed_at + 5:
                cmd.publish(MotorCommand(names=names, intensity=np.full(len(names), 0.7)))   # into the void
                time.sleep(0.002)
            off_after = time.monotonic() - killed_at
            # The motor node sees the broker's connection close and turns every motor off at its next
            # refresh tick (5 ms), not a watchdog period (100 ms) after the last command.
            assert off_after <= 0.1, off_after
            code = run.proc.wait(20)
            run.join()
            assert code != 0
            last = run.text.strip().splitlines()[-1]
            assert f"the broker at tcp://127.0.0.1:{sub_port} went away" in last, run.text[-2000:]
            # The motor node stopped cleanly on its way out: the boards were sent NMT STOP.
            assert all(b.nmt_state == "STOPPED" for b in emu.boards.values())
    finally:
        if broker.proc.poll() is None:
            broker.proc.kill()
        broker.proc.wait()
        broker.join()
        emu.stop()

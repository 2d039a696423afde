"""The firmware core in the loop: the haptic stack (scripted hand, scene, tactile, motor node)
drives boards that run the firmware's own logic, and their outputs carry the commanded duties.
Also the motor node's and the CLI's way of choosing it."""
from __future__ import annotations

import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.boards.duty import duty_to_levels, intensity_to_duty
from touch4d.bus import Node
from touch4d.bus.testing import collect, node_process, running_broker
from touch4d.errors import ConfigError
from touch4d.messages import MotorCommand, MotorStatus
from touch4d.nodes.motors import MotorsNode

ROOT = Path(__file__).resolve().parents[1]
CFG = load_glove_can(ROOT / "config" / "glove.yaml")
RECENT = 30  # commands (~330 ms at 90 Hz) an output may lag behind: the refresh and the bus thread
AHEAD = 5    # commands the motor node may have received before the probe node


def board_levels(cmd: MotorCommand) -> dict[int, list[int]]:
    """What each board's channels should carry for one command (the motor node's duty curve)."""
    by_name = dict(zip(cmd.names, cmd.intensity))
    motor = duty_to_levels(intensity_to_duty(np.array([by_name.get(n, 0.0) for n in CFG.motor_names]), CFG.duty))
    out = {b.id: [0] * b.channels for b in CFG.boards}
    for k, (b, c) in enumerate(zip(CFG.motor_board, CFG.motor_channel)):
        out[b][c] = int(motor[k])
    return out


@pytest.mark.timeout(180)
def test_the_full_stack_drives_the_firmware_boards_outputs_to_the_commanded_duties():
    with running_broker() as bus:
        motors = MotorsNode(params={"channel": f"fw-stack-{uuid.uuid4().hex}", "emulate": True,
                                    "board_emulator": "firmware", "status_hz": 20.0}, bus=bus)
        probe = Node("probe", bus=bus, heartbeat=False)
        try:
            commands = collect(probe, "tactile/motors", MotorCommand)
            status = collect(probe, "motors/status", MotorStatus)
            glove = motors.emulator
            samples = []   # (commands seen, {board: levels}, {board: pwm})
            with node_process("scene", bus, params={"scene": "config/scenes/hypercube.yaml"}), \
                    node_process("tactile", bus), \
                    node_process("scripted_tracker", bus, params={"path": "demo", "start_s": 2.5, "loop": False}):
                end = time.monotonic() + 120
                touched_at = None
                while time.monotonic() < end:
                    motors.spin_once(0.002)
                    probe.spin_once(0.0)
                    if not commands:
                        continue
                    outputs = {b: glove.outputs(b) for b in glove.boards}   # levels and PWM of one moment
                    samples.append((len(commands), {b: o[0] for b, o in outputs.items()},
                                    {b: o[1] for b, o in outputs.items()}))
                    if touched_at is None and commands[-1].intensity.max() > 0:
                        touched_at = len(commands)
                    quiet = len(commands) > 90 and not any(c.intensity.any() for c in commands[-90:])
                    if touched_at is not None and quiet and not any(any(v) for v in samples[-1][1].values()):
                        break   # the hand touched, left a second ago, and the boards are off
        finally:
            probe.shutdown()
            motors.shutdown()
    assert touched_at is not None, "the tactile node never commanded a motor"
    want = [board_levels(c) for c in commands]
    matched = 0
    for seen, levels, pwm in samples:
        for b, got in levels.items():
            # Every board carries the duties of one of the latest commands (or is off: the node's
            # watchdog or a command too old to use), on the right channels. The motor node may
            # have had a command or two that this probe had not yet when it sampled.
            options = [want[i][b] for i in range(max(0, seen - RECENT), min(len(want), seen + AHEAD))]
            assert got in options or not any(got), (seen, b, got, options[-1])
            matched += bool(any(got)) and got == want[seen - 1][b]
            # duty -> PWM: the nearest compare value of the Blue Pill's timer (exact fractions)
            assert pwm[b] == [(2 * v * glove.core.pwm_period + 127) // 254 for v in got]
    assert matched >= 100, f"only {matched} board samples carried the latest command's duties"
    assert not any(any(v) for v in samples[-1][1].values())
    # The boards answered as boards do: online, operational, every duty frame acknowledged.
    answered = [s for s in status if all(b["online"] and b["state"] == "operational" and not b["faults"]
                                         for b in s.boards) and s.duty.max() > 0]
    assert answered, status[-1].boards if status else "no motors/status"


def test_the_motor_node_names_the_board_emulators_it_knows():
    with running_broker() as bus:
        with pytest.raises(ConfigError, match="board_emulator.*one of firmware, python.*'c-core'"):
            MotorsNode(params={"emulate": True, "board_emulator": "c-core"}, bus=bus)


@pytest.mark.timeout(60)
def test_glove_emulate_firmware_runs_the_core_on_a_bus():
    done = subprocess.run([sys.executable, "-m", "touch4d.cli", "glove", "emulate", "--firmware", "--duration", "0.5",
                           "--print-period", "0.4", "--channel", f"fw-cli-{uuid.uuid4().hex}"],
                          capture_output=True, text=True, timeout=50)
    assert done.returncode == 0, done.stderr
    assert "emulating boards [1, 2, 3, 4] (firmware)" in done.stdout
    assert "board 1: pre_operational pre_operational levels [0, 0, 0, 0, 0, 0, 0, 0] pwm [0, 0, 0, 0, 0, 0, 0, 0]/3600" \
        in done.stdout

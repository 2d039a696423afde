"""The boards' firmware builds: the STM32F103 image (warning-free, fits, safe vectors), the frame
code generated from the DBC (regenerated when it changes, and packing what cantools packs), and
the core's self-test on the host. The same self-test on the Cortex-M3 runs with the conformance
suite (test_boards_conformance.py)."""
from __future__ import annotations

import ctypes
import re
import struct
import subprocess
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.boards.config import load_glove_can
from touch4d.boards.dbc import DUTY_LEVELS, NMT_COMMANDS, NMT_STATES, OUTPUT_STATES, dbc_text, load_dbc
from touch4d.boards.emulator import COUNTER_WINDOW, REJECTED
from touch4d.boards.firmware import FIRMWARE_DIR, FirmwareCore, build, build_dir

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = load_glove_can(ROOT / "config" / "glove.yaml")
BIG = load_glove_can(ROOT / "config" / "gloves" / "64-motor.yaml")
FLASH, RAM = 64 * 1024, 20 * 1024  # STM32F103C8


def make(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-C", str(FIRMWARE_DIR), *args], capture_output=True, text=True, timeout=timeout)


def symbol(elf: Path, name: str) -> int:
    nm = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    return int(re.search(rf"^([0-9a-f]+) \w {name}$", nm, re.M).group(1), 16)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("flags", [[], ["NODE_ID=3", "SUPPLY_SENSE=1"]], ids=["straps", "node-3-supply-sense"])
def test_the_blue_pill_image_builds_warning_free_fits_and_starts_with_its_outputs_off(tmp_path, flags):
    done = make(f"BUILD={tmp_path}", *flags)               # `make -C firmware`, into a fresh folder
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert "-Wall -Wextra -Werror" in out and "warning" not in out.lower()
    flash = int(re.search(r"flash: (\d+) of 65536 bytes", out).group(1))
    ram = int(re.search(r"RAM:\s+(\d+) of 20480 bytes", out).group(1))
    elf, image = tmp_path / "bluepill" / "touch4d-board.elf", (tmp_path / "bluepill" / "touch4d-board.bin").read_bytes()
    assert flash == len(image) and 0 < flash < FLASH and 0 < ram < RAM - 2048
    stack, reset, *system = struct.unpack("<16I", image[:64])
    assert stack == 0x2000_0000 + RAM                     # the top of the SRAM
    assert reset == symbol(elf, "reset_handler") | 1       # Thumb
    fault = symbol(elf, "fault_handler") | 1
    assert system[:5] == [fault] * 5                      # NMI, HardFault, MemManage, BusFault, UsageFault
    assert struct.unpack("<43I", image[64:64 + 43 * 4]) == (fault,) * 43   # no interrupt but SysTick
    # The reset handler's first call turns the outputs off, before memory is even set up.
    dis = subprocess.run(["arm-none-eabi-objdump", "-d", "--disassemble=reset_handler", str(elf)],
                         capture_output=True, text=True, check=True).stdout
    calls = re.findall(r"\bbl\s+[0-9a-f]+ <(\w+)>", dis)
    assert calls[0] == "board_outputs_off_gpio", dis


def test_the_build_regenerates_the_frame_code_when_the_dbc_changes(tmp_path):
    dbc = tmp_path / "glove.dbc"
    gen = tmp_path / "build" / "gen"
    dbc.write_text(dbc_text(DEFAULT))
    assert make(f"BUILD={tmp_path / 'build'}", f"DBC={dbc}", f"{gen}/.stamp").returncode == 0
    assert "#define T4D_BOARD_COUNT 4u" in (gen / "glove_boards.h").read_text()
    stamp = (gen / ".stamp").stat().st_mtime_ns
    assert make(f"BUILD={tmp_path / 'build'}", f"DBC={dbc}", f"{gen}/.stamp").returncode == 0
    assert (gen / ".stamp").stat().st_mtime_ns == stamp    # the same DBC: nothing regenerated
    dbc.write_text(dbc_text(BIG))
    assert make(f"BUILD={tmp_path / 'build'}", f"DBC={dbc}", f"{gen}/.stamp").returncode == 0
    assert "#define T4D_BOARD_COUNT 8u" in (gen / "glove_boards.h").read_text()
    assert "GLOVE_DUTY_B8_FRAME_ID (0x208u)" in (gen / "glove.h").read_text()


def test_a_dbc_that_does_not_speak_the_protocol_fails_the_build_naming_what_is_missing(tmp_path):
    dbc = tmp_path / "glove.dbc"
    dbc.write_text(re.sub(r"VAL_ 0 Command[^\n]*\n", "", dbc_text(DEFAULT)))
    done = make(f"BUILD={tmp_path / 'build'}", f"DBC={dbc}", f"{tmp_path}/build/gen/.stamp")
    assert done.returncode != 0
    assert "NMT.Command: expected value table entries ['START', 'STOP', 'PRE_OPERATIONAL', 'RESET_NODE']" in done.stderr


@pytest.mark.parametrize("cfg", [DEFAULT, BIG], ids=["glove", "64-motor"])
def test_the_generated_board_table_is_the_dbc(cfg):
    db = load_dbc(dbc_text(cfg))
    core = FirmwareCore.for_glove(cfg)
    want = []
    for b in cfg.boards:
        duty, status, hb = (db.get_message_by_name(f"{kind}_B{b.id}") for kind in ("Duty", "Status", "Heartbeat"))
        want.append({"node_id": b.id, "channels": b.channels, "duty_id": duty.frame_id, "duty_length": duty.length,
                     "duty_full_scale": DUTY_LEVELS, "status_id": status.frame_id, "status_length": status.length,
                     "status_cycle_ms": status.cycle_time, "heartbeat_id": hb.frame_id,
                     "heartbeat_length": hb.length, "heartbeat_cycle_ms": hb.cycle_time})
    assert core.boards() == want
    assert want[0]["status_cycle_ms"] == round(1000 / cfg.status_hz)


DB = load_dbc(dbc_text(DEFAULT))


@pytest.fixture(scope="module")
def core():
    return FirmwareCore.for_glove(DEFAULT)


def test_the_core_counts_every_reason_the_emulator_counts(core):
    assert core.counter_names == ("applied", "nmt", "ignored", "bad_counter", "unknown", "bad_length",
                                  "bad_frame_type", "bad_command", "error_frame", "watchdog_trips")
    assert set(REJECTED) <= set(core.counter_names)
    assert core.counter_window == COUNTER_WINDOW          # the same counter check


@settings(max_examples=60, deadline=None)
@given(board=st.integers(0, 3), counter=st.integers(0, 255), levels=st.lists(st.integers(0, 127), min_size=8, max_size=8))
def test_the_generated_duty_unpacking_reads_what_cantools_packs(core, board, counter, levels):
    msg = DB.get_message_by_name(f"Duty_B{board + 1}")
    data = msg.encode({"Counter": counter, **{f"Duty_Ch{c}": v for c, v in enumerate(levels)}}, scaling=False)
    got_counter, got_levels = ctypes.c_uint8(), (ctypes.c_uint8 * 8)()
    assert core.lib.t4d_host_unpack_duty(board, data, len(data), ctypes.byref(got_counter), got_levels) == 0
    assert got_counter.value == counter and list(got_levels) == levels


@settings(max_examples=60, deadline=None)
@given(board=st.integers(0, 3), state=st.sampled_from(sorted(OUTPUT_STATES)), faults=st.integers(0, 31),
       last=st.integers(0, 255), mask=st.integers(0, 255), bad=st.integers(0, 0xFFFF), nmt=st.sampled_from(sorted(NMT_STATES)))
def test_the_generated_status_and_heartbeat_packing_writes_what_cantools_packs(core, board, state, faults, last, mask, bad, nmt):
    status = DB.get_message_by_name(f"Status_B{board + 1}")
    flags = {f"Fault_{f}": (faults >> i) & 1 for i, f in
             enumerate(("Watchdog", "BadFrame", "Overtemp", "Overcurrent", "Undervoltage"))}
    want = status.encode({"State": state, "LastCounter": last, "ActiveMask": mask, "BadFrames": bad, **flags},
                         scaling=False)
    out = (ctypes.c_uint8 * 8)()
    assert core.lib.t4d_host_pack_status(board, out, state, faults, last, mask, bad) == len(want)
    assert bytes(out)[:len(want)] == want
    hb = DB.get_message_by_name(f"Heartbeat_B{board + 1}")
    assert core.lib.t4d_host_pack_heartbeat(board, out, nmt) == 1
    assert bytes(out)[:1] == hb.encode({"State": nmt}, scaling=False)


@given(command=st.sampled_from(sorted(NMT_COMMANDS)), node=st.integers(0, 255))
def test_the_generated_nmt_unpacking_reads_what_cantools_packs(core, command, node):
    data = DB.get_message_by_name("NMT").encode({"Command": command, "Node": node}, scaling=False)
    c, n = ctypes.c_uint8(), ctypes.c_uint8()
    assert core.lib.t4d_host_unpack_nmt(data, len(data), ctypes.byref(c), ctypes.byref(n)) == 0
    assert (c.value, n.value) == (command, node)
    codes = (ctypes.c_uint32 * 6)()
    core.lib.t4d_host_nmt_codes(codes)
    assert list(codes) == [0x000, 2, 1, 2, 0x80, 0x81]   # id, length, START, STOP, PRE_OPERATIONAL, RESET_NODE


def test_the_core_self_test_passes_on_the_host():
    done = make("-s", "check-host", f"BUILD={build(DEFAULT, 'host')}")
    assert done.returncode == 0 and done.stdout.splitlines()[-1] == "END 0", done.stdout + done.stderr
    assert build_dir(DEFAULT) == build(DEFAULT, "host")

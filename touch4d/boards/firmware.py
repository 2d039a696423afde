"""The boards' firmware core (firmware/, C) on the Python CAN bus, in place of the Python emulator.

`build(cfg, target)` runs `make -C firmware TARGET` for a glove's DBC into firmware/build/glove-<hash>/
(make regenerates the frame code when the DBC changes and rebuilds only what changed);
`FirmwareGloveEmulator` is a `GloveEmulator` whose boards are the core built for the host and
loaded with ctypes: every frame on the bus reaches every board's core as raw bytes, as on a real
bus, and the core decides what it is. A board also shows the timer compare values its Blue Pill
would write (`pwm`, of `pwm_period`).
"""
from __future__ import annotations

import ctypes
import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import can

from touch4d.boards.config import Board, GloveCan
from touch4d.boards.dbc import NMT_STATES, OUTPUT_STATES, dbc_text
from touch4d.boards.emulator import HARDWARE_FAULTS, MALFORMED, GloveEmulator
from touch4d.boards.protocol import FAULT_NAMES
from touch4d.errors import Touch4dError

FIRMWARE_ENV = "TOUCH4D_FIRMWARE_DIR"
# The C sources sit in a checkout's firmware/; a wheel has none, so $TOUCH4D_FIRMWARE_DIR may name a
# checkout's firmware/ folder (the core for this machine is then built there, in its build/).
FIRMWARE_DIR = Path(os.environ.get(FIRMWARE_ENV) or Path(__file__).resolve().parents[2] / "firmware")
BUILD_DIR = FIRMWARE_DIR / "build"
# What `build` makes -> the Makefile's goal: the shared library and self-test for this machine, the
# self-test for the Cortex-M3 (QEMU), the STM32F103 image.
TARGETS = {"host": "host", "qemu": "qemu", "bluepill": "all"}
FLAGS = {"extended": 1, "remote": 2, "error": 4, "fd": 8}  # enum t4d_frame_flags
MAX_FRAMES = 3                                               # T4D_TICK_MAX_FRAMES


class FirmwareBuildError(Touch4dError, RuntimeError):
    """The firmware could not be built (sources missing, a compiler missing, or it failed)."""


def build_dir(cfg: GloveCan) -> Path:
    """The build folder of a glove's protocol: one per DBC text, so gloves do not rebuild each other."""
    return BUILD_DIR / f"glove-{hashlib.sha256(dbc_text(cfg).encode()).hexdigest()[:12]}"


def build(cfg: GloveCan, target: str = "host") -> Path:
    """Build the firmware's `target` ('host', 'qemu' or 'bluepill') for this glove; its build folder.

    Concurrent callers (the motor node and a test, say) wait for each other on a lock file.
    """
    if target not in TARGETS:
        raise ValueError(f"firmware target {target!r}: expected one of {sorted(TARGETS)}")
    if not (FIRMWARE_DIR / "Makefile").is_file():
        where = f"${FIRMWARE_ENV} names {FIRMWARE_DIR}, which" if os.environ.get(FIRMWARE_ENV) else \
            f"{FIRMWARE_DIR} is not there: an installed wheel ships no firmware sources, and this installation"
        raise FirmwareBuildError(
            f"the firmware core is built from the boards' C sources, and {where} has no firmware/Makefile. "
            f"Either run from a source checkout (git clone the repository; ./dev installs it and the compilers), "
            f"or keep this installation and set {FIRMWARE_ENV}=/path/to/checkout/firmware to build the core for "
            "this machine there (needs make and gcc). The Python emulator (board_emulator: python, the "
            "default; `touch4d glove emulate` without --firmware) needs neither")
    tools = ["make", "gcc"] + (["arm-none-eabi-gcc"] if target != "host" else [])
    missing = [t for t in tools if shutil.which(t) is None]
    if missing:
        raise FirmwareBuildError(f"building the firmware ({target}) needs {', '.join(missing)}: run ./dev, which "
                                 "installs them")
    out = build_dir(cfg)
    out.mkdir(parents=True, exist_ok=True)
    dbc = out / "glove-in.dbc"
    text = dbc_text(cfg)
    with open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not dbc.is_file() or dbc.read_text() != text:
            dbc.write_text(text)
        make_target = TARGETS[target]
        done = subprocess.run(["make", "-C", str(FIRMWARE_DIR), make_target, f"BUILD={out}", f"DBC={dbc}",
                               f"PYTHON={sys.executable}"],  # this interpreter has cantools
                              capture_output=True, text=True)
    if done.returncode != 0:
        raise FirmwareBuildError(f"make -C {FIRMWARE_DIR} {make_target} failed:\n{done.stdout}{done.stderr}")
    return out


def _us(now: float) -> int:
    """Seconds -> the core's wrapping uint32 microsecond clock."""
    return int(round(now * 1e6)) & 0xFFFFFFFF


def _frame_args(msg: can.Message) -> tuple:
    """A python-can message as the core's frame: id, flags, length, 8 data bytes."""
    flags = ((FLAGS["extended"] if msg.is_extended_id else 0) | (FLAGS["remote"] if msg.is_remote_frame else 0)
             | (FLAGS["error"] if msg.is_error_frame else 0) | (FLAGS["fd"] if msg.is_fd else 0))
    data = bytes(msg.data or b"")
    return msg.arbitration_id & 0x1FFFFFFF, flags, min(len(data), 255), data[:8].ljust(8, b"\0")


class FirmwareCore:
    """The host build of the core, loaded once per glove protocol (a ctypes library)."""

    _loaded: dict[Path, "FirmwareCore"] = {}

    def __init__(self, path: Path):
        # PyDLL keeps the GIL during calls: a board's state is never read while the bus thread
        # is inside the core, as with the Python emulator.
        lib = self.lib = ctypes.PyDLL(str(path))
        u8, u16, u32, size, ptr = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_size_t, ctypes.c_void_p
        for name, res, args in [
            ("t4d_host_board_size", size, []), ("t4d_host_counter_count", ctypes.c_uint, []),
            ("t4d_host_counter_name", ctypes.c_char_p, [ctypes.c_uint]), ("t4d_host_pwm_period", u16, []),
            ("t4d_host_max_channels", ctypes.c_uint, []), ("t4d_host_counter_window", u32, []),
            ("t4d_host_init", ctypes.c_int, [ptr, u8, u32, u16, u32]), ("t4d_host_boot", None, [ptr, u32]),
            ("t4d_host_receive", None, [ptr, u32, u8, u8, ctypes.c_char_p, u32]),
            ("t4d_host_receive_many", None, [ptr, size, u32, u8, u8, ctypes.c_char_p, u32]),
            ("t4d_host_tick", size, [ptr, u32, ptr, ptr, ptr]), ("t4d_host_due_in", u32, [ptr, u32]),
            ("t4d_host_set_hardware_faults", None, [ptr, u8]), ("t4d_host_all_off", None, [ptr]),
            ("t4d_host_output_state", u8, [ptr]), ("t4d_host_nmt_state", u8, [ptr]),
            ("t4d_host_watchdog_tripped", ctypes.c_int, [ptr]), ("t4d_host_outputs", None, [ptr, ptr, ptr]),
            ("t4d_host_counters", None, [ptr, ptr]),
            ("t4d_host_board_count", size, []), ("t4d_host_board_proto", None, [size, ptr]),
            ("t4d_host_nmt_codes", None, [ptr]),
            ("t4d_host_unpack_duty", ctypes.c_int, [size, ctypes.c_char_p, size, ptr, ptr]),
            ("t4d_host_pack_status", ctypes.c_int, [size, ptr, u8, u8, u8, u8, u16]),
            ("t4d_host_pack_heartbeat", ctypes.c_int, [size, ptr, u8]),
            ("t4d_host_unpack_nmt", ctypes.c_int, [ctypes.c_char_p, size, ptr, ptr]),
        ]:
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
        self.board_size = lib.t4d_host_board_size()
        self.channels = lib.t4d_host_max_channels()
        self.counter_names = tuple(lib.t4d_host_counter_name(i).decode() for i in range(lib.t4d_host_counter_count()))
        self.pwm_period = lib.t4d_host_pwm_period()
        self.counter_window = lib.t4d_host_counter_window()

    @classmethod
    def for_glove(cls, cfg: GloveCan) -> "FirmwareCore":
        """The core built (if need be) and loaded for this glove's protocol."""
        path = build_dir(cfg) / "host" / "libt4dboard.so"
        if path not in cls._loaded:   # built once per process: make is quick, but not free
            build(cfg, "host")
            cls._loaded[path] = cls(path)
        return cls._loaded[path]

    def boards(self) -> list[dict]:
        """The protocol table generated from the DBC, as the core sees it."""
        keys = ("node_id", "channels", "duty_id", "duty_length", "duty_full_scale", "status_id", "status_length",
                "status_cycle_ms", "heartbeat_id", "heartbeat_length", "heartbeat_cycle_ms")
        out = []
        for i in range(self.lib.t4d_host_board_count()):
            values = (ctypes.c_uint32 * len(keys))()
            self.lib.t4d_host_board_proto(i, values)
            out.append(dict(zip(keys, values)))
        return out


class FirmwareBoard:
    """One board running the firmware core: BoardEmulator's interface over the C state."""

    def __init__(self, core: FirmwareCore, board: Board, cfg: GloveCan, now: float, clock=time.monotonic):
        self.core = core
        self.lib = core.lib
        self.id = board.id
        self.channels = board.channels
        self.clock = clock
        self.hardware_faults: set[str] = set()   # as BoardEmulator: names of HARDWARE_FAULTS
        self._faults_mask = 0
        self._state = ctypes.create_string_buffer(core.board_size)
        self._ids = (ctypes.c_uint32 * MAX_FRAMES)()
        self._lens = (ctypes.c_uint8 * MAX_FRAMES)()
        self._data = (ctypes.c_uint8 * (8 * MAX_FRAMES))()
        if self.lib.t4d_host_init(self._state, board.id, round(cfg.board_watchdog_s * 1e6), core.pwm_period,
                                  _us(now)) != 0:
            raise FirmwareBuildError(f"the firmware core has no board {board.id}: it was built from another DBC")

    def _sync_faults(self) -> None:
        """Hand `hardware_faults` to the core (they act at its next frame or tick, as in BoardEmulator)."""
        mask = sum(1 << FAULT_NAMES.index(f) for f in self.hardware_faults if f in HARDWARE_FAULTS)
        if mask != self._faults_mask:
            self.lib.t4d_host_set_hardware_faults(self._state, mask)
            self._faults_mask = mask

    def boot(self, now: float) -> None:
        self.lib.t4d_host_boot(self._state, _us(now))

    def receive(self, msg: can.Message, now: float) -> None:
        """One raw frame from the bus."""
        self._sync_faults()
        self.lib.t4d_host_receive(self._state, *_frame_args(msg), _us(now))

    def tick(self, now: float) -> list[can.Message]:
        self._sync_faults()
        n = self.lib.t4d_host_tick(self._state, _us(now), self._ids, self._lens, self._data)
        return [can.Message(arbitration_id=self._ids[i], data=bytes(self._data[8 * i:8 * i + self._lens[i]]),
                            is_extended_id=False) for i in range(n)]

    def next_due(self) -> float:
        now = self.clock()
        return now + self.lib.t4d_host_due_in(self._state, _us(now)) / 1e6

    def all_off(self) -> None:
        self.lib.t4d_host_all_off(self._state)

    def _outputs(self) -> tuple[list[int], list[int]]:
        levels = (ctypes.c_uint8 * self.core.channels)()
        compare = (ctypes.c_uint16 * self.core.channels)()
        self.lib.t4d_host_outputs(self._state, levels, compare)
        return list(levels)[:self.channels], list(compare)[:self.channels]

    @property
    def levels(self) -> list[int]:
        """Duty level (0..127) of every channel."""
        return self._outputs()[0]

    @property
    def pwm(self) -> list[int]:
        """Timer compare value of every channel (0..pwm_period), as the Blue Pill writes it."""
        return self._outputs()[1]

    @property
    def pwm_period(self) -> int:
        return self.core.pwm_period

    @property
    def counters(self) -> Counter:
        """What the board counted (enum t4d_counter), and `malformed`, the sum of MALFORMED."""
        values = (ctypes.c_uint32 * len(self.core.counter_names))()
        self.lib.t4d_host_counters(self._state, values)
        out = Counter(dict(zip(self.core.counter_names, values)))
        out["malformed"] = sum(out[k] for k in MALFORMED)
        return out

    @property
    def nmt_state(self) -> str:
        return NMT_STATES[self.lib.t4d_host_nmt_state(self._state)]

    def output_state(self) -> str:
        return OUTPUT_STATES[self.lib.t4d_host_output_state(self._state)]

    @property
    def watchdog_tripped(self) -> bool:
        return bool(self.lib.t4d_host_watchdog_tripped(self._state))


class FirmwareGloveEmulator(GloveEmulator):
    """Every board of a glove running the firmware core, on one python-can bus (see GloveEmulator)."""

    def __init__(self, cfg: GloveCan, *args, **kwargs):
        self.core = FirmwareCore.for_glove(cfg)  # before the bus opens: a failed build leaves nothing open
        self._live_key: tuple | None = None
        super().__init__(cfg, *args, **kwargs)

    def _make_board(self, board: Board, now: float) -> FirmwareBoard:
        return FirmwareBoard(self.core, board, self.cfg, now, self.clock)

    def process(self, msg: can.Message, now: float) -> None:
        """Every present board's core gets the frame, whatever it is (it decodes and counts)."""
        self.counters["received"] += 1
        live = self._live()
        key = tuple(b.id for b in live)
        if self._live_key != key:
            self._live_key = key
            self._live_states = (ctypes.c_void_p * len(live))(*(ctypes.addressof(b._state) for b in live))
        for b in live:
            b._sync_faults()
        self.core.lib.t4d_host_receive_many(self._live_states, len(live), *_frame_args(msg), _us(now))

    def pwm(self, board_id: int) -> list[int]:
        """Timer compare values of a board's channels."""
        return self.boards[board_id].pwm

    def outputs(self, board_id: int) -> tuple[list[int], list[int]]:
        """A board's duty levels and timer compare values, read together (the bus thread may apply
        a frame between two separate reads)."""
        return self.boards[board_id]._outputs()


__all__ = ["FirmwareGloveEmulator", "FirmwareBoard", "FirmwareCore", "FirmwareBuildError", "build", "build_dir",
           "FIRMWARE_DIR"]

"""Firmware benchmark: the board's flash and RAM, and the time from a duty frame's arrival to the
PWM compare registers, on the Cortex-M3.

- flash/RAM: `make -C firmware` of the STM32F103 image (the default glove).
- core paths, in instructions: the self-test under qemu-system-arm (stm32vldiscovery, Cortex-M3)
  with `-icount`, where SysTick advances a fixed step per instruction (calibrated in the same run
  on 100 NOPs). Baseline: the cantools-generated unpacking of the same duty frame alone.
- board-layer paths (registers QEMU does not model: bxCAN, TIM), in instructions: the length of
  each function in the image's disassembly (straight-line code: an upper bound of what runs).
- frame arrival -> compare registers: read at once; on an idle bus, landing just after the loop
  found the receive FIFO empty (a whole iteration first); worst case, landing then behind two
  other frames in the 3-deep FIFO that each change every channel, in an iteration whose tick
  sends three frames. Cycles: 1.5 per instruction is typical for a
  Cortex-M3 running from flash at 72 MHz with two wait states and the prefetch buffer; 3 is a
  pessimistic bound. The compare value then takes effect at the next PWM period (<= 50 us).
- host: one frame through the firmware core (ctypes) vs through the Python emulator.
Run: .venv/bin/python bench/bench_firmware.py
"""
from __future__ import annotations

import re
import subprocess
import time
import uuid

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads

from touch4d.boards.config import DEFAULT_GLOVE, load_glove_can
from touch4d.boards.emulator import make_glove_emulator
from touch4d.boards.firmware import FIRMWARE_DIR, build
from touch4d.boards.protocol import GloveProtocol

CPU_HZ = 72e6
PWM_PERIOD_US = 50.0


def function_sizes(elf, names):
    dis = subprocess.run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    sizes, current = {}, None
    for line in dis.splitlines():
        m = re.match(r"^[0-9a-f]+ <(\w+)>:$", line)
        if m:
            current = m.group(1) if m.group(1) in names else None
        elif current and re.match(r"^\s+[0-9a-f]+:\s", line):
            sizes[current] = sizes.get(current, 0) + 1
    return sizes


def host_frame_us(kind, cfg, count=20000):
    proto = GloveProtocol(cfg)
    glove = make_glove_emulator(kind, cfg, interface="virtual", channel=f"bench-fw-{uuid.uuid4().hex}",
                                clock=lambda: 1000.0)
    glove.process(proto.nmt("START"), 1000.0)
    frames = [proto.duty(1 + k % 4, [(k + c) % 128 for c in range(8)], k) for k in range(256)]
    t0 = time.perf_counter()
    for k in range(count):
        glove.process(frames[k % 256], 1000.0 + k * 1e-5)
    dt = (time.perf_counter() - t0) / count * 1e6
    glove.stop()
    return dt


def main():
    cfg = load_glove_can(DEFAULT_GLOVE)
    out = build(cfg, "bluepill")
    size = subprocess.run(["arm-none-eabi-size", str(out / "bluepill" / "touch4d-board.elf")], capture_output=True,
                          text=True, check=True).stdout.splitlines()[1].split()
    text, data, bss = (int(x) for x in size[:3])
    print(f"STM32F103C8 image (default glove, node id from straps): flash {text + data} of 65536 bytes, "
          f"RAM {data + bss} of 20480 bytes and a 2048-byte stack")

    build(cfg, "qemu")
    check = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), "check-qemu", f"BUILD={out}"], capture_output=True,
                           text=True, check=True).stdout
    m = dict((k, int(v)) for k, v in re.findall(r"^MEASURE (\w+) (\d+)$", check, re.M))
    assert "END 0" in check, check
    print("core on the Cortex-M3 (qemu stm32vldiscovery, -icount), instructions:")
    for k in ("receive_duty_all_channels_change", "receive_unknown_id", "receive_other_board_frame",
              "tick_three_frames", "tick_idle"):
        print(f"  {k:36s} {m[k]:5d}")
    print(f"  baseline: generated unpack alone      {m['baseline_generated_unpack']:5d}  "
          f"(a whole duty frame applied = {m['receive_duty_all_channels_change'] / m['baseline_generated_unpack']:.1f}x)")

    board = function_sizes(out / "bluepill" / "touch4d-board.elf",
                           {"main", "can_receive", "can_send", "outputs_write", "clock_micros"})
    print("board layer (STM32F103 image), instructions per function:", dict(sorted(board.items())))
    # One loop iteration after the FIFO was found empty: the rest of main's body, the worst tick
    # and its three sends; then three frames read, two earlier duty frames and ours applied.
    frame = board["can_receive"] + m["receive_duty_all_channels_change"]
    loop = board["main"] + 2 * board["clock_micros"]
    cases = (("read at once", frame),
             ("idle bus, just after the FIFO check", loop + m["tick_idle"] + frame),
             ("worst case", loop + m["tick_three_frames"] + 3 * board["can_send"] + 3 * frame))
    for what, n in cases:
        print(f"  duty frame -> compare registers, {what}: {n} instructions = "
              f"{n * 1.5 / CPU_HZ * 1e6:.1f} us at 1.5 cycles/instruction, <= {n * 3 / CPU_HZ * 1e6:.1f} us at 3; "
              f"the PWM output follows within {PWM_PERIOD_US:.0f} us more")

    py, fw = host_frame_us("python", cfg), host_frame_us("firmware", cfg)
    print(f"host, one duty frame into a 4-board glove: firmware core (ctypes) {fw:.1f} us, "
          f"Python emulator {py:.1f} us (ratio {fw / py:.2f})")


if __name__ == "__main__":
    main()

"""The glove's CAN protocol, written down as a DBC database generated from the glove config.

A DBC cannot template node ids, so the database is built per glove: for every board with node id
N (CANopen-style id bases, configurable in `can.ids`):

- `NMT` at `ids.stop` (0x000, the highest priority on the bus), controller -> all boards:
  `Command` (1 START, 2 STOP, 0x80 PRE_OPERATIONAL, 0x81 RESET_NODE) and `Node` (0 = every board).
  `Command=STOP, Node=0` is the broadcast stop: every channel off at once, duty frames ignored
  until START.
- `Duty_BN` at `ids.duty + N` (RPDO1 style), controller -> board, every `1/refresh_hz`:
  `Counter` (8 bit, rolling) then one 7-bit `Duty_ChK` per channel (0..127 = 0..100 % PWM).
  8 channels x 7 bit + 8 bit = 64 bit: a whole board's update fits one classic 8-byte frame, so
  a board never applies half an update, and the counter lets the board's status acknowledge it
  (a board applies a frame only if its counter is newer than the last applied: emulator.py).
  128 levels are finer than a coin motor's felt resolution.
- `Status_BN` at `ids.status + N` (TPDO1 style), board -> controller, every `1/status_hz` and on
  a change of state: `State`, fault flags, `LastCounter` (counter of the last duty frame applied),
  `ActiveMask` (channels on), `BadFrames` (malformed, unknown or out-of-sequence frames received, saturating).
- `Heartbeat_BN` at `ids.heartbeat + N` (0x700 + N), board -> controller, every `1/heartbeat_hz`:
  the CANopen NMT state byte (0 boot-up, 4 stopped, 5 operational, 127 pre-operational).
"""
from __future__ import annotations

import cantools
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from touch4d.boards.config import GloveCan

CONTROLLER = "Controller"
DUTY_BITS = 7
DUTY_LEVELS = (1 << DUTY_BITS) - 1  # 127: the raw value of 100 % duty

NMT_COMMANDS = {1: "START", 2: "STOP", 0x80: "PRE_OPERATIONAL", 0x81: "RESET_NODE"}
NMT_STATES = {0: "BOOTUP", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE_OPERATIONAL"}
OUTPUT_STATES = {0: "IDLE", 1: "ACTIVE", 2: "WATCHDOG_OFF", 3: "STOPPED", 4: "FAULT_OFF", 5: "PRE_OPERATIONAL"}
FAULT_FLAGS = ("Watchdog", "BadFrame", "Overtemp", "Overcurrent", "Undervoltage")


def board_node(board_id: int) -> str:
    return f"Board{board_id}"


def _signal(name, start, length, comment, receivers, choices=None, scale=1, maximum=None, unit=None):
    conversion = BaseConversion.factory(scale=scale, offset=0, choices=choices, is_float=False)
    return Signal(name, start, length, conversion=conversion, minimum=0,
                  maximum=maximum if maximum is not None else (1 << length) - 1,
                  unit=unit, comment=comment, receivers=list(receivers))


def _ms(hz: float) -> int:
    return max(1, round(1000.0 / hz))


def build_database(cfg: GloveCan) -> Database:
    """The cantools database of the glove's protocol (see the module doc for the frames)."""
    boards = [board_node(b.id) for b in cfg.boards]
    messages = [Message(
        cfg.ids.stop, "NMT", 2, [
            _signal("Command", 0, 8, "NMT command; STOP turns every channel off at once", boards,
                    choices=NMT_COMMANDS),
            _signal("Node", 8, 8, "target node id, 0 = every board", boards),
        ],
        senders=[CONTROLLER],
        comment="Network management (CANopen style). Command=STOP Node=0 is the broadcast stop.",
    )]
    for b in cfg.boards:
        node = board_node(b.id)
        signals = [_signal("Counter", 0, 8, "rolling counter, +1 per frame sent, echoed in LastCounter", [node])]
        for c in range(b.channels):
            signals.append(_signal(f"Duty_Ch{c}", 8 + DUTY_BITS * c, DUTY_BITS, f"PWM duty of channel {c}",
                                   [node], scale=1 / DUTY_LEVELS, maximum=1, unit="1"))
        messages.append(Message(
            cfg.ids.duty + b.id, f"Duty_B{b.id}", (8 + DUTY_BITS * b.channels + 7) // 8, signals,
            senders=[CONTROLLER], cycle_time=_ms(cfg.refresh_hz),
            comment=f"PWM duty of every channel of board {b.id}; no frame for "
                    f"{round(cfg.board_watchdog_s * 1000)} ms turns every channel off",
        ))
        status = [_signal("State", 0, 8, "output state", [CONTROLLER], choices=OUTPUT_STATES)]
        status += [_signal(f"Fault_{f}", 8 + i, 1, f"fault flag {f}", [CONTROLLER])
                   for i, f in enumerate(FAULT_FLAGS)]
        status += [
            _signal("LastCounter", 16, 8, "Counter of the last duty frame applied", [CONTROLLER]),
            _signal("ActiveMask", 24, 8, "bit K set: channel K is on", [CONTROLLER]),
            _signal("BadFrames", 32, 16, "malformed, unknown or out-of-sequence frames received, saturating", [CONTROLLER]),
        ]
        messages.append(Message(
            cfg.ids.status + b.id, f"Status_B{b.id}", 6, status, senders=[node],
            cycle_time=_ms(cfg.status_hz), comment=f"status of board {b.id}, periodic and on change",
        ))
        messages.append(Message(
            cfg.ids.heartbeat + b.id, f"Heartbeat_B{b.id}", 1,
            [_signal("State", 0, 8, "NMT state", [CONTROLLER], choices=NMT_STATES)],
            senders=[node], cycle_time=_ms(cfg.heartbeat_hz), comment=f"CANopen heartbeat of board {b.id}",
        ))
    return Database(messages=messages, nodes=[Node(CONTROLLER)] + [Node(n) for n in boards],
                    version="touch4d-glove-1", strict=True)


def dbc_text(cfg: GloveCan) -> str:
    """The DBC file of this glove, for firmware authors and `touch4d glove dbc` (Unix line ends)."""
    return build_database(cfg).as_dbc_string().replace("\r\n", "\n")


def load_dbc(text: str) -> Database:
    """Load a DBC text with cantools (strict: overlapping or out-of-frame signals are errors)."""
    return cantools.database.load_string(text, database_format="dbc", strict=True)

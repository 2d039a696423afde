"""System messages: motor status, the safety stop, node heartbeats and window input."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import Array, Bool, Float, Int, IntList, Map, Message, Records, Str, StrList, spec

BOARD_STATUS = Records(
    {"id": Int(), "online": Bool(), "faults": StrList(), "last_frame": Float(), "state": Str()},
)


@dataclass(kw_only=True)
class MotorStatus(Message):
    """What the motor node knows of the glove's boards (topic motors/status)."""

    boards: list = spec(
        BOARD_STATUS,
        "per board: CAN node id, online (answered within its timeout), fault names, stamp of the last "
        "frame heard, state ('operational', 'stopped', 'offline', ...)",
    )
    duty: np.ndarray = spec(Array((None,)), "last PWM duty sent per motor, 0..1, glove config order")
    bus_load: float = spec(Float(), "CAN bus load of the configuration, 0..1 of the bitrate")
    errors: dict = spec(Map(), "counters: send errors, bus-off, queue full, malformed frames, ...")


@dataclass(kw_only=True)
class Stop(Message):
    """All motors off, now (topic safety/stop); anyone may publish it."""

    reason: str = spec(Str(), "why, for the log")
    origin: str = spec(Str(), "name of the node or tool that asked")


@dataclass(kw_only=True)
class Heartbeat(Message):
    """A node says it is alive, once a second (topic node/heartbeat)."""

    node: str = spec(Str(), "node name (its role in the launch file)")
    pid: int = spec(Int(), "process id")
    kind: str = spec(Str(), "node module in touch4d.nodes")
    publishes: list = spec(StrList(), "topics it publishes")
    subscribes: list = spec(StrList(), "topics it subscribes")
    stats: dict = spec(Map(), "counters: received, dropped, malformed, gaps, ...")


@dataclass(kw_only=True)
class InputEvents(Message):
    """Keyboard and mouse of the renderer window (topic ui/input), to steer a desktop hand."""

    keys_down: list = spec(StrList(), "keys held, lower-case names: 'w', 'left', 'space', 'left_shift'")
    pressed: list = spec(StrList(), "keys pressed since the previous message")
    mouse: np.ndarray = spec(Array((2,)), "pointer position in window pixels")
    mouse_delta: np.ndarray = spec(Array((2,)), "pointer motion since the previous message, pixels")
    buttons: list = spec(IntList(), "mouse buttons held (1 left, 2 right, 3 middle)")
    scroll: float = spec(Float(), "scroll since the previous message")


@dataclass(kw_only=True)
class MotorTrace(Message):
    """When each motor command reached the CAN bus (topic motors/trace), for latency measurements.

    Published in batches by the motor node when its `trace` parameter is on."""

    source_stamps: np.ndarray = spec(Array((None,)), "source_stamp (hand/pose stamp) of each command sent")
    frame_times: np.ndarray = spec(Array((None,)), "wall-clock time its last duty frame was on the bus, s")

    def check(self):
        if len(self.source_stamps) != len(self.frame_times):
            raise ValueError("frame_times: expected one per source stamp")

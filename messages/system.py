"""System messages: motor status, the safety stop, node heartbeats and window input."""
from .base import Array, Float, Map, Message, Records, doc

BoardStatus = Records(id=int, online=bool, faults=list[str], last_frame=Float, state=str)


class MotorStatus(Message):
    """What the motor node knows of the glove's boards (topic motors/status)."""

    boards: BoardStatus = doc(
        "per board: CAN node id, online (answered within its timeout), fault names, stamp of the last "
        "frame heard, state ('operational', 'stopped', 'offline', ...)",
    )
    duty: Array(None) = doc("last PWM duty sent per motor, 0..1, glove config order")
    bus_load: Float = doc("CAN bus load of the configuration, 0..1 of the bitrate")
    errors: Map = doc("counters: send errors, bus-off, queue full, malformed frames, ...")


class Stop(Message):
    """All motors off, now (topic safety/stop); anyone may publish it."""

    reason: str = doc("why, for the log")
    origin: str = doc("name of the node or tool that asked")


class Heartbeat(Message):
    """A node says it is alive, once a second (topic node/heartbeat)."""

    node: str = doc("node name (its role in the launch file)")
    pid: int = doc("process id")
    kind: str = doc("node module in touch4d.nodes")
    publishes: list[str] = doc("topics it publishes")
    subscribes: list[str] = doc("topics it subscribes")
    stats: Map = doc("counters: received, dropped, malformed, gaps, ...")


class InputEvents(Message):
    """Keyboard and mouse of the renderer window (topic ui/input), to steer a desktop hand."""

    keys_down: list[str] = doc("keys held, lower-case names: 'w', 'left', 'space', 'left_shift'")
    pressed: list[str] = doc("keys pressed since the previous message")
    mouse: Array(2) = doc("pointer position in window pixels")
    mouse_delta: Array(2) = doc("pointer motion since the previous message, pixels")
    buttons: list[int] = doc("mouse buttons held (1 left, 2 right, 3 middle)")
    scroll: Float = doc("scroll since the previous message")


class MotorTrace(Message):
    """When each motor command reached the CAN bus (topic motors/trace), for latency measurements.

    Published in batches by the motor node when its `trace` parameter is on."""

    source_stamps: Array(None) = doc("source_stamp (hand/pose stamp) of each command sent")
    frame_times: Array(None) = doc("wall-clock time its last duty frame was on the bus, s")

    def check(self):
        if len(self.source_stamps) != len(self.frame_times):
            raise ValueError("frame_times: expected one per source stamp")

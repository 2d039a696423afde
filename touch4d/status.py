"""Live status of a running stack: topic rates, touched motors, pose-to-motor latency, glove boards.

Pure bookkeeping, fed by the monitor node (nodes/monitor.py) and formatted as one line.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from touch4d.bus.topology import shared_inputs
from touch4d.glovefile import DEFAULT_TOUCH_THRESHOLD
from touch4d.messages import Heartbeat, MotorCommand, MotorStatus, MotorTrace

NODE_TIMEOUT = 3.5  # s without a heartbeat after which a node counts as gone (they beat every second)
SETTLE = 2.5        # s of heartbeats heard before a topic is called unpublished (every live node has beaten)


@dataclass
class StackStatus:
    """Counts what passes on the bus over a sliding window of `window` seconds."""

    window: float = 2.0
    arrivals: dict[str, deque] = field(default_factory=dict)
    latencies: deque = field(default_factory=lambda: deque(maxlen=2000))   # (arrival, pose -> command)
    frame_latencies: deque = field(default_factory=lambda: deque(maxlen=2000))  # (arrival, pose -> CAN frame)
    touched: int = 0
    touch_threshold: float = DEFAULT_TOUCH_THRESHOLD   # the glove file's: a motor above it is touched
    motors: int = 0
    boards_online: int | None = None
    boards: int | None = None
    bus_load: float | None = None
    nodes: dict[str, tuple[float, Heartbeat]] = field(default_factory=dict)  # name -> (heard at, last beat)
    first_beat: float | None = None

    def on_message(self, topic: str, now: float) -> None:
        times = self.arrivals.setdefault(topic, deque())
        times.append(now)
        while times and times[0] < now - self.window:
            times.popleft()

    def on_motors(self, msg: MotorCommand, now: float) -> None:
        self.touched = int(np.count_nonzero(msg.intensity > self.touch_threshold))
        self.motors = len(msg.intensity)
        if msg.source_stamp > 0:
            # Stamped by the tactile node when it published: the monitor's own wake-up (it runs at
            # normal priority beside the renderer) does not count.
            self.latencies.append((now, msg.stamp - msg.source_stamp))

    def on_trace(self, msg: MotorTrace, now: float) -> None:
        """When the motor node traces commands: pose -> duty frame on the CAN bus, per command."""
        for lat in (msg.frame_times - msg.source_stamps).tolist():
            self.frame_latencies.append((now, lat))

    def on_motor_status(self, msg: MotorStatus) -> None:
        self.boards = len(msg.boards)
        self.boards_online = sum(1 for b in msg.boards if b["online"])
        self.bus_load = msg.bus_load

    def on_heartbeat(self, msg: Heartbeat, now: float) -> None:
        self.nodes[msg.node] = (now, msg)
        if self.first_beat is None:
            self.first_beat = now

    def unpublished(self, now: float) -> dict[str, list[str]]:
        """Topics some live node subscribes to (not optionally) that no live node publishes and on
        which nothing arrived within the window: topic -> the nodes waiting for it."""
        if self.first_beat is None or now - self.first_beat < SETTLE:
            return {}
        live = [hb for heard, hb in self.nodes.values() if now - heard <= NODE_TIMEOUT]
        published = {t for hb in live for t in hb.publishes}
        waiting: dict[str, list[str]] = {}
        for hb in live:
            for topic in hb.subscribes:
                if topic.endswith(("*", "?")) or topic in published or self.rate(topic, now) > 0:
                    continue
                waiting.setdefault(topic, []).append(hb.node)
        return {t: sorted(names) for t, names in sorted(waiting.items())}

    def shared(self, now: float) -> dict[str, list[str]]:
        """Inputs two or more live nodes publish: topic -> the publishers (touch4d.bus.topology)."""
        return shared_inputs(hb for heard, hb in self.nodes.values() if now - heard <= NODE_TIMEOUT)

    def rate(self, topic: str, now: float) -> float:
        times = self.arrivals.get(topic)
        if not times:
            return 0.0
        recent = [t for t in times if t >= now - self.window]
        return len(recent) / self.window

    def latency_ms(self, now: float, frames: bool = False) -> tuple[float, float] | None:
        """p50 and p99 over the window, milliseconds, of hand/pose -> tactile/motors published, or
        (frames) hand/pose -> duty frame on the CAN bus."""
        source = self.frame_latencies if frames else self.latencies
        recent = [lat for t, lat in source if t >= now - self.window]
        if not recent:
            return None
        p50, p99 = np.percentile(recent, [50, 99])
        return 1e3 * float(p50), 1e3 * float(p99)

    def hand_source(self, now: float) -> str | None:
        """Which hand a live tactile node follows (its heartbeat's `hand_joints`), or None."""
        for heard, beat in self.nodes.values():
            if now - heard <= NODE_TIMEOUT and "hand_joints" in beat.stats:
                return "fingers tracked (hand/joints)" if beat.stats["hand_joints"] else "rigid hand (hand/pose)"
        return None

    def line(self, now: float, topics: tuple[str, ...] = ("hand/pose", "scene/state", "tactile/motors")) -> str:
        parts = [f"{t} {self.rate(t, now):.0f} Hz" for t in topics]
        parts.append(f"touched {self.touched}/{self.motors} motors" if self.motors else "no motor command yet")
        hand = self.hand_source(now)
        if hand is not None:
            parts.append(hand)
        frames = self.latency_ms(now, frames=True)
        lat = frames or self.latency_ms(now)
        what = "pose->CAN" if frames else "pose->motors"
        parts.append(f"{what} p50 {lat[0]:.1f} ms p99 {lat[1]:.1f} ms" if lat else f"{what} -")
        if self.boards is not None:
            parts.append(f"boards {self.boards_online}/{self.boards} online, CAN load {100 * self.bus_load:.0f}%")
        shared = self.shared(now)
        if shared:
            parts.append("several publishers: " + ", ".join(f"{t} ({', '.join(n)})" for t, n in shared.items()))
        missing = self.unpublished(now)
        if missing:
            parts.append("no publisher: " + ", ".join(f"{t} ({', '.join(n)})" for t, n in missing.items()))
        return " | ".join(parts)

"""Study benchmark: a trial's stimulus onset (the stamp of the `study/trial` that opens the gate) ->
the first motor duty frame on the CAN bus with a motor on, and -> the first frame the renderer drew
with the object in it. Baseline in the same run: `hand/pose` -> its duty frame (as bench_e2e).

`scene` and `tactile` run as node processes. The motor node (emulated boards, `trace: true`) and the
renderer node (headless, EGL) run in threads of this process, so the bench reads the CAN frames on
the virtual bus itself (python-can's receive time) and the renderer's frames as they finish (the
bench's renderer waits for the GL to finish each frame before it notes the time). The bench
publishes poses at 90 Hz (the hand circling the tesseract's front vertex, so the motors run) and
alternates trials: `visual+touch` stimulus for `--on` s, idle for `--off` s.

    .venv/bin/python bench/bench_study_latency.py [--trials 40] [--on 0.3] [--off 0.2]
"""
from __future__ import annotations

import argparse
import tempfile
import threading
import time
import uuid
from pathlib import Path

import can
import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from bench_e2e import SCENE, bench_glove, ms, pose_at
from touch4d.boards.config import load_glove_can
from touch4d.boards.protocol import GloveProtocol
from touch4d.bus import Node
from touch4d.bus.testing import node_process, running_broker, wait_until
from touch4d.messages import HandPose, MotorTrace, StudyTrial
from touch4d.nodes.motors import MotorsNode
from touch4d.nodes.renderer import RendererNode

POSE_HZ = 90.0


class Spinner:
    """A node built and spun in its own thread of this process."""

    def __init__(self, make):
        self.node = None
        self.error = None
        self._stop = False
        self._ready = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(make,), daemon=True)
        self.thread.start()
        if not self._ready.wait(60) or self.error:
            raise RuntimeError(f"node did not start: {self.error}")

    def _run(self, make):
        try:
            self.node = make()
        except Exception as exc:  # noqa: BLE001 - reported to the caller
            self.error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            while not self._stop:
                self.step()
        finally:
            self.node.shutdown()

    def step(self):
        self.node.spin_once(0.002)

    def close(self):
        self._stop = True
        self.thread.join(10)


class CanGlove(Spinner):
    """The motor node and a listener on its virtual CAN channel: (receive time, any motor on) per duty frame."""

    def __init__(self, bus, glove_file: Path):
        self.channel = f"bench-study-{uuid.uuid4().hex}"
        cfg = load_glove_can(glove_file)
        self.protocol = GloveProtocol(cfg)
        self.channels = {b.id: b.channels for b in cfg.boards}
        self.frames: list[tuple[float, bool]] = []
        self.listener = can.Bus(interface="virtual", channel=self.channel)
        super().__init__(lambda: MotorsNode(params={"glove": str(glove_file), "channel": self.channel,
                                                    "emulate": True, "trace": True}, bus=bus))

    def step(self):
        self.node.spin_once(0.001)
        while (msg := self.listener.recv(0)) is not None:
            frame = self.protocol.decode(msg)
            if frame is not None and frame.kind == "duty":
                self.frames.append((msg.timestamp, any(self.protocol.levels(frame, self.channels[frame.board]))))

    def close(self):
        super().close()
        self.listener.shutdown()


class TimedRenderer(RendererNode):
    """The renderer node, noting when each frame is finished and whether its objects were drawn."""

    def setup(self):
        super().setup()
        self.drawn: list[tuple[float, bool]] = []

    def on_frame(self):
        super().on_frame()
        self.renderer.read()                     # the frame is finished on the GL when this returns
        self.drawn.append((time.time(), self.gate.objects and self.view.layer is not None))


def first_after(events: list[tuple[float, bool]], t0: float, t1: float) -> float | None:
    """The first event time in [t0, t1) whose flag is true."""
    for when, on in events:
        if t0 <= when < t1 and on:
            return when
    return None


def stats(name: str, values: np.ndarray, base_p99: float | None = None) -> None:
    p50, p99 = np.percentile(values, 50), np.percentile(values, 99)
    ratio = f"   {p99 / base_p99:5.2f}x the baseline's p99" if base_p99 else ""
    print(f"  {name:38s} p50 {ms(p50)} ms   p99 {ms(p99)} ms   max {ms(values.max())} ms   (n={len(values)}){ratio}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--on", type=float, default=0.3, help="stimulus phase, s")
    parser.add_argument("--off", type=float, default=0.2, help="idle phase between trials, s")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp, running_broker() as bus:
        glove_file = bench_glove(Path(tmp))
        with node_process("scene", bus, params={"scene": str(SCENE)}), \
                node_process("tactile", bus, params={"glove": str(glove_file)}):
            glove = CanGlove(bus, glove_file)
            render = Spinner(lambda: TimedRenderer(params={"headless": True, "width": 320, "height": 240,
                                                           "samples": 0, "rate": 60.0, "show_status": False},
                                                   bus=bus, heartbeat=False))
            probe = Node("bench", bus=bus, heartbeat=False)
            poses = probe.create_publisher("hand/pose", HandPose)
            trials = probe.create_publisher("study/trial", StudyTrial)
            traces: list[MotorTrace] = []
            probe.create_subscription("motors/trace", MotorTrace, traces.append)

            def trial(phase: str, index: int) -> StudyTrial:
                return StudyTrial(study="bench", participant="B", phase=phase, index=index, total=args.trials,
                                  condition="visual+touch", task="front", kind="front-element", stimulus="vertex",
                                  prompt="?", options=["face", "edge", "vertex"], time_limit_s=10.0)

            try:
                start = time.monotonic()
                next_pose = start
                # warm up: poses flow, the renderer has the scene, the gate starts closed
                trials.publish(trial("idle", 0))
                wait_until(lambda: render.node.view.layer is not None, timeout=60)
                onsets, ends = [], []
                phase_end = time.monotonic() + args.off
                phase, index = "idle", 0
                while index < args.trials or phase == "stimulus":
                    now = time.monotonic()
                    if now >= next_pose:
                        poses.publish(pose_at(now - start))
                        next_pose += 1.0 / POSE_HZ
                    if now >= phase_end:
                        if phase == "idle":
                            msg = trial("stimulus", index)
                            msg.stamp = time.time()
                            msg.onset = msg.stamp
                            trials.publish(msg)
                            onsets.append(msg.stamp)
                            phase, phase_end = "stimulus", now + args.on
                        else:
                            trials.publish(trial("idle", index + 1))
                            ends.append(time.time())
                            phase, phase_end = "idle", now + args.off
                            index += 1
                    probe.spin_once(max(0.0, min(next_pose, phase_end) - time.monotonic()))
                probe.spin(0.3)
            finally:
                probe.shutdown()
                render.close()
                glove.close()

    to_duty, to_frame = [], []
    for t0, t1 in zip(onsets, ends):
        duty = first_after(glove.frames, t0, t1)
        frame = first_after(render.node.drawn, t0, t1)
        if duty is not None:
            to_duty.append(duty - t0)
        if frame is not None:
            to_frame.append(frame - t0)
    inside = [(s, f) for tr in traces for s, f in zip(tr.source_stamps, tr.frame_times)
              if any(t0 <= s < t1 for t0, t1 in zip(onsets, ends))]
    base = np.array([f - s for s, f in inside])
    print(f"study latency: {len(onsets)} trials of {args.on:g} s (visual+touch), idle {args.off:g} s between; "
          f"poses at {POSE_HZ:g} Hz; scene and tactile as processes, motors and renderer as threads here")
    if len(base) == 0:
        print("  no hand/pose -> duty frame traced: no baseline")
        return
    b99 = float(np.percentile(base, 99))
    stats("baseline: hand/pose -> its duty frame", base)
    if to_duty:
        stats("onset -> first duty frame with a motor on", np.array(to_duty), b99)
    print(f"  trials whose onset gave no duty frame with a motor on: {len(onsets) - len(to_duty)}")
    if to_frame:
        stats("onset -> first drawn frame with the object", np.array(to_frame), b99)
    print(f"  trials with no frame drawn with the object: {len(onsets) - len(to_frame)}")


if __name__ == "__main__":
    main()

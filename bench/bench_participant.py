"""One served participant's per-input CPU, without sockets: what `touch4d study serve` spends in a
participant's process for each `input` message its page sends at 72 Hz.

The process of launch/study-serve.yaml is wired here in one thread, as its nodes wire it: a
WebBridge (tracker, controller grip, config/calibration.yaml's hand_in_grip, a touch trial running)
with the tactile engine of config/gloves/quest-controller.yaml on the hypercube scene, and the
haptic loop's private topics handed over in-process as touch4d.bus.local does (each message checked
and encoded once by its publisher, decoded without a second check by each subscriber: hand/pose by
the page's node, the tactile model and the study node; controller/state by the scene node;
tactile/field by the page's node; tactile/motors by the page's node and the study node). The page's
inputs are bench/bench_serve.py's: the grip in and out of the hypercube's front cell every 300 ms,
at 72 Hz on a simulated clock, and the bridge ticks at its deadlines (WebBridge.next_due, as the
node's `call_later` does, a millisecond's slack after each): a change's frame, stale checks; the
study node measures each pose and motor command (touch4d.study.measures, as in a trial's stimulus).
Not here: the sockets (the page server on the node's loop), the executor, the scene node's handling of
controller/state (nothing while the trigger is released), the recorder.

Figures, CPU microseconds per input (time.process_time: other load on the machine is not counted;
the best of a few repeats): the whole path; then the same path with each stage timed (its own time,
without the stages it calls, the least over the repeats: the timing adds some, shown as "timing
overhead", so the stages are a guide to where the time goes, not a sum); the baseline
measured in the same run is the empty driver loop (the same events, no work). And one frame's
packing beside its previous form in the same run: every field JSON-encoded each frame.

`--paced N K`: instead, N participants at once at the page's real rate (72 Hz, sleeping between
inputs, as a served participant's process does), first each in a process of its own (the
baseline), then K to a process (a container, touch4d.bus.container), and the CPU per input of each:
what sharing a process saves when the code's caches are not kept warm by a tight loop.

    .venv/bin/python bench/bench_participant.py [--inputs 3000] [--repeat 3] [--paced 16 8]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

import touch4d.web.bridge as bridge_module
from touch4d.geometry.scene import load_scene
from touch4d.messages import ControllerState, HandPose, MotorCommand, StudyTrial, TactileField
from touch4d.study.measures import TrialMeasures
from touch4d.tactile.engine import HandSource, TactileEngine
from touch4d.tactile.glove import load_glove
from touch4d.tracking import webxr
from touch4d.tracking.calibration import load_calibration, load_placement
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.protocol import json_members, pack_frame, unpack_frame

REPO = Path(__file__).resolve().parents[1]
GLOVE = REPO / "config/gloves/quest-controller.yaml"
SCENE = REPO / "config/scenes/hypercube.yaml"
CALIBRATION = REPO / "config/calibration.yaml"
RATE_HZ, TOGGLE_S = 72.0, 0.3
SLACK_S = 0.001   # a deadline runs this long after its time (call_later adds touch4d.bus.executor.TIMER_SLACK)
INSIDE = [0.0, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]      # the grip at the screen's centre: in the front cell
OUTSIDE = [0.6, 1.2, -0.45, 0.0, 0.0, 0.0, 1.0]     # beside the screen
HEAD = [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0]
CONN = 1


class Stages:
    """Exclusive CPU time per stage: a stage's time without the stages it calls."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.stack: list[list] = []          # [name, started, time in children]

    def wrap(self, name: str, fn):
        def timed(*args, **kwargs):
            self.stack.append([name, time.process_time(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                name_, t0, children = self.stack.pop()
                spent = time.process_time() - t0
                self.seconds[name_] = self.seconds.get(name_, 0.0) + spent - children
                if self.stack:
                    self.stack[-1][2] += spent
        return timed


def page_inputs(n: int) -> list[tuple[float, str]]:
    """(arrival, text) of `n` page inputs at 72 Hz, the grip in and out of the front cell every 300 ms."""
    out = []
    for k in range(n):
        t = k / RATE_HZ
        grip = INSIDE if int(t / TOGGLE_S) % 2 == 0 else OUTSIDE
        out.append((t, json.dumps({"type": "input", "time": 1000.0 * (1.7e9 + t), "tracking": True, "head": HEAD,
                                   "sources": [{"handedness": "right", "grip": grip, "trigger": 0.0, "buttons": [],
                                                "joints": None}]})))
    return out


def events(n: int) -> list[tuple[float, str]]:
    """The page's inputs, in time order (the bridge's deadlines come between them: Participant.run)."""
    return page_inputs(n)


class Participant:
    """The participant's nodes in one thread, the private topics handed over in-process."""

    def __init__(self, stages: Stages | None = None):
        self.clock = 1.7e9   # the simulated clock (the inputs arrive from here on)
        glove = load_glove(GLOVE)
        wrap = stages.wrap if stages is not None else (lambda name, fn: fn)
        self.engine = TactileEngine(glove, joints=False)
        self.engine.set_scene(load_scene(SCENE).to_message())
        self.hand = HandSource(self.engine)
        # the study node's share: in a trial's stimulus its machine measures every pose and motor command
        self.measures = TrialMeasures(threshold=glove.touch_threshold)
        self.frames = 0
        self.bridge = WebBridge(BridgeConfig(tracker=True, hand="right", hand_source="controller",
                                             controller_hand="right", study_gate="closed", stale_s=0.06),
                                glove, load_calibration(CALIBRATION, "hand_in_grip"), load_placement(CALIBRATION),
                                publish=wrap("bridge: publish", self.publish), broadcast=self.broadcast,
                                send=lambda conn, data: None, now=lambda: self.clock)
        b = self.bridge
        b.on_scene(load_scene(SCENE).to_message())
        b.on_trial(StudyTrial(study="bench", participant="P01", phase="stimulus", index=0, total=10,
                              condition="touch", options=["a", "b"], onset=1.0))
        self.subscribers = {   # topic -> (type, callback) per subscribing node, as the nodes subscribe
            "hand/pose": [(HandPose, wrap("bridge: on_hand_pose", b.on_hand_pose)),
                          (HandPose, wrap("tactile: on_pose", self.on_pose)),
                          (HandPose, wrap("study: pose", self.on_study_pose))],
            "controller/state": [(ControllerState, None)],
            "tactile/field": [(TactileField, wrap("bridge: on_field", b.on_field))],
            "tactile/motors": [(MotorCommand, wrap("bridge: on_motors", b.on_motors)),
                               (MotorCommand, wrap("study: motors", self.on_study_motors))],
        }
        self.encode = wrap("publish: check + encode", lambda msg, seq: msg.publish_payload(seq))
        self.decode = wrap("decode", lambda cls, payload: cls._decode(payload))
        self.seq = 0
        if stages is not None:
            # the library functions the path calls, timed where the bridge and the engine look them up
            bridge_module.parse_page_message = wrap("parse page message", _PARSE)
            webxr.hand_pose = wrap("hand pose", _HAND_POSE)
            webxr.controller_state = wrap("controller state", _CONTROLLER_STATE)
            self.engine.messages = wrap("tactile: stimulus + messages", self.engine.messages)
            b.frame = wrap("bridge: frame", b.frame)
            b.tick = wrap("bridge: tick", b.tick)
            b.page_message = wrap("bridge: page message", b.page_message)
        b.connected(CONN, "bench")

    def publish(self, topic: str, msg) -> None:
        """A private topic: checked and encoded once, each subscriber's copy decoded (no second check)."""
        payload = self.encode(msg, self.seq)
        self.seq += 1
        for cls, callback in self.subscribers[topic]:
            copy = self.decode(cls, payload)
            if callback is not None:
                callback(copy)

    def on_pose(self, msg: HandPose) -> None:
        """The tactile node's on_pose: the stimulus, then tactile/field and tactile/motors."""
        out = self.hand.on_pose(msg)
        if out is not None:
            field, motors = out
            if field is not None:
                self.publish("tactile/field", field)
            self.publish("tactile/motors", motors)

    def on_study_pose(self, msg: HandPose) -> None:
        self.measures.add_pose(msg.stamp, msg.position, msg.valid)

    def on_study_motors(self, msg: MotorCommand) -> None:
        self.measures.add_motors(msg.stamp, msg.intensity)

    def broadcast(self, frame: bytes, latest: bool) -> None:
        self.frames += 1

    def run(self, timeline: list) -> tuple[float, int]:
        """CPU seconds for the timeline's events, and the inputs among them."""
        b, n = self.bridge, 0
        t0 = time.process_time()
        for t, text in timeline:
            arrival = 1.7e9 + t
            while (due := b.next_due()) <= arrival:   # the node's deadline, before this input came
                self.clock = max(self.clock, due + SLACK_S)
                b.tick()
            self.clock = arrival
            b.page_message(CONN, text, self.clock)
            n += 1
        return time.process_time() - t0, n


_PARSE, _HAND_POSE, _CONTROLLER_STATE = bridge_module.parse_page_message, webxr.hand_pose, webxr.controller_state


def restore() -> None:
    """The library functions as they were before a Participant timed them."""
    bridge_module.parse_page_message, webxr.hand_pose, webxr.controller_state = _PARSE, _HAND_POSE, _CONTROLLER_STATE


def empty_loop(timeline: list) -> float:
    """The driver alone: the same events, nothing done with them."""
    sink = []
    t0 = time.process_time()
    for t, text in timeline:
        sink.append((1.7e9 + t, text))
    return time.process_time() - t0


PER_FRAME = ("n", "hand_valid", "haptic", "time", "hand_source")   # the frame's fields that change every frame


def frame_packing(p: Participant, number: int, repeat: int) -> tuple[float, float]:
    """CPU us to pack one of the participant's frames: its rarely changing fields encoded beforehand
    (as the bridge does), and every field encoded each time (the previous form)."""
    p.bridge.on_hand_pose(HandPose(position=np.zeros(3), valid=True))
    header, arrays = unpack_frame(p.bridge.frame())
    header.pop("kind")
    fields = {k: header.pop(k) for k in PER_FRAME}
    members = json_members(header)
    out = []
    for make in (lambda: pack_frame("frame", fields, arrays, members),
                 lambda: pack_frame("frame", {**fields, **header}, arrays)):
        best = float("inf")
        for _ in range(repeat):
            t0 = time.process_time()
            for _ in range(number):
                make()
            best = min(best, (time.process_time() - t0) / number * 1e6)
        out.append(best)
    return out[0], out[1]


def paced(k: int, seconds: float) -> float:
    """CPU us per input of `k` participants in this process, each at 72 Hz in real time (their inputs
    interleaved, the process asleep between rounds), over `seconds` after a second's warm-up."""
    participants = [Participant() for _ in range(k)]
    timeline = page_inputs(int((seconds + 1.0) * RATE_HZ))
    spent, counted = 0.0, 0
    start = time.monotonic()
    for i, (t, text) in enumerate(timeline):
        arrival = 1.7e9 + t
        for p in participants:
            b = p.bridge
            t0 = time.thread_time()
            while (due := b.next_due()) <= arrival:
                p.clock = max(p.clock, due + SLACK_S)
                b.tick()
            p.clock = arrival
            b.page_message(CONN, text, p.clock)
            if t >= 1.0:
                spent += time.thread_time() - t0
                counted += 1
        time.sleep(max(0.0, start + (i + 1) / RATE_HZ - time.monotonic()))
    return spent / max(counted, 1) * 1e6


def run_paced(n: int, k: int, seconds: float) -> None:
    """N participants as N processes of one, then as processes of K: CPU us per input of each."""
    def layout(per: int) -> float:
        counts = [per] * (n // per) + ([n % per] if n % per else [])
        procs = [subprocess.Popen([sys.executable, __file__, "--paced-worker", str(c), str(seconds)],
                                  stdout=subprocess.PIPE, text=True) for c in counts]
        results = [(c, float(proc.communicate()[0].split()[-1])) for c, proc in zip(counts, procs)]
        return sum(c * us for c, us in results) / n

    one = layout(1)
    shared = layout(k)
    print(f"{n} participants at {RATE_HZ:.0f} Hz for {seconds:g} s, CPU time per page input (the path above, paced):")
    print(f"  baseline: a process each          {one:8.1f} us")
    print(f"  {k} to a process                   {shared:8.1f} us   ({shared / one:.2f}x)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inputs", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--paced", type=int, nargs=2, metavar=("N", "K"),
                    help="N participants at 72 Hz: a process each, then K to a process")
    ap.add_argument("--seconds", type=float, default=8.0, help="--paced: how long each layout runs")
    ap.add_argument("--paced-worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.paced_worker:
        print(f"{paced(int(args.paced_worker[0]), float(args.paced_worker[1])):.3f}")
        return
    if args.paced:
        run_paced(args.paced[0], args.paced[1], args.seconds)
        return
    timeline = events(args.inputs)
    n = args.inputs

    Participant().run(events(200))   # warm up (first frames, caches)
    whole, frames = [], 0
    for _ in range(args.repeat):
        p = Participant()
        p.run(events(50))
        seconds, _ = p.run(timeline)
        whole.append(seconds / n * 1e6)
        frames = p.frames
    empty = min(empty_loop(timeline) / n * 1e6 for _ in range(args.repeat))
    best = min(whole)

    per_stage: dict[str, float] = {}    # each stage's least time over the timed runs
    timed = float("inf")
    for _ in range(args.repeat):
        stages = Stages()
        p = Participant(stages)
        p.run(events(50))
        stages.seconds.clear()
        seconds, _ = p.run(timeline)
        restore()
        timed = min(timed, seconds / n * 1e6)
        for name, s in stages.seconds.items():
            per_stage[name] = min(per_stage.get(name, float("inf")), s / n * 1e6)

    print(f"one participant's process, per page input ({n} inputs at {RATE_HZ:.0f} Hz, ticks at the bridge's deadlines, "
          f"{frames} frames sent; CPU time, best of {args.repeat})")
    print(f"  whole path                         {best:8.1f} us   ({best / max(empty, 1e-9):.0f}x the empty loop, "
          f"{best * RATE_HZ / 1e4:.2f}% of a core at {RATE_HZ:.0f} Hz)")
    print(f"  baseline: empty driver loop        {empty:8.2f} us")
    steady, every = frame_packing(p, 3000, args.repeat)
    print(f"  a frame packed, its steady fields encoded once per change {steady:6.1f} us; every field each frame "
          f"(the previous form) {every:.1f} us ({steady / every:.2f}x)")
    print(f"  stages (own time, least of {args.repeat} timed runs; the least timed run: {timed:.1f} us in all)")
    total = sum(per_stage.values())
    for name, us in sorted(per_stage.items(), key=lambda kv: -kv[1]):
        print(f"    {name:34s} {us:8.1f} us  {us / total:6.1%}")
    print(f"    {'timing overhead':34s} {timed - best:8.1f} us")


if __name__ == "__main__":
    main()

"""The page's controller as the glove's output, on the node's side (no bus, no browser): the frame's
`haptic` follows tactile/motors, and is 0 whenever the glove would be off (study gate, invalid hand,
stale motors); what each page can vibrate is counted for the heartbeat."""
import json
import math
from pathlib import Path

import numpy as np

from touch4d.messages import HandPose, MotorCommand, StudyTrial
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import Placement, load_calibration
from touch4d.web.bridge import BridgeConfig, WebBridge
from touch4d.web.haptics import haptic_level
from touch4d.web.protocol import unpack_frame

REPO = Path(__file__).resolve().parents[1]
CONTROLLER = load_glove(REPO / "config/gloves/quest-controller.yaml")


class Rig:
    def __init__(self, glove=CONTROLLER, **config):
        self.t = 1000.0
        self.frames = []
        self.seen = 0
        config.setdefault("frame_period_s", 0.0)          # a frame each tick: the clock stands still here
        self.bridge = WebBridge(BridgeConfig(**config), glove,
                                load_calibration(REPO / "config/calibration.yaml", "hand_in_grip"), Placement(0.5, 0.3),
                                publish=lambda topic, msg: None,
                                broadcast=lambda data, latest: self.frames.append(unpack_frame(data)[0]),
                                send=lambda conn, data: None, now=lambda: self.t)

    def motors(self, *values):
        self.bridge.on_motors(MotorCommand(names=[f"m{i}" for i in range(len(values))],
                                           intensity=np.array(values, float)))

    def hand(self, valid=True):
        self.bridge.on_hand_pose(HandPose(position=np.zeros(3), valid=valid))

    def haptic(self):
        """The `haptic` of the last frame sent since the last look, the next tick included (None: no frame)."""
        self.bridge.tick()
        sent, self.seen = self.frames[self.seen:], len(self.frames)
        return sent[-1]["haptic"] if sent else None


def trial(condition, phase="stimulus"):
    return StudyTrial(study="s", participant="P01", phase=phase, index=0, total=2, condition=condition,
                      options=["a", "b"], onset=1.0 if phase == "stimulus" else 0.0)


def test_the_level_is_the_strongest_motor_clipped_to_0_1():
    assert haptic_level(np.array([0.25, 0.75, 0.125]), True) == 0.75
    assert haptic_level(np.array([1.6]), True) == 1.0
    assert haptic_level(np.array([-0.3]), True) == 0.0
    assert haptic_level(np.array([np.nan]), True) == 0.0
    assert haptic_level(np.array([0.5]), False) == 0.0
    assert haptic_level(np.zeros(0), True) == 0.0


def test_the_frame_carries_the_intensity_and_follows_it():
    rig = Rig()
    rig.hand()
    rig.motors(0.25)
    assert rig.haptic() == 0.25
    rig.motors(0.75)
    assert rig.haptic() == 0.75


def test_a_touch_starting_or_ending_is_sent_at_once_a_level_changing_at_the_tick():
    rig = Rig()
    rig.hand()
    rig.haptic()
    rig.motors(0.5)                                 # the touch starts: its frame without waiting for a tick
    assert [f["haptic"] for f in rig.frames[rig.seen:]] == [0.5]
    assert rig.haptic() == 0.5 and rig.haptic() is None
    rig.motors(0.75)                                # still touching: the next tick carries it
    assert rig.frames[rig.seen:] == []
    assert rig.haptic() == 0.75
    rig.motors(0.0)                                 # the touch ends: at once
    assert [f["haptic"] for f in rig.frames[rig.seen:]] == [0.0]


def test_a_closed_study_gate_sends_no_touch_at_once():
    rig = Rig(study_gate="closed")
    rig.hand()
    rig.haptic()
    rig.motors(0.5)
    assert rig.frames[rig.seen:] == []
    assert rig.haptic() == 0.0


def test_an_invalid_hand_gives_0():
    rig = Rig()
    rig.hand()
    rig.motors(0.5)
    assert rig.haptic() == 0.5
    rig.hand(valid=False)
    assert rig.haptic() == 0.0


def test_stale_motors_give_0_on_the_next_tick_without_any_new_message():
    rig = Rig(motors_stale_s=0.06)
    rig.hand()
    rig.motors(0.5)
    assert rig.haptic() == 0.5
    rig.t += 0.05
    assert rig.haptic() is None                    # fresh still, nothing changed: no frame
    rig.t += 0.02                                  # 70 ms since tactile/motors: stale
    assert rig.haptic() == 0.0
    rig.motors(0.375)
    assert rig.haptic() == 0.375


def test_the_study_gate_holds_the_controller_off_in_a_visual_trial_and_between_trials():
    rig = Rig(study_gate="closed")
    rig.hand()
    rig.motors(0.625)
    assert rig.haptic() == 0.0                      # a study's launch: closed until its first message
    rig.bridge.on_trial(trial("touch"))
    assert rig.haptic() == 0.625
    rig.bridge.on_trial(trial("visual"))
    rig.motors(0.625)
    assert rig.haptic() == 0.0
    rig.bridge.on_trial(trial("visual+touch"))
    rig.motors(0.625)
    assert rig.haptic() == 0.625
    rig.bridge.on_trial(trial("touch", phase="break"))
    assert rig.haptic() == 0.0


def test_what_pages_can_vibrate_is_counted_and_bad_outputs_are_dropped():
    rig = Rig()
    for conn in (1, 2, 3):
        rig.bridge.connected(conn)
    assert rig.bridge.haptic_outputs() == {"haptics_pulse": 0, "haptics_rumble": 0, "haptics_none": 0}
    for conn, output in ((1, "pulse"), (2, "none"), (3, "dual-rumble")):
        rig.bridge.page_message(conn, json.dumps({"type": "haptics", "output": output}), rig.t)
    assert rig.bridge.haptic_outputs() == {"haptics_pulse": 1, "haptics_rumble": 1, "haptics_none": 1}
    rig.bridge.page_message(3, json.dumps({"type": "haptics", "output": "buzz"}), rig.t)
    assert rig.bridge.counts["page_malformed"] == 1
    rig.bridge.closed(1)
    assert rig.bridge.haptic_outputs()["haptics_pulse"] == 0


def test_the_bridge_is_next_due_for_a_changes_frame_and_when_the_vibration_goes_stale():
    """WebBridge.next_due on a hand-moved clock: a change's frame at once, then no sooner than a frame
    period after the last; the frame that turns the controller to 0 motors_stale_s after the last
    tactile/motors; nothing at all when nothing waits (the node then sleeps until an event)."""
    rig = Rig(frame_period_s=0.01)
    t0 = rig.t
    rig.hand(True)
    assert rig.bridge.next_due() == -math.inf                # a change, and no frame yet
    assert rig.haptic() == 0.0 and rig.bridge.next_due() == math.inf
    rig.motors(0.5)                                          # a touch starts: its frame at once
    assert rig.frames[-1]["haptic"] == 0.5
    rig.seen = len(rig.frames)
    assert rig.bridge.next_due() == t0 + 0.06                # motors_stale_s after it
    rig.t = t0 + 0.004
    rig.motors(0.625)                                        # a level that only changes waits its period
    assert rig.bridge.next_due() == t0 + 0.01
    assert rig.haptic() is None                              # ticked too early: nothing sent
    rig.t = t0 + 0.01
    assert rig.haptic() == 0.625
    assert rig.bridge.next_due() == t0 + 0.004 + 0.06
    rig.t = t0 + 0.004 + 0.06 + 1e-6
    assert rig.haptic() == 0.0                               # stale: 0, within the deadline
    assert rig.bridge.next_due() == math.inf

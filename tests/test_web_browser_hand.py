"""A tracked hand in a real browser drives the glove with its fingers: Debian's chromium, a Quest 3
emulated by iwer with hand tracking (25 joints per hand), the stack of launch/webxr.yaml, the duty
frames read on the (virtual) CAN bus. Curling the fingers out of the object changes which motors run."""
import time

import numpy as np
import pytest

from test_web_browser import CENTER, browser, stack, tracker_page  # noqa: F401 - fixtures
from touch4d.bus.testing import collect, wait_until
from touch4d.messages import Heartbeat, MotorCommand

pytestmark = pytest.mark.timeout(150)

# The hypercube's front cell fills the screen's cube [-0.6, 0.6]^3 (0.3 m in the room). iwer's right
# hand, set 0.15 m toward the viewer from the screen's centre, reaches into it with its fingers
# only: the wrist and the knuckles stay outside (screen z > 0.6), the relaxed fingers' tips reach
# z ~ 0.4. Pointing keeps the index in and curls the middle, ring and little fingers out.
HAND = (CENTER[0], CENTER[1], CENTER[2] + 0.15)


def board_on_since(glove, board, t):
    with glove.lock:
        return any(on for when, b, on in glove.frames if when >= t and b == board)


def board_off_since(glove, board, t):
    with glove.lock:
        frames = [on for when, b, on in glove.frames if when >= t and b == board]
    return len(frames) >= 3 and not any(frames)


def test_the_tracked_hands_fingers_drive_the_glove_and_pointing_changes_which_motors_run(browser, stack):
    watcher, glove = stack["watcher"], stack["glove"]
    commands = collect(watcher, "tactile/motors", MotorCommand, latest_only=True)
    beats = collect(watcher, "node/heartbeat", Heartbeat)
    page = tracker_page(browser, stack["url"])
    try:
        page.evaluate("xr.primaryInputMode = 'hand'")
        page.evaluate(f"xr.hands.right.position.set{HAND}")

        def motors_on():
            return {n for n, v in zip(commands[-1].names, commands[-1].intensity) if v > 0} if commands else set()

        relaxed = wait_until(lambda: (on := motors_on()) and any(n.startswith("ring-") for n in on) and on,
                             timeout=30, spin=watcher)
        # the fingers touch, the palm (outside the object) does not: the samples follow the joints
        assert {"middle-front-distal", "ring-front-distal"} <= relaxed
        assert not any(n.startswith(("palm-", "back-")) for n in relaxed)
        t0 = time.time()
        wait_until(lambda: board_on_since(glove, 4, t0), timeout=10)       # ring and little on board 4
        tactile = wait_until(lambda: [b for b in beats if b.node == "tactile" and b.stats.get("joints", 0) > 0],
                             timeout=10, spin=watcher)[-1]
        assert tactile.stats["hand_joints"] == 1

        page.evaluate("xr.hands.right.poseId = 'point'")
        pointing = wait_until(lambda: (on := motors_on()) and not any(n.startswith(("ring-", "little-", "middle-"))
                                                                      for n in on) and on,
                              timeout=30, spin=watcher)
        assert any(n.startswith("index-") for n in pointing)               # the pointing index still touches
        t1 = time.time()
        wait_until(lambda: board_off_since(glove, 4, t1), timeout=10)      # ring and little off on the bus
        assert board_on_since(glove, 3, t1) or board_on_since(glove, 2, t1)   # the index's motors run
    finally:
        page.context.close()

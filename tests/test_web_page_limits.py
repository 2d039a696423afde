"""What one page may do, without a bus or a network: its inputs paced and only the latest kept,
its other messages bounded, re-centring at most once a second and only from the page in control
(which alone answers a study), the calibration file written at most so often and whole, positions
a room can hold, and what it sends escaped in the log within a warning budget of its own."""
import json
import logging
import threading

import numpy as np
import pytest

from touch4d.messages import HandJoints
from touch4d.tracking.calibration import load_calibration, save_screen_placement
from touch4d.web.inbox import Inbox
from touch4d.web.protocol import PageError, parse_page_message, printable

from test_study_web import trial
from test_web_bridge import REPO, Rig

pytestmark = pytest.mark.timeout(60)
HEAD = [0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0]


def recenter(rig, conn, head=HEAD):
    rig.bridge.page_message(conn, json.dumps({"type": "recenter", "head": head}), rig.clock.t)


# ---- the hand-over between the server's thread and the node's --------------------------------------


def test_inputs_are_paced_and_only_the_latest_is_handed_over():
    inbox = Inbox(input_hz=100.0)                          # one input per 10 ms at most
    assert inbox.offer("i0", 1.000, True) == (True, None)    # the first goes at once, the node is woken
    assert inbox.offer("i1", 1.001, True) == (False, pytest.approx(1.010))   # held for its time
    assert inbox.offer("i2", 1.002, True) == (False, pytest.approx(1.010))   # replaces it
    assert inbox.take() == [("i0", 1.000)]
    assert inbox.release(1.010) is True
    assert inbox.take() == [("i2", 1.002)] and inbox.replaced == 1
    # a node slower than the pace gets the newest input, not a backlog
    for k in range(1, 50):
        wake, at = inbox.offer(f"j{k}", 1.010 + 0.02 * k, True)
        assert at is None
    assert inbox.take() == [("j49", pytest.approx(1.990))] and inbox.replaced == 49
    assert inbox.take() == []


def test_other_messages_keep_their_order_within_a_bucket():
    inbox = Inbox(rate=10.0, burst=5)
    results = [inbox.offer(f"m{k}", 2.0, False) for k in range(8)]
    assert [wake for wake, _ in results] == [True] + [False] * 7   # one wake-up for the lot
    assert [d for d, _ in inbox.take()] == ["m0", "m1", "m2", "m3", "m4"] and inbox.dropped == 3
    assert inbox.offer("late", 2.2, False) == (True, None)   # 0.2 s refill two
    assert inbox.offer("error", 2.2, False, always=True) == (False, None)
    assert [d for d, _ in inbox.take()] == ["late", "error"]


def test_the_hand_over_is_bounded_whatever_the_page_sends():
    """Two threads: a page flooding as fast as it can, a node that takes now and then."""
    inbox = Inbox(input_hz=144.0)
    taken, stop = [], threading.Event()

    def node():
        while not stop.is_set():
            taken.append(len(inbox.take()))
            stop.wait(0.005)
    worker = threading.Thread(target=node)
    worker.start()
    t = 0.0
    for k in range(20000):
        t += 1e-5                                          # 100,000 messages per second
        inbox.offer("x", t, k % 2 == 0)
    stop.set()
    worker.join()
    taken.append(len(inbox.take()))
    # at most one input and a burst with its refill over the 0.2 s (page clock): never a backlog
    assert max(taken) <= 1 + 20 + 0.2 * 20
    assert sum(taken) <= 20 + 0.2 * 20 + 144 * 0.2 + 2


# ---- re-centring and answers ------------------------------------------------------------------------


def test_recentring_is_at_most_once_a_second_and_the_file_at_most_every_save_min_s():
    rig = Rig(tracker=True, save_min_s=5.0)
    rig.bridge.connected(1)
    rig.input(1)
    for _ in range(20000 // 100):                          # a flood: 200 in 0.2 s
        recenter(rig, 1)
        rig.clock.t += 0.001
    assert rig.bridge.counts["recentred"] == 1 and rig.bridge.counts["recenter_limited"] == 199
    assert len(rig.saved) == 1
    rig.clock.t += 1.0
    rig.input(1)
    recenter(rig, 1, [0.5, 1.7, 0.0, 0, 0, 0, 1])          # a second later: allowed, but not yet stored
    assert rig.bridge.counts["recentred"] == 2 and len(rig.saved) == 1
    rig.bridge.tick()
    assert len(rig.saved) == 1
    rig.clock.t += 5.0
    rig.bridge.tick()                                      # its time has come: the latest placement
    assert len(rig.saved) == 2 and np.allclose(rig.saved[-1].center_m, [0.5, 1.4, -0.5])
    rig.clock.t += 10.0
    rig.bridge.tick()
    assert len(rig.saved) == 2                             # nothing new: nothing written


def test_only_the_page_in_control_answers_or_recentres():
    rig = Rig(tracker=False)                               # view-only pages: nobody drives the hand
    rig.bridge.connected(1, "192.0.2.1:1")
    rig.bridge.connected(2, "192.0.2.2:2")
    rig.bridge.on_trial(trial())
    answer = {"type": "response", "index": 3, "option": "vertex", "time": 1e6}
    rig.bridge.page_message(2, json.dumps(answer), rig.clock.t)
    recenter(rig, 2)
    assert [m for t, m in rig.published if t == "study/response"] == [] and rig.bridge.counts["recentred"] == 0
    assert rig.bridge.counts["page_not_driver"] == 2
    told = [frame[0] for conn, frame in rig.sent if conn == 2 and frame[0]["kind"] == "driver"]
    assert told == [{"kind": "driver", "driver": False}]                  # told, but not who or where
    rig.bridge.page_message(1, json.dumps(answer), rig.clock.t)            # the page open longest
    (response,) = [m for t, m in rig.published if t == "study/response"]
    assert response.response == "vertex" and response.received == rig.clock.t
    rig.bridge.closed(1)
    rig.bridge.page_message(2, json.dumps(answer), rig.clock.t)            # now page 2 is in control
    assert len([m for t, m in rig.published if t == "study/response"]) == 2


def test_a_tracker_page_that_does_not_drive_cannot_answer():
    rig = Rig(tracker=True)
    rig.bridge.connected(1)
    rig.bridge.connected(2)
    rig.input(1)                                           # page 1 drives
    rig.bridge.on_trial(trial())
    rig.bridge.page_message(2, json.dumps({"type": "response", "index": 3, "option": "edge", "time": 1e6}),
                            rig.clock.t)
    rig.clock.t += 0.5                                     # page 1 silent: it no longer drives, but stays in control
    rig.bridge.page_message(2, json.dumps({"type": "response", "index": 3, "option": "face", "time": 1e6}),
                            rig.clock.t)
    recenter(rig, 2)
    assert [m for t, m in rig.published if t == "study/response"] == [] and rig.bridge.counts["recentred"] == 0


# ---- the calibration file ---------------------------------------------------------------------------


def test_a_saved_calibration_is_never_seen_half_written(tmp_path):
    path = tmp_path / "calibration.yaml"
    path.write_text((REPO / "config/calibration.yaml").read_text())
    path.chmod(0o640)
    calibration = load_calibration(path, "hand_in_grip")
    torn, stop = [], threading.Event()

    def reader():
        while not stop.is_set():
            text = path.read_text()
            if "center_m" not in text:
                torn.append(len(text))
    watcher = threading.Thread(target=reader)
    watcher.start()
    try:
        for k in range(300):
            save_screen_placement(path, calibration.placed_in_front(np.array([0.001 * k, 1.7, 0.0]),
                                                                    np.array([0, 0, 0, 1.0]), 0.5, 0.3))
    finally:
        stop.set()
        watcher.join()
    assert torn == []
    assert path.stat().st_mode & 0o777 == 0o640                            # its permissions kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.yaml"]   # no temporary file left


# ---- positions and the log ----------------------------------------------------------------------------


def test_positions_are_metres_a_room_can_hold():
    for head in ([1.7e308, 1.6, 0, 0, 0, 0, 1], [0, -1e6, 0, 0, 0, 0, 1]):
        with pytest.raises(PageError) as err:
            parse_page_message(json.dumps({"type": "recenter", "head": head}))
        assert "head" in str(err.value)
    joint = [0.0, 1.2, -1000.0, 0, 0, 0, 1, 0.01]
    with pytest.raises(PageError, match=r"joints"):
        parse_page_message(json.dumps({"type": "input", "time": 1, "tracking": True, "head": None, "sources": [
            {"handedness": "right", "trigger": 0, "buttons": [], "joints": [joint] * 25}]}))
    assert parse_page_message(json.dumps({"type": "recenter", "head": [99, 2, -99, 0, 0, 0, 1]}))["type"] == "recenter"


def test_what_a_page_sends_is_escaped_in_the_log(caplog):
    rig = Rig()
    rig.bridge.connected(1, "192.0.2.1:1")
    forged = '{"type": "stats", "fps": 1, "x\\n[tracker] INFO tracker: FAKE LINE\\u001b[31m\\u2028": 1}'
    with caplog.at_level(logging.WARNING, logger="touch4d.web.bridge"):
        rig.bridge.page_message(1, forged, rig.clock.t)
    (record,) = caplog.records
    text = record.getMessage()
    assert "\n" not in text and "\x1b" not in text and "\u2028" not in text
    assert "\\n[tracker] INFO tracker: FAKE LINE\\x1b[31m\\u2028" in text
    assert printable("ok\ttab\r\x00\x7f\x9b\u202e") == "ok\\ttab\\r\\x00\\x7f\\x9b\\u202e"


def test_a_page_cannot_use_up_the_warnings_of_another(caplog):
    rig = Rig()
    rig.bridge.connected(1, "192.0.2.1:1")
    rig.bridge.connected(2, "192.0.2.2:2")
    with caplog.at_level(logging.WARNING, logger="touch4d.web.bridge"):
        for k in range(100):                               # 100 distinct bad keys
            rig.bridge.page_message(1, json.dumps({"type": "stats", "fps": 1, f"bad{k}": 1}), rig.clock.t)
        rig.bridge.page_message(2, json.dumps({"type": "stats", "fps": -1}), rig.clock.t)
        rig.bridge.on_hand_joints(HandJoints(handedness="right", names=["wrist"], positions=np.zeros((1, 3)),
                                             orientations=np.array([[0, 0, 0, 1.0]]), radii=np.ones(1), valid=True))
    texts = [r.getMessage() for r in caplog.records]
    from_1 = [t for t in texts if t.startswith("page 1 ")]
    assert len(from_1) == 6 and "only counted" in from_1[-1]           # its budget: 5, and a last word
    assert any(t.startswith("page 2 ") and "fps" in t for t in texts)  # page 2's first problem is logged
    assert any(t.startswith("hand/joints not drawn") for t in texts)   # and so are the node's own
    assert rig.bridge.counts["page_malformed"] == 101


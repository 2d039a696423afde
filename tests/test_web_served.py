"""A served participant's session without a server or a browser (touch4d.web.served): synthetic page
messages on a fake clock drive a whole quick session, and what it wrote (trials.csv, the log, the
manifest) and sent the page (frames) is read back: the trial's condition gates the page's own touch,
a touch-only trial's stimulus reaches the page undrawn, the exploration columns come from the page's
batches (closed forms), a restart resumes at the first trial without a row, bad messages are counted."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from touch4d.log.reader import LogReader
from touch4d.study.design import load_study
from touch4d.study.plan import quick_plan
from touch4d.web.protocol import unpack_frame
from touch4d.web.served import ServedOptions, ServedSession, Shared

STUDY = "config/studies/paper.yaml"
OFFSET_S = 5.0          # the page's clock runs this much behind the server's (a headset's own clock)


class Page:
    """The fake clock, what the session sent the page, and the page's messages."""

    def __init__(self, tmp_path, participant="P01", **options):
        self.now = 1000.0
        self.frames: list[tuple[dict, dict]] = []
        self.study = load_study(STUDY)
        self.shared = Shared(ServedOptions(quick=True, iti_s=0.2, **options))
        self.out = tmp_path / "out"
        self.participant = participant
        self.session = self.open()

    def open(self) -> ServedSession:
        return ServedSession(self.study, STUDY, self.participant, self.out, self.shared,
                             send=lambda conn, f: self.frames.append(unpack_frame(f)),
                             broadcast=lambda f, latest: self.frames.append(unpack_frame(f)), clock=lambda: self.now)

    def page_ms(self, at=None) -> float:
        return 1000.0 * ((self.now if at is None else at) - OFFSET_S)

    def send(self, message: dict) -> None:
        self.session.page_message(1, json.dumps(message), self.now)

    def advance(self, seconds: float, step: float = 0.01) -> None:
        end = self.now + seconds
        while self.now < end - 1e-9:
            self.now = min(end, self.now + step)
            if self.session.next_due() <= self.now:
                self.session.tick()

    def until(self, phase: str, limit: float = 30.0) -> None:
        waited = 0.0
        while self.session.trial.phase != phase:
            assert waited < limit, f"no {phase} within {limit} s (phase {self.session.trial.phase})"
            self.advance(0.05)
            waited += 0.05

    def last_frame(self) -> dict:
        return next(h for h, _ in reversed(self.frames) if h["kind"] == "frame")


def rows(out, participant="P01") -> list[dict]:
    with open(out / participant / "trials.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_a_quick_session_runs_every_trial_gated_by_its_condition_and_measured_from_the_pages_batches(tmp_path):
    page = Page(tmp_path)
    plan = quick_plan(page.study, "P01")
    session = page.session
    session.connected(1)
    kinds = [h["kind"] for h, _ in page.frames]
    assert kinds[-3:] == ["setup", "geometry", "frame"]          # a page that connects gets the state at once
    setup = next(h for h, _ in page.frames if h["kind"] == "setup")
    assert setup["touch"] == "page" and setup["tracker"] is True and setup["batch_s"] == pytest.approx(0.25)
    expected, starts = {}, []
    for trial in plan:
        page.until("break") if session.trial.phase == "break" else None
        if session.trial.phase == "break":
            page.send({"type": "response", "index": session.trial.index, "option": "", "time": page.page_ms()})
        page.until("stimulus")
        assert session.trial.index == trial.index
        frame = page.last_frame()
        touch_trial = trial.condition in ("touch", "visual+touch")
        # the condition gates the page's own touch; a touch-only trial's objects are not drawn
        assert frame["touch_on"] is touch_trial, trial.condition
        assert frame["draw_objects"] is (trial.condition != "touch"), trial.condition
        geometry = [h for h, _ in page.frames if h["kind"] == "geometry"][-1]
        assert geometry["bodies"] >= 1 and frame["geometry"] == geometry["key"]   # the stimulus reached the page
        # 0.3 s into the stimulus the hand goes 0.05 along x and back in 4 frames (where it was before the
        # trial: the pose held from then adds no step), and the page plays 0.8, then 0
        page.advance(0.3)
        t0 = page.now
        starts.append(t0)
        frames = [t0 + 0.02 * k for k in range(5)]
        page.advance(0.3)                                          # the batch arrives after its frames
        page.send({"type": "batch",
                   "poses": {"time": [page.page_ms(t) for t in frames], "valid": [True] * 5,
                             "hand": [v for x in (0, 0.025, 0.05, 0.025, 0) for v in (x, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0)]},
                   "touches": {"time": [page.page_ms(t0), page.page_ms(t0 + 0.25)], "intensity": [0.8, 0.0]}})
        page.advance(0.2)
        answer = trial.options[1]
        page.send({"type": "response", "index": trial.index, "option": answer, "time": page.page_ms()})
        expected[trial.index] = (answer, 0.25 if touch_trial else 0.0)
    page.advance(0.1)
    assert session.finished and session.trial.phase == "done"
    assert page.last_frame()["touch_on"] is False                  # done: the gate and a stop hold the touch off
    session.close()
    written = rows(page.out)
    assert len(written) == len(plan)
    for row in written:
        answer, touching = expected[int(row["index"])]
        assert row["response"] == answer
        assert float(row["time_touching_s"]) == pytest.approx(touching, abs=1e-6)
        assert float(row["path_length"]) == pytest.approx(0.1, abs=1e-6)   # 4 steps of 0.025 along x, there and back
    # the log: the page's poses with its stamps mapped to the server's clock, what it played, the trials
    log = page.out / "P01" / "session-001.mcap"
    reader = LogReader(log)
    assert {"hand/poses", "tactile/played", "study/trial", "scene/state", "study/response"} <= set(reader.topics())
    batch = next(m.decode() for m in reader.messages({"hand/poses"}))
    assert batch["stamps"][0] == pytest.approx(batch["stamps"][1] - 0.02) and batch["valid"].all()
    assert batch["stamps"][0] == pytest.approx(starts[0], abs=1e-9)   # the page's clock mapped to the server's
    played = [m.decode() for m in reader.messages({"tactile/played"})]
    assert len(played) == len(plan) and played[0]["intensity"].tolist() == [[0.8], [0.0]]


def test_a_session_closed_mid_way_resumes_at_the_first_trial_without_a_row_in_a_new_log(tmp_path):
    page = Page(tmp_path)
    session = page.session
    session.connected(1)
    page.send({"type": "response", "index": session.trial.index, "option": "", "time": page.page_ms()})
    page.until("stimulus")
    first = session.trial
    page.send({"type": "response", "index": first.index, "option": first.options[0], "time": page.page_ms()})
    page.until("stimulus")
    second = session.trial.index
    session.close()                                   # a trial under way: shown again from its start
    assert [int(r["index"]) for r in rows(page.out)] == [first.index]
    page.session = again = page.open()
    again.connected(2)
    page.send({"type": "response", "index": again.trial.index, "option": "", "time": page.page_ms()})
    page.until("stimulus")
    assert again.trial.index == second
    again.close()
    assert sorted(p.name for p in (page.out / "P01").glob("*.mcap")) == ["session-001.mcap", "session-002.mcap"]
    manifest = json.loads((page.out / "P01" / "manifest.json").read_text())
    assert [s["resumed_at"] for s in manifest["starts"]] == [0, second]


def test_the_experimenters_pause_and_the_pages_stats_and_haptics_reach_the_manifest(tmp_path):
    page = Page(tmp_path)
    session = page.session
    session.connected(1)
    page.send({"type": "haptics", "output": "pulse"})
    for fps in (71.5, 72.0, 36.0):
        page.send({"type": "stats", "fps": fps})
    session.command("pause", "the experimenter")
    assert session.trial.phase == "paused" and page.last_frame()["touch_on"] is False
    session.command("resume", "the experimenter")
    assert session.trial.phase != "paused"
    session.close()
    seen = json.loads((page.out / "P01" / "manifest.json").read_text())["page"][0]
    assert seen["haptics"] == "pulse" and seen["fps_median"] == 71.5 and seen["fps_min"] == 36.0


def test_a_connected_page_gets_the_last_frame_again_every_heartbeat_and_none_without_a_page(tmp_path):
    page = Page(tmp_path, heartbeat_s=0.25, gate_stale_s=1.0)
    session = page.session
    assert session.trial.phase == "break"          # nothing changes in a break: only the heartbeat sends
    session.connected(1)
    count = len(page.frames)
    page.advance(1.0)
    repeats = [h for h, _ in page.frames[count:] if h["kind"] == "frame"]
    assert len(repeats) in (3, 4) and len({h["n"] for h in repeats}) == 1     # every 0.25 s, the same frame
    session.closed(1)
    count = len(page.frames)
    page.advance(1.0)
    assert len(page.frames) == count
    session.close()


@pytest.mark.parametrize("message, counted", [
    ("not json", "malformed"),
    (json.dumps({"type": "input", "time": 1.0, "tracking": False, "sources": []}), "malformed"),   # not batched
    (json.dumps({"type": "batch", "poses": {"time": [1.0], "valid": [True], "hand": [0, 0, 0, 0, 0, 0, 2]},
                 "touches": {"time": [], "intensity": []}}), "malformed"),             # not a unit quaternion
    (json.dumps({"type": "batch", "poses": {"time": [], "valid": [], "hand": []},
                 "touches": {"time": [1.0], "intensity": [0.1, 0.2]}}), "malformed"),   # 2 motors: the glove has 1
])
def test_a_bad_message_is_counted_and_changes_nothing(tmp_path, message, counted):
    page = Page(tmp_path)
    session = page.session
    session.connected(1)
    before = session.trial
    session.page_message(1, message, page.now)
    assert session.counts[counted] == 1 and session.trial == before
    session.close()
    assert not (page.out / "P01" / "trials.csv").read_text().strip().count("\n")   # the header only


def test_the_controllers_thumbstick_moves_the_slice_as_in_the_lab(tmp_path):
    page = Page(tmp_path)
    session = page.session
    session.connected(1)
    session.control.command("view", "slice")
    c = session.control.scene.slice_w
    page.send({"type": "buttons", "held": ["thumbstick-up"]})
    assert session.control.scene.slice_w > c
    page.send({"type": "buttons", "held": []})
    page.send({"type": "buttons", "held": ["a"]})                  # an answer button changes no scene
    assert session.control.scene.slice_w > c
    session.close()
    assert np.isfinite(session.control.scene.slice_w)

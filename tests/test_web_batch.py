"""A served page's batching and buttons (touch4d/web/static/batch.js, run by node.js): a batch goes
out after its period or when full and holds every frame once; the controller's answer buttons
answer as the node's bridge reads them (the k-th button the k-th option, any one ends a break, a
held button answers once), the re-centre button re-centres unless it answered, and the glove hand's
buttons are told when they change. Each case's answer is written out here, not computed."""
from __future__ import annotations

import json

from pagejs import run_page_module
from touch4d.web.bridge import ANSWER_BUTTONS
from touch4d.web.protocol import MAX_BATCH, parse_page_message

RUN = """
import { Batch, buttonActions, MAX_BATCH } from './batch.mjs';
import { readFileSync } from 'node:fs';
const input = JSON.parse(readFileSync(0, 'utf8'));
const out = { maxBatch: MAX_BATCH, batches: [], actions: [] };
const batch = new Batch(100, 1);
for (const [now, hand, played] of input.frames) {
  batch.pose(now + 5000, hand, now);
  if (played !== null) batch.touch(now + 4990, [played], now);
  if (batch.due(now)) out.batches.push({ at: now, message: batch.take() });
}
let held = new Set();
for (const [buttons, study] of input.presses) {
  const r = buttonActions([{ handedness: 'right', buttons }], held, study, input.setup);
  held = r.held;
  out.actions.push({ answer: r.answer, recenter: r.recenter, buttons: r.buttons });
}
process.stdout.write(JSON.stringify(out));
"""


def run(tmp_path, payload):
    return run_page_module(tmp_path, "batch", RUN, payload)


HAND = {"position": [0.1, 0.2, 0.3], "orientation": [0, 0, 0, 1]}
SETUP = {"answer_buttons": list(ANSWER_BUTTONS), "hand": "right", "recenter_button": "a"}
STIMULUS = {"phase": "stimulus", "index": 4, "options": ["left", "right"]}
BREAK = {"phase": "break", "index": 5, "options": []}


def test_frames_leave_in_batches_of_their_period_each_once_and_the_server_reads_them(tmp_path):
    # 72 Hz frames for 0.5 s; every third one untracked; a touch played for every other one
    frames = [[1000 * k / 72, None if k % 3 == 2 else HAND, 0.5 if k % 2 == 0 else None] for k in range(36)]
    got = run(tmp_path, {"frames": frames, "presses": [], "setup": SETUP})
    assert got["maxBatch"] == MAX_BATCH
    batches = got["batches"]
    # a batch goes with the frame 100 ms or more after its first: 9 frames (0 .. 111.1 ms) each
    assert [len(b["message"]["poses"]["time"]) for b in batches] == [9, 9, 9, 9]
    sent = [t for b in batches for t in b["message"]["poses"]["time"]]
    assert sent == [f[0] + 5000 for f in frames]                          # each frame once, in order
    first = batches[0]["message"]
    assert first["poses"]["valid"] == [k % 3 != 2 for k in range(9)]
    assert first["poses"]["hand"][:7] == [0.1, 0.2, 0.3, 0, 0, 0, 1] and first["poses"]["hand"][14:21] == [0, 0, 0, 0, 0, 0, 1]
    assert first["touches"]["intensity"] == [0.5] * 5 and first["touches"]["time"] == [f[0] + 4990 for f in frames[0:9:2]]
    parsed = parse_page_message(json.dumps(first))                          # what the server makes of it
    assert parsed["type"] == "batch" and parsed["valid"].tolist() == first["poses"]["valid"]
    assert parsed["intensity"].shape == (5, 1)


def test_a_fast_page_fills_a_batch_before_its_period(tmp_path):
    frames = [[k * 0.5, HAND, None] for k in range(MAX_BATCH + 3)]        # 2000 Hz: the batch is full first
    got = run(tmp_path, {"frames": frames, "presses": [], "setup": SETUP})
    assert len(got["batches"][0]["message"]["poses"]["time"]) == MAX_BATCH


def test_answer_and_recentre_buttons_as_the_bridge_reads_them(tmp_path):
    presses = [
        [["b"], STIMULUS],              # B: the second option
        [["b"], STIMULUS],              # still held: nothing more
        [[], STIMULUS],
        [["a"], STIMULUS],              # A answers (the first option), so it does not re-centre
        [[], None],
        [["a"], None],                  # no trial: A re-centres
        [["a"], None],                  # held: once
        [["thumbstick"], BREAK],        # any answer button ends a break
        [["squeeze"], STIMULUS],        # the 4th button: no 4th option, nothing
        [["thumbstick-up"], None],      # the glove hand's buttons changed: told (the scene's slice)
        [["thumbstick-up"], None],      # unchanged: not told
    ]
    got = run(tmp_path, {"frames": [], "presses": presses, "setup": SETUP})["actions"]
    assert [a["answer"] for a in got] == [
        {"index": 4, "option": "right"}, None, None, {"index": 4, "option": "left"}, None, None, None,
        {"index": 5, "option": ""}, None, None, None]
    assert [a["recenter"] for a in got] == [False, False, False, False, False, True, False, False, False, False,
                                           False]
    assert [a["buttons"] for a in got] == [["b"], None, [], ["a"], [], ["a"], None, ["thumbstick"], ["squeeze"],
                                          ["thumbstick-up"], None]

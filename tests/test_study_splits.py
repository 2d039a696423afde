"""`touch4d study analyze DIR --by FIELD`: the trials split by a field of the sessions' manifests,
each group analysed as the whole study is, on synthetic sessions whose groups' accuracies are known."""
from __future__ import annotations

import json
import math

import pytest

from touch4d.cli import main
from touch4d.errors import ConfigError
from touch4d.study.analysis import load
from touch4d.study.splits import analyze_by, field_path, groups_of
from touch4d.study.table import write_rows

# participant -> (its manifest's device, trials answered right of 8)
SESSIONS = {"P01": ({"browser": "chrome", "rumble": True}, 8), "P02": ({"browser": "chrome", "rumble": False}, 8),
            "P03": ({"browser": "firefox", "rumble": True}, 4), "P04": (None, 2)}


def row(participant, trial, correct):
    return {"participant": participant, "session": "1", "block": 0, "trial": trial, "index": trial,
            "practice": False, "task": "looks", "kind": "look-alikes", "condition": "touch", "stimulus": "a",
            "level": math.nan, "transform": "[]", "answer": "a", "response": "a" if correct else "b",
            "correct": correct, "rt_s": 1.0 + trial, "timed_out": False, "time_touching_s": 1.0,
            "mean_intensity": 0.3, "path_length": 0.5, "onset_stamp": 0.0, "response_stamp": 1.0, "seed": 0,
            "response_received": math.nan, "clock_suspect": False}


@pytest.fixture
def study(tmp_path):
    for participant, (device, right) in SESSIONS.items():
        write_rows(tmp_path / participant / "trials.csv", [row(participant, t, t < right) for t in range(8)])
        manifest = {"study": "s", "study_sha256": "0" * 64, "quick": False, "simulation": None,
                    "participant": participant, "condition_order": ["touch"], "trials": 8}
        if device is not None:
            manifest["device"] = device
        (tmp_path / participant / "manifest.json").write_text(json.dumps(manifest))
    return tmp_path


def test_groups_by_a_nested_manifest_field_have_their_known_accuracies(study):
    split = analyze_by(load(study), "manifest.device.browser", bootstrap=0, tests=False)
    groups = {g["value"]: g for g in split["groups"]}
    assert list(groups) == ["chrome", "firefox", "(missing)"]
    assert groups["chrome"]["participants"] == ["P01", "P02"] and groups["chrome"]["trials"] == 16
    assert groups["firefox"]["participants"] == ["P03"] and groups["(missing)"]["participants"] == ["P04"]
    accuracy = {v: g["result"]["tasks"]["looks"]["touch"]["accuracy"] for v, g in groups.items()}
    assert accuracy == {"chrome": 1.0, "firefox": 0.5, "(missing)": 0.25}
    assert groups["chrome"]["result"]["tasks"]["looks"]["touch"]["rt_s"] == pytest.approx(4.5)   # median of 1..8


def test_a_value_that_is_not_a_string_is_named_as_json_and_manifest_is_optional(study):
    groups = groups_of(load(study), "device.rumble")
    assert {k: len(v) for k, v in groups.items()} == {"true": 2, "false": 1, "(missing)": 1}


def test_analyze_by_on_the_command_line(study, capsys):
    assert main(["study", "analyze", str(study), "--by", "device.browser", "--json", "--no-report",
                 "--bootstrap", "0"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["trials"] == 32                                      # the whole study, as before
    assert {g["value"]: g["result"]["tasks"]["looks"]["touch"]["correct"] for g in result["by"]["groups"]} == {
        "chrome": 16, "firefox": 4, "(missing)": 2}
    assert main(["study", "analyze", str(study), "--by", "device.browser", "--no-report", "--bootstrap", "0"]) == 0
    out = capsys.readouterr().out
    assert "device.browser = firefox (P03; 8 trials)" in out and "device.browser = chrome (P01, P02; 16 trials)" in out


def test_a_field_no_manifest_has_is_refused_naming_it(study, capsys):
    assert main(["study", "analyze", str(study), "--by", "device.gpu", "--no-report", "--bootstrap", "0"]) == 2
    err = capsys.readouterr().err
    assert "--by" in err and "device.gpu" in err and "condition_order" in err and "Traceback" not in err
    with pytest.raises(ConfigError):
        field_path("device..browser")

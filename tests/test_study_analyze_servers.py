"""`touch4d study analyze A B`: the --out folders of several servers of one study analysed together,
on synthetic sessions whose accuracies are known; a participant id in two folders is refused."""
from __future__ import annotations

import json
import shutil

import pytest

from touch4d.cli import main

from test_study_splits import row
from touch4d.study.table import write_rows

RIGHT = {"P01": 8, "P02": 6, "P03": 4, "P04": 2}    # trials answered right of 8


def sessions(where, participants):
    for participant in participants:
        write_rows(where / participant / "trials.csv", [row(participant, t, t < RIGHT[participant]) for t in range(8)])
        (where / participant / "manifest.json").write_text(json.dumps(
            {"study": "s", "study_sha256": "0" * 64, "quick": False, "simulation": None, "participant": participant,
             "condition_order": ["touch"], "trials": 8}))


def analyzed(capsys, *dirs):
    assert main(["study", "analyze", *map(str, dirs), "--json", "--no-report", "--bootstrap", "0"]) == 0
    return json.loads(capsys.readouterr().out)


def test_two_servers_folders_are_analysed_as_one_study(tmp_path, capsys):
    sessions(tmp_path / "a", ["P01", "P02"])
    sessions(tmp_path / "b", ["P03", "P04"])
    result = analyzed(capsys, tmp_path / "a", tmp_path / "b")
    assert result["tasks"]["looks"]["touch"]["accuracy"] == pytest.approx(20 / 32)   # (8+6+4+2) of 32


def test_a_participant_in_two_servers_folders_is_refused_naming_both(tmp_path, capsys):
    sessions(tmp_path / "a", ["P01", "P02"])
    sessions(tmp_path / "b", ["P03"])
    shutil.copytree(tmp_path / "a" / "P01", tmp_path / "b" / "P01")
    assert main(["study", "analyze", str(tmp_path / "a"), str(tmp_path / "b"), "--no-report"]) == 2
    err = capsys.readouterr().err
    assert "P01 in " in err and str(tmp_path / "a" / "P01") in err and str(tmp_path / "b" / "P01") in err

"""A session on disk without a bus: trials.csv written row by row and read back after a crash, the
manifest, and the exploration measures against sums worked by hand."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from touch4d.errors import ConfigError
from touch4d.study.manifest import read_manifest, start_manifest, write_manifest
from touch4d.study.measures import TrialMeasures
from touch4d.study.store import SessionError, TrialsFile, next_segment
from touch4d.study.table import COLUMNS


def row(index: int, **extra) -> dict:
    base = dict.fromkeys(COLUMNS, "")
    base.update(participant="P01", session="1", block=0, trial=index, index=index, practice=False, task="front",
                kind="front-element", condition="touch", stimulus="face", level=float("nan"),
                transform=json.dumps([["xw", 1.5]]), answer="face", response="edge", correct=False, rt_s=1.25,
                timed_out=False, time_touching_s=0.5, mean_intensity=0.1, path_length=0.3, onset_stamp=100.0,
                response_stamp=101.25, seed=7)
    base.update(extra)
    return base


def test_rows_are_read_back_exactly_and_a_row_cut_by_a_crash_is_dropped(tmp_path):
    path = tmp_path / "P01" / "trials.csv"
    f = TrialsFile(path)
    f.write(row(0))
    f.write(row(1, response="", timed_out=True, rt_s=float("nan"), correct=False))
    with pytest.raises(SessionError, match="trial 1 already"):
        f.write(row(1))
    f.close()
    with open(path, "a") as raw:          # the process died half-way through a row
        raw.write("P01,1,0,2,2,0,fr")
    again = TrialsFile(path)
    assert again.done == {0, 1}
    again.write(row(2))
    again.close()
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == COLUMNS
    assert [r["index"] for r in rows] == ["0", "1", "2"]
    assert rows[0]["practice"] == "0" and rows[0]["correct"] == "0" and rows[0]["rt_s"] == "1.25"
    assert rows[0]["level"] == "" and json.loads(rows[0]["transform"]) == [["xw", 1.5]]
    assert rows[1]["response"] == "" and rows[1]["timed_out"] == "1" and rows[1]["rt_s"] == ""


def test_a_session_begun_before_the_arrival_columns_resumes_in_its_own_columns(tmp_path):
    from touch4d.study.table import ARRIVAL_COLUMNS, read_trials
    old = [c for c in COLUMNS if c not in ARRIVAL_COLUMNS]
    path = tmp_path / "P01" / "trials.csv"
    path.parent.mkdir()
    first = row(0)
    path.write_text(",".join(old) + "\n")
    f = TrialsFile(path)                   # refused before: the header is not today's
    assert f.done == set()
    f.write(first)
    f.write(row(1, response_received=101.3))
    f.close()
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(old) and len(lines) == 3 and all(len(x.split(",")) >= len(old) for x in lines)
    table = read_trials(path)
    assert list(table["index"]) == [0, 1] and not table["clock_suspect"].any()
    assert table["response_received"].isna().all()


def test_a_header_cut_short_is_written_again(tmp_path):
    path = tmp_path / "trials.csv"
    path.write_text("participant,sess")
    f = TrialsFile(path)
    f.write(row(0))
    f.close()
    assert path.read_text().splitlines()[0] == ",".join(COLUMNS) and TrialsFile(path).done == {0}


def test_a_file_with_other_columns_or_a_repeated_index_is_refused_naming_it(tmp_path):
    bad = tmp_path / "trials.csv"
    bad.write_text("participant,index\nP01,0\n")
    with pytest.raises(ConfigError, match="trials.csv.*header"):
        TrialsFile(bad)
    f = TrialsFile(tmp_path / "x" / "trials.csv")
    f.write(row(0))
    f.close()
    text = (tmp_path / "x" / "trials.csv").read_text()
    (tmp_path / "x" / "trials.csv").write_text(text + text.splitlines()[1] + "\n")
    with pytest.raises(ConfigError, match="each trial index once"):
        TrialsFile(tmp_path / "x" / "trials.csv")


def test_manifest_is_replaced_whole_and_segments_count_up(tmp_path):
    write_manifest(tmp_path, {"a": 1})
    write_manifest(tmp_path, {"a": 2, "starts": []})
    assert read_manifest(tmp_path) == {"a": 2, "starts": []}
    assert not list(tmp_path.glob("*.tmp"))
    assert next_segment(tmp_path).name == "session-001.mcap"
    (tmp_path / "session-001.mcap").write_bytes(b"")
    assert next_segment(tmp_path).name == "session-002.mcap"


def test_measures_hold_each_sample_until_the_next_and_clip_to_the_window():
    m = TrialMeasures(threshold=0.02)
    on, off = np.full(30, 0.3), np.zeros(30)
    m.add_motors(9.0, on)        # before the onset: holds into the window from 10.0
    m.add_motors(10.5, off)
    m.add_motors(11.0, np.r_[np.full(15, 0.6), np.zeros(15)])   # mean 0.3, touching
    m.add_motors(13.0, on)       # after the end: ignored
    m.add_pose(9.5, [0, 0, 0], True)
    m.add_pose(10.2, [0.3, 0, 0], True)
    m.add_pose(10.4, [0.3, 0.4, 0], True)
    m.add_pose(10.6, [9, 9, 9], False)       # tracking lost: no step across it
    m.add_pose(10.8, [0.3, 0.4, 1.0], True)
    m.add_pose(11.5, [0.3, 0.4, 2.0], True)
    result = m.measure(onset=10.0, end=12.0)
    # touching over [10, 10.5] and [11, 12]; the mean intensity 0.3 over those 1.5 s of the 2 s
    assert result.time_touching_s == pytest.approx(1.5)
    assert result.mean_intensity == pytest.approx(0.3 * 1.5 / 2.0)
    # steps: 0.3 (from the pose held at the onset), 0.4, then after the gap 1.0
    assert result.path_length == pytest.approx(0.3 + 0.4 + 1.0)
    m.reset()
    later = m.measure(onset=20.0, end=21.0)     # the last command (on) still holds
    assert later.time_touching_s == pytest.approx(1.0) and later.path_length == 0.0


def test_a_motor_command_with_nan_counts_it_as_zero():
    m = TrialMeasures(threshold=0.02)
    m.add_motors(10.0, np.array([np.nan, 0.6, 0.0]))    # mean (0 + 0.6 + 0) / 3, touching
    m.add_motors(11.0, np.array([np.nan, np.nan, 0.01]))   # below the threshold: not touching
    result = m.measure(onset=10.0, end=12.0)
    assert result.time_touching_s == pytest.approx(1.0)
    assert result.mean_intensity == pytest.approx((0.2 + 0.01 / 3) / 2)


def test_the_overrides_of_a_run_are_valid_for_the_study_launch_file_and_user_overrides_win(tmp_path):
    from touch4d.bus.launchfile import load_launch
    from touch4d.cli import build_parser
    from touch4d.study.session import STUDY_LAUNCH, SessionOptions, session_overrides

    # as touch4d.cli reads a command line: overrides after the options come back unknown and join the rest
    args, extra = build_parser("study").parse_known_args(["study", "run", "config/studies/paper.yaml", "--simulate",
                                                          "--quick", "--out", str(tmp_path), "renderer:=renderer",
                                                          "study.iti_s:=1.5"])
    args.items.extend(extra)
    assert args.items == ["renderer:=renderer", "study.iti_s:=1.5"]
    # an id YAML would read as a boolean reaches the nodes as the text it is
    overrides = session_overrides("config/studies/paper.yaml", "true", tmp_path,
                                  SessionOptions(quick=True, simulate=True, seed=3), user=args.items)
    nodes = load_launch(STUDY_LAUNCH, [*overrides, *args.items])
    assert "monitor" not in nodes        # a simulation runs without what nobody watches, unless asked
    assert nodes["tracker"].module == "study_observer" and nodes["renderer"].module == "renderer"
    assert nodes["study"].params["participant"] == "true" and nodes["study"].params["iti_s"] == 1.5
    assert nodes["tracker"].params["seed"] == 3 and nodes["tracker"].params["quick"] is True
    assert nodes["recorder"].params["file"] == str(tmp_path / "true" / "session-001.mcap")
    with pytest.raises(SessionError, match="'P 7'"):     # not a folder name under OUT
        session_overrides("config/studies/paper.yaml", "P 7", tmp_path)
    assert nodes["motors"].params["study_gate"] == "closed" and nodes["renderer"].params["study_gate"] == "closed"
    assert all(spec.respawn for spec in nodes.values())
    person = load_launch(STUDY_LAUNCH, session_overrides("config/studies/paper.yaml", "007", tmp_path))
    assert person["tracker"].module == "desktop" and person["study"].params["participant"] == "007"
    # a counterbalancing row and the simulation's settings reach the study node (and the observer's plan)
    settings = {"mode": "full stack", "noise": 0.08, "tracker": ["tracker.pace:=0.1"]}
    picked = load_launch(STUDY_LAUNCH, session_overrides("config/studies/paper.yaml", "bob", tmp_path, SessionOptions(
        order=3, simulate=True, simulation=settings)))
    assert picked["study"].params["order"] == 3 and picked["tracker"].params["order"] == 3
    assert json.loads(picked["study"].params["simulation"]) == settings


def test_a_session_resumes_only_as_it_was_started(tmp_path):
    from touch4d.boards.config import load_glove_can
    from touch4d.boards.dbc import dbc_text
    from touch4d.configfile import resolve_path
    from touch4d.study.design import load_study

    study_path = resolve_path("config/studies/paper.yaml")
    common = dict(study=load_study(study_path), study_path=study_path, session="1",
                  condition_order=["visual", "touch", "visual+touch"], trials=9,
                  glove_path=resolve_path("config/glove.yaml"),
                  calibration_path=resolve_path("config/calibration.yaml"),
                  dbc_text=dbc_text(load_glove_can(None)))
    first = start_manifest(tmp_path, participant="P01", resumed_at=0, quick=True, **common)
    again = start_manifest(tmp_path, participant="P01", resumed_at=4, quick=True, **common)
    assert [s["resumed_at"] for s in again["starts"]] == [0, 4] and again["study_sha256"] == first["study_sha256"]
    from touch4d.study.plan import participant_seed
    assert participant_seed(common["study"], "P01").entropy == first["seed"]      # the plan's random stream
    with pytest.raises(SessionError, match="quick"):
        start_manifest(tmp_path, participant="P01", resumed_at=4, quick=False, **common)
    with pytest.raises(SessionError, match="participant"):
        start_manifest(tmp_path, participant="P02", resumed_at=4, quick=True, **common)
    other = tmp_path / "other.yaml"
    other.write_text(study_path.read_text() + "\n# changed\n")
    with pytest.raises(SessionError, match="sha256"):
        start_manifest(tmp_path, participant="P01", resumed_at=4, quick=True, **{**common, "study_path": other})


def test_a_restarted_recorder_never_writes_over_a_segment(tmp_path):
    from touch4d.nodes.recorder import unused_path

    first = tmp_path / "session-001.mcap"
    assert unused_path(first) == first
    first.write_bytes(b"x")
    assert unused_path(first) == tmp_path / "session-001-2.mcap"
    (tmp_path / "session-001-2.mcap").write_bytes(b"x")
    assert unused_path(first) == tmp_path / "session-001-3.mcap"

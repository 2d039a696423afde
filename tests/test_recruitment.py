"""The open link's assignment (touch4d.study.recruitment), without a server: the next visitor's id
fills the least-filled counterbalancing row among those done or under way, abandoned places free
their row, ids with a folder or a link are skipped; a platform's parameters are checked and its
identity maps to one participant, kept in OUT/recruits.json across restarts."""
from __future__ import annotations


import pytest

from touch4d.study.design import load_study
from touch4d.study.plan import order_table, participant_index
from touch4d.study.recruitment import (Place, Recruits, holds_row, identity, next_participant, platform_params,
                                       rows_filled)

STUDY = "config/studies/paper.yaml"


def row_of_p(rows):
    return lambda participant: (int(participant[1:]) - 1) % rows


def test_visitors_one_after_another_take_the_rows_in_turn_and_the_plan_agrees():
    study = load_study(STUDY)
    rows = len(order_table(study))
    places, given = [], []
    for _ in range(2 * rows + 1):
        filled = rows_filled(rows, places, row_of_p(rows), now=100.0, leave_after_s=30)
        participant, row = next_participant(filled, [p.participant for p in places])
        assert participant_index(study, participant) == row       # the plan gives that id that row
        places.append(Place(participant, "running", since=100.0))
        given.append(participant)
    assert given == [f"P{n:02d}" for n in range(1, 2 * rows + 2)]


def test_completed_and_running_fill_rows_and_abandoned_places_free_theirs():
    rows = 3
    places = [Place("P01", "done", since=0.0),             # row 0, done long ago: holds it
              Place("P02", "running", since=95.0),         # row 1, a trial 5 s ago
              Place("P03", "running", since=10.0),         # row 2, no trial for 90 s: abandoned
              Place("P04", "left", since=99.0),            # row 0, left: holds nothing
              Place("P05", "invited", since=50.0),         # row 1, given a link 50 s ago, not joined yet
              Place("P06", "invited", since=None)]         # row 2, invited by the experimenter: no row held
    filled = rows_filled(rows, places, row_of_p(rows), now=100.0, leave_after_s=30, pending_s=600)
    assert filled == [1, 2, 0]
    # the free row 2 goes to the next visitor: P03 and P06 are taken (a folder, a link), P09 is next
    assert next_participant(filled, [p.participant for p in places]) == ("P09", 2)
    assert not holds_row(Place("P05", "invited", since=50.0), now=700.0, leave_after_s=30, pending_s=600)
    assert holds_row(Place("P07", "paused", since=90.0), now=100.0, leave_after_s=30)


def test_ties_go_to_the_first_row_and_taken_ids_are_skipped_whatever_their_case():
    assert next_participant([0, 0, 0], []) == ("P01", 0)
    assert next_participant([1, 0, 0], ["p02", "P05"]) == ("P08", 1)
    assert next_participant([5], ["P01"]) == ("P02", 0)
    with pytest.raises(ValueError):
        next_participant([], [])


def test_platform_parameters_are_checked_and_name_the_participant():
    query = {"PROLIFIC_PID": "5f2b3c", "STUDY_ID": "s1", "SESSION_ID": "x9", "other": "ignored"}
    names = ("PROLIFIC_PID", "STUDY_ID", "SESSION_ID", "workerId")
    params = platform_params(query, names)
    assert params == {"PROLIFIC_PID": "5f2b3c", "STUDY_ID": "s1", "SESSION_ID": "x9"}
    assert identity(params) == "PROLIFIC_PID=5f2b3c"
    assert identity({"workerId": "W1", "STUDY_ID": "s1"}, ["workerId"]) == "workerId=W1"
    assert identity({"STUDY_ID": "s1", "SESSION_ID": "x"}) is None       # a study and a try name no one
    for bad in ("", "a\nb", "x" * 129, "tab\there"):
        with pytest.raises(ValueError, match="PROLIFIC_PID: expected 1-128 printable"):
            platform_params({"PROLIFIC_PID": bad}, names)


def test_the_key_and_the_platform_ids_are_kept_in_the_out_folder(tmp_path):
    recruits = Recruits(tmp_path)
    assert recruits.key is None and recruits.participant_of("PROLIFIC_PID=a") is None
    key = recruits.open()
    assert Recruits(tmp_path).open() == key                   # kept across a restart
    recruits.remember("PROLIFIC_PID=a", "P01", {"PROLIFIC_PID": "a", "STUDY_ID": "s"})
    again = Recruits(tmp_path)
    assert again.participant_of("PROLIFIC_PID=a") == "P01"
    assert again.params_of("P01") == {"PROLIFIC_PID": "a", "STUDY_ID": "s"} and again.params_of("P02") is None
    assert oct((tmp_path / "recruits.json").stat().st_mode & 0o777) == "0o600"
    again.forget("P01")
    again.close()
    reread = Recruits(tmp_path)
    assert reread.participant_of("PROLIFIC_PID=a") is None and reread.key is None
    with pytest.raises(ValueError):
        recruits.remember("PROLIFIC_PID=b", "../P01", {})


@pytest.mark.parametrize("text", ["{", "[]", '{"key": "short"}', '{"key": null, "platform": {"x": 1}}'])
def test_a_bad_recruits_file_is_named(tmp_path, text):
    (tmp_path / "recruits.json").write_text(text)
    with pytest.raises(ValueError, match="recruits.json"):
        Recruits(tmp_path)

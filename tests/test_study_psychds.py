"""`touch4d study export DIR --psych-ds OUT`: a simulated study's sessions become a Psych-DS dataset
that an independent checker (tests/psychds_check.py, from the spec's rules) accepts, with the rows,
manifests and logs unchanged; a dataset that breaks the rules is refused by the same checker; bad
input and an occupied OUT are refused by name (exit 2), and a failed export leaves nothing behind."""
from __future__ import annotations

import csv
import hashlib
import json
import math
import shutil
from importlib.metadata import version

import pytest

import psychds_check
from touch4d.cli import main
from touch4d.log.writer import LogWriter
from touch4d.study import psychds
from touch4d.study.design import study_file_path
from touch4d.study.lock import WRITER, SessionLock
from touch4d.study.table import write_rows

pytestmark = pytest.mark.timeout(300)

P01 = "study-paper_subject-P01_session-1_data.csv"
P02 = "study-paper_subject-P02_session-1_data.csv"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """Two simulated participants (quick plans, offline), P01 with an MCAP log as a session through the
    stack would have."""
    out = tmp_path_factory.mktemp("study") / "runs"
    assert main(["study", "run", "paper", "--simulate", "--offline", "--quick", "--participants", "2",
                 "--out", str(out)]) == 0
    with LogWriter(out / "P01" / "session-001.mcap"):
        pass
    return out


@pytest.fixture(scope="module")
def dataset(study, tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "dataset"
    assert main(["study", "export", str(study), "--psych-ds", str(out)]) == 0
    return out


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def codes(found):
    return {code for code, _, _ in found}


def test_a_simulated_study_exports_a_dataset_the_checker_accepts(dataset):
    errors, warnings = psychds_check.check(dataset)
    assert errors == []
    assert warnings == []                     # only the official keywords in the file names
    assert sorted(p.name for p in (dataset / "data").glob("*.csv")) == [P01, P02]


def test_every_row_and_column_is_exported_as_the_session_wrote_it(study, dataset):
    description = json.loads((dataset / "dataset_description.json").read_text())
    for participant, name in (("P01", P01), ("P02", P02)):
        header, rows = read_csv(study / participant / "trials.csv")
        assert read_csv(dataset / "data" / name) == (header, rows)
        assert rows and {r[header.index("participant")] for r in rows} == {participant}
        assert [v["name"] for v in description["variableMeasured"]] == header
    units = {v["name"]: v.get("unitText") for v in description["variableMeasured"]}
    assert units["rt_s"] == "s" and units["level"] == "degree" and units["participant"] is None


def test_the_description_names_the_study_file_by_digest_and_the_software_version(dataset):
    description = json.loads((dataset / "dataset_description.json").read_text())
    assert description["@type"] == "Dataset" and "paper" in description["name"]
    digest = hashlib.sha256(study_file_path("paper").read_bytes()).hexdigest()
    based = {b["@type"]: b for b in description["isBasedOn"]}
    assert based["CreativeWork"]["identifier"]["value"] == digest
    assert based["SoftwareApplication"]["softwareVersion"] == version("touch4d")


def test_manifests_and_logs_are_copied_unchanged_beside_the_data(study, dataset):
    records = dataset / "data" / "primary_data"
    assert sorted(p.relative_to(records).as_posix() for p in records.rglob("*") if p.is_file()) == [
        "P01/manifest.json", "P01/session-001.mcap", "P02/manifest.json"]
    for name in ("P01/manifest.json", "P01/session-001.mcap", "P02/manifest.json"):
        assert (records / name).read_bytes() == (study / name).read_bytes()
    assert "data/primary_data/" in (dataset / ".psychds-ignore").read_text().splitlines()
    assert P01 in (dataset / "README.md").read_text()


# ---- the checker can fail ----------------------------------------------------------------------------


@pytest.fixture
def broken(dataset, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    return copy


def test_the_checker_refuses_a_column_missing_from_variable_measured(broken):
    path = broken / "dataset_description.json"
    description = json.loads(path.read_text())
    description["variableMeasured"] = [v for v in description["variableMeasured"] if v["name"] != "rt_s"]
    path.write_text(json.dumps(description))
    errors, _ = psychds_check.check(broken)
    assert {(code, message) for code, _, message in errors} == {
        ("CSV_COLUMN_MISSING_FROM_METADATA", "not in variableMeasured: rt_s")}


@pytest.mark.parametrize("name", ["P01_data.csv", "study-paper_subject-P_01_data.csv", "study-paper_subject-P01.csv",
                                  "Study-paper_data.csv", "study-paper_subject-P01_data2.csv"])
def test_the_checker_refuses_a_data_file_named_against_the_keyword_grammar(broken, name):
    (broken / "data" / P01).rename(broken / "data" / name)
    errors, _ = psychds_check.check(broken)
    assert [(code, path) for code, path, _ in errors] == [("FILENAME_KEYWORD_FORMATTING_ERROR", f"data/{name}")]


def test_the_checker_warns_of_an_unofficial_keyword_and_refuses_missing_required_keys(broken):
    (broken / "data" / P01).rename(broken / "data" / "study-paper_participant-P01_data.csv")
    path = broken / "dataset_description.json"
    description = json.loads(path.read_text())
    del description["name"], description["@type"]
    path.write_text(json.dumps(description))
    errors, warnings = psychds_check.check(broken)
    assert codes(errors) == {"JSON_KEY_REQUIRED", "MISSING_DATASET_TYPE"}
    assert codes(warnings) == {"FILENAME_UNOFFICIAL_KEYWORD_WARNING"}


def test_the_checker_refuses_a_ragged_row_and_a_dataset_without_data(broken):
    with open(broken / "data" / P02, "a") as f:
        f.write("P02,1,9\n")
    assert codes(psychds_check.check(broken)[0]) == {"CSV_HEADER_LENGTH_MISMATCH"}
    shutil.rmtree(broken / "data")
    assert codes(psychds_check.check(broken)[0]) == {"MISSING_DATA_DIRECTORY"}


# ---- ids, names and refusals -------------------------------------------------------------------------


def row(participant, trial, correct=True):
    return {"participant": participant, "session": "1", "block": 0, "trial": trial, "index": trial,
            "practice": False, "task": "looks", "kind": "look-alikes", "condition": "touch", "stimulus": "a",
            "level": math.nan, "transform": "[]", "answer": "a", "response": "a" if correct else "b",
            "correct": correct, "rt_s": 1.5, "timed_out": False, "time_touching_s": 1.0, "mean_intensity": 0.3,
            "path_length": 0.5, "onset_stamp": 0.0, "response_stamp": 1.5, "seed": 0, "response_received": math.nan,
            "clock_suspect": False}


def session(root, folder, participant, manifest=None):
    write_rows(root / folder / "trials.csv", [row(participant, 0), row(participant, 1, False)])
    if manifest is not False:
        (root / folder / "manifest.json").write_text(json.dumps(
            manifest or {"study": "tilt-pilot", "study_sha256": "ab" * 32, "version": "9.9", "participant": participant}))


def test_ids_outside_the_keyword_grammar_keep_their_letters_and_digits_in_names_and_whole_in_rows(tmp_path):
    session(tmp_path / "runs", "P-7", "P-7")
    session(tmp_path / "runs", "bob_2", "bob_2")
    assert main(["study", "export", str(tmp_path / "runs"), "--psych-ds", str(tmp_path / "ds")]) == 0
    assert psychds_check.check(tmp_path / "ds") == ([], [])
    header, rows = read_csv(tmp_path / "ds" / "data" / "study-tiltpilot_subject-P7_session-1_data.csv")
    assert {r[header.index("participant")] for r in rows} == {"P-7"}
    assert (tmp_path / "ds" / "data" / "study-tiltpilot_subject-bob2_session-1_data.csv").is_file()
    assert (tmp_path / "ds" / "data" / "primary_data" / "bob_2" / "manifest.json").is_file()


def test_two_ids_that_would_share_a_file_name_are_refused_naming_both(tmp_path, capsys):
    session(tmp_path / "runs", "P-1", "P-1")
    session(tmp_path / "runs", "P1", "P1")
    assert main(["study", "export", str(tmp_path / "runs"), "--psych-ds", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert "'P-1'" in err and "'P1'" in err and "study-tiltpilot_subject-P1_session-1_data.csv" in err
    assert "Traceback" not in err and not (tmp_path / "ds").exists()


def test_bad_input_is_refused_by_name(tmp_path, capsys):
    runs = tmp_path / "runs"
    session(runs, "P01", "P01", manifest=False)
    assert main(["study", "export", str(runs), "--psych-ds", str(tmp_path / "ds")]) == 2
    assert f"{runs / 'P01' / 'manifest.json'}: key '(file)': expected the session's manifest" in capsys.readouterr().err
    (runs / "P01" / "manifest.json").write_text(json.dumps({"study": "x"}))
    (runs / "P01" / "trials.csv").write_text("participant,answer\nP01,a\n")
    assert main(["study", "export", str(runs), "--psych-ds", str(tmp_path / "ds")]) == 2
    assert f"{runs / 'P01' / 'trials.csv'}: key '(header)': expected the trials.csv columns" in capsys.readouterr().err
    assert main(["study", "export", str(tmp_path / "nowhere"), "--psych-ds", str(tmp_path / "ds")]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_an_occupied_out_is_refused_and_force_replaces_only_an_earlier_export(study, tmp_path, capsys):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["study", "export", str(study), "--psych-ds", str(out)]) == 2
    assert f"{out}: expected a new or empty folder" in capsys.readouterr().err
    assert main(["study", "export", str(study), "--psych-ds", str(out), "--force"]) == 2   # not an export
    assert (out / "notes.txt").read_text() == "mine"
    (out / "notes.txt").unlink()
    assert main(["study", "export", str(study), "--psych-ds", str(out)]) == 0              # empty: written
    (out / "README.md").write_text("stale")
    assert main(["study", "export", str(study), "--psych-ds", str(out), "--force"]) == 0
    assert "stale" not in (out / "README.md").read_text()
    assert main(["study", "export", str(study), "--psych-ds", str(study), "--force"]) == 2  # the sessions' own folder
    assert "outside the study's sessions" in capsys.readouterr().err
    assert (study / "P01" / "trials.csv").is_file()


def test_a_failed_export_leaves_no_dataset_and_keeps_the_earlier_one(study, tmp_path, monkeypatch):
    out = tmp_path / "ds"
    assert main(["study", "export", str(study), "--psych-ds", str(out)]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def disk_full(source, target):
        raise psychds.ExportError(f"{source}: cannot copy it into the dataset (No space left on device)")

    monkeypatch.setattr(psychds, "_copy", disk_full)
    assert main(["study", "export", str(study), "--psych-ds", str(out), "--force"]) == 2
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert main(["study", "export", str(study), "--psych-ds", str(tmp_path / "new")]) == 2
    assert not (tmp_path / "new").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]          # no staging folder left


def test_a_session_a_study_node_still_writes_is_refused_naming_it(study, tmp_path, capsys):
    with SessionLock(study / "P02", WRITER):
        assert main(["study", "export", str(study), "--psych-ds", str(tmp_path / "ds")]) == 2
    assert f"{study / 'P02'}: another process" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()
    assert main(["study", "export", str(study), "--psych-ds", str(tmp_path / "ds")]) == 0   # claims released


def test_a_session_folder_or_its_table_exports_alone(study, tmp_path):
    for where in (study / "P02", study / "P02" / "trials.csv"):
        out = tmp_path / where.name
        assert main(["study", "export", str(where), "--psych-ds", str(out)]) == 0
        assert psychds_check.check(out) == ([], [])
        assert sorted(p.relative_to(out).as_posix() for p in (out / "data").rglob("*") if p.is_file()) == [
            "data/primary_data/P02/manifest.json", f"data/{P02}"]


def test_every_trials_column_is_described():
    from touch4d.study.table import COLUMNS

    assert set(psychds.COLUMN_DESCRIPTIONS) == set(COLUMNS)


def test_a_platforms_ids_and_the_user_agent_stay_out_of_the_dataset(study, tmp_path):
    """What could name a participant on the recruitment platform is not shared; the rest is as recorded."""
    import shutil
    copy = tmp_path / "runs"
    shutil.copytree(study, copy)
    manifest = json.loads((copy / "P01" / "manifest.json").read_text())
    manifest["platform"] = {"PROLIFIC_PID": "5f1e0a0b0c0d0e0f10111213", "STUDY_ID": "abc"}
    manifest["device"] = {"browser": "OculusBrowser", "user_agent": "Mozilla/5.0 (X11; Linux x86_64) Quest 3",
                          "hits": 6}
    (copy / "P01" / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    out = tmp_path / "dataset"
    assert main(["study", "export", str(copy), "--psych-ds", str(out)]) == 0
    text = (out / "data" / "primary_data" / "P01" / "manifest.json").read_text()
    shared = json.loads(text)
    assert "platform" not in shared and "5f1e0a0b" not in text and "Quest 3" not in text
    assert shared["device"] == {"browser": "OculusBrowser", "hits": 6}
    del manifest["platform"], manifest["device"]["user_agent"]
    assert shared == manifest

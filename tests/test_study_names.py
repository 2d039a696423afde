"""Every command that takes a study takes a packaged study's bare name (paper for
config/studies/paper.yaml) the same way, and a misspelt one is an error that lists the names."""
import json

import pytest

from touch4d.cli import main


def commands(tmp_path, study):
    return {
        "check": ["study", "check", study],
        "plan": ["study", "plan", study, "--participant", "P01"],
        "transfer": ["study", "transfer", study, "--task", "nothing"],
        "power": ["study", "power", study, "--fit", str(tmp_path / "fit.json"), "--out", str(tmp_path / "power")],
        "glove design": ["glove", "design", "--motors", "1", "--study", study, "--task", "nothing",
                         "-o", str(tmp_path / "g.yaml")],
        "serve": ["study", "serve", study, "--out", str(tmp_path / "served"), "--glove", "config/gloves/no-such.yaml"],
        "fit": ["study", "fit", str(tmp_path / "pilot"), "--study", study, "--workers", "0"],
    }


@pytest.fixture
def pilot(tmp_path):
    """A pilot folder of another study (its manifest names it): only a packaged study by name can differ."""
    folder = tmp_path / "pilot" / "P01"
    folder.mkdir(parents=True)
    from touch4d.study.table import COLUMNS

    (folder / "trials.csv").write_text(",".join(COLUMNS) + "\n" + ",".join(["0"] * len(COLUMNS)) + "\n")
    (folder / "manifest.json").write_text(json.dumps({"study": "elsewhere", "study_file": "elsewhere.yaml"}))
    (tmp_path / "fit.json").write_text(json.dumps({"study": "elsewhere", "population": {}}))
    return tmp_path


@pytest.mark.parametrize("command", ["check", "plan", "transfer", "power", "glove design", "serve", "fit"])
def test_a_misspelt_study_name_lists_the_packaged_names(pilot, command, capsys):
    assert main(commands(pilot, "papr")[command]) != 0
    err = capsys.readouterr().err
    assert "a study file: a path, or the name of one in config/studies/" in err and "'paper'" in err, err


@pytest.mark.parametrize("command, reached", [
    ("power", "expected a fit of study 'paper'"),                    # read the study, then the fit
    ("glove design", "expected a task with id 'nothing'"),           # read the study, then its tasks
    ("transfer", "expected a task with id 'nothing'"),
    ("serve", "key '--glove': expected an existing glove file"),     # read the study, then the glove file
    ("fit", "expected the study of the pilot's sessions (elsewhere), got 'paper'"),
])
def test_every_command_reads_a_packaged_study_by_its_name(pilot, command, reached, capsys):
    assert main(commands(pilot, "paper")[command]) != 0
    err = capsys.readouterr().err
    assert reached in err and "STUDY" not in err.split(reached)[0][-200:], err

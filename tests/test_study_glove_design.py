"""A glove designed: the file it writes is a working glove (tactile model, CAN boards and channels,
DBC) that `study transfer --glove` accepts; the designed layout tells more than random layouts of the
same size; more motors than sample points is a clear error."""
import json

import cantools
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.cli import main
from touch4d.study.design import load_study
from touch4d.study.fanout import Cluster
from touch4d.study.glovedesign import design_gloves
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.tactile import load_glove

STUDY = "tests/data/studies/lookalikes.yaml"


@pytest.mark.timeout(400)
def test_glove_design_writes_a_working_glove_that_study_transfer_accepts(tmp_path, capsys):
    out = tmp_path / "designed.yaml"
    assert main(["glove", "design", "--motors", "10", "--study", STUDY, "--random", "2", "--rounds", "0",
                 "--scenes", "4", "--positions", "4", "--workers", "0", "-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    places = result["sizes"]["10"]["designed"]["places"]
    assert len(set(places)) == 10
    glove, base = load_glove(out), load_glove()
    assert len(glove.motor_names) == 10
    assert sorted(glove.motor_sample.tolist()) == sorted(places)             # each motor on its chosen sample
    assert abs(glove.motor_positions - base.samples[places]).max() < 1e-6       # written to the micrometre
    can = load_glove_can(out)
    assert sorted(zip(can.motor_board, can.motor_channel)) == [(1 + k // 8, k % 8) for k in range(10)]
    assert [b.id for b in can.boards] == [1, 2]
    dbc = cantools.database.load_file(str(out.with_suffix(".dbc")))
    assert {m.frame_id for m in dbc.messages} >= {0x201, 0x202}              # a duty frame per board
    assert main(["study", "transfer", STUDY, "--glove", str(out), "--scenes", "4", "--positions", "4", "--json"]) == 0
    transfer = json.loads(capsys.readouterr().out)
    assert transfer["results"][0]["motors"] == 10 and 0.0 <= transfer["results"][0]["bits"] <= 1.585 + 1e-9


@pytest.mark.timeout(400)
def test_a_designed_pair_of_motors_tells_more_than_random_pairs():
    study, glove = load_study(STUDY), load_glove()
    result = design_gloves(glove, study, [2], noise=HUMAN_NOISE, random_layouts=8, rounds=1, scenes=6, positions=6,
                           progress=False, cluster=Cluster(workers=0))
    size = result["sizes"][2]
    assert size["designed"]["mean_bits"] > size["random_mean_bits"] + size["random_sd_bits"]
    assert 0.0 <= size["designed"]["mean_bits"] <= 1.585 + 1e-9


def test_more_motors_than_sample_points_is_a_clear_error(capsys):
    assert main(["glove", "design", "--motors", "1000", "--study", STUDY, "--workers", "0", "-o", "x.yaml"]) != 0
    assert "--motors': expected at most 247 motors" in capsys.readouterr().err


def test_regions_restrict_the_places_and_an_unknown_region_is_a_clear_error(capsys):
    from touch4d.study.glovedesign import candidates_in, sample_regions

    study, glove = load_study(STUDY), load_glove()
    regions = sample_regions(glove)
    palm = candidates_in(glove, ["palm"])
    assert palm == regions["palm"] and all(glove.samples[i][2] < 0 for i in palm)
    assert set(candidates_in(glove, ["index", "thumb"])) == set(regions["index"]) | set(regions["thumb"])
    result = design_gloves(glove, study, [2], noise=HUMAN_NOISE, random_layouts=2, rounds=0, scenes=3, positions=3,
                           candidates=palm, progress=False, cluster=Cluster(workers=0))
    assert set(result["sizes"][2]["designed"]["places"]) <= set(palm)
    assert main(["glove", "design", "--motors", "2", "--study", STUDY, "--regions", "wrist", "--workers", "0",
                 "-o", "x.yaml"]) != 0
    assert "--regions': expected regions of the hand: palm, back, thumb" in capsys.readouterr().err

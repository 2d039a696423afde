"""A glove designed: the file it writes is a working glove (tactile model, CAN boards and channels,
DBC) that `study transfer --glove` accepts; the designed layout tells more than random layouts of the
same size on test examples; the greedy steps and the swaps find the informative places of known
synthetic data, swaps only on what the validation examples show; the search is deterministic by
seed and also starts from the glove's own layout; more motors than sample points is a clear error."""
import json

import cantools
import msgspec
import numpy as np
import pytest

from touch4d.boards.config import load_glove_can
from touch4d.cli import main
from touch4d.study.design import load_study
from touch4d.study.fanout import Cluster
from touch4d.study.glovedesign import (DesignOptions, Examples, design_gloves, greedy_layout, improve_by_swaps,
                                       step_sample)
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.tactile import load_glove

STUDY = "tests/data/studies/lookalikes.yaml"


@pytest.mark.timeout(200)
def test_glove_design_writes_a_working_glove_that_study_transfer_accepts(tmp_path, capsys):
    out = tmp_path / "designed.yaml"            # 10 motors among the index's and middle's 30 places: two boards
    assert main(["glove", "design", "--motors", "10", "--study", STUDY, "--regions", "index", "middle", "--random",
                 "0", "--rounds", "0", "--scenes", "3", "--positions", "3", "--workers", "0", "-o", str(out),
                 "--json"]) == 0
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


@pytest.mark.timeout(200)
def test_a_designed_pair_of_motors_tells_more_than_random_pairs_on_test_examples():
    study, glove = load_study(STUDY), load_glove()
    options = DesignOptions(noise=HUMAN_NOISE, random_layouts=8, rounds=1, tries=4, scenes=5, positions=5)
    result = design_gloves(glove, study, [2], options=options, progress=False, cluster=Cluster(workers=0))
    size = result["sizes"][2]
    assert size["designed"]["mean_bits"] > size["random_mean_bits"] + size["random_sd_bits"]
    assert 0.0 <= size["designed"]["mean_bits"] <= 1.585 + 1e-9


def synthetic(informative, *, samples=8, rows=120, seed=0) -> Examples:
    """Two stimuli told apart only by the columns `informative` (a shift of 3 sd), every other column
    pure noise; odd rows held out."""
    rng = np.random.default_rng(seed)
    k = np.arange(rows) % 2
    x = rng.normal(0.0, 1.0, (rows, samples))
    x[:, informative] += 3.0 * k[:, None]
    return Examples({"task": (x, k, (np.arange(rows) // 2) % 2 == 1, 2)})


def test_greedy_steps_pick_the_informative_place_of_known_data():
    assert greedy_layout(synthetic([5]), 1) == [5]
    assert greedy_layout(synthetic([5]), 1, candidates=[0, 1, 2, 3]) in ([0], [1], [2], [3])
    assert greedy_layout(synthetic([5, 6]), 2, start=[6]) == [6, 5]


def test_swaps_follow_the_validation_examples_not_the_search_ones():
    validation = synthetic([2], seed=1)       # the search would have liked 5; validation shows 2
    places, bits = improve_by_swaps(validation, [5], candidates=range(8), rounds=2, tries=7,
                                    rng=np.random.default_rng(0))
    assert places == [2] and bits > 0.6         # 3-sd shift: ~93% correct, ~0.63 bits
    kept, kept_bits = improve_by_swaps(validation, [2], candidates=range(8), rounds=2, tries=7,
                                       rng=np.random.default_rng(0))
    assert kept == [2] and kept_bits == bits    # nothing on validation beats it: no swap


def test_the_greedy_sample_shrinks_with_k_so_a_design_costs_about_the_same_at_any_k():
    assert step_sample(247, 1) == step_sample(247, 2) == 247            # small K: every place tried
    assert step_sample(247, 30) == 38                                   # 247 / 30 ln 100 = 37.9
    assert 30 * step_sample(247, 30) < 1.2 * 247 * np.log(100)


@pytest.mark.timeout(200)
def test_the_search_is_deterministic_by_seed_and_at_the_gloves_motor_count_also_starts_from_its_layout():
    study, glove = load_study(STUDY), load_glove()
    own = sorted(set(int(s) for s in glove.motor_sample))
    pool = sorted(set(own) | set(range(0, 247, 25)))          # its 29 places and a few others: a quick search
    options = DesignOptions(noise=HUMAN_NOISE, random_layouts=0, rounds=1, tries=2, scenes=3, positions=3)
    kw = dict(candidates=pool, progress=False, cluster=Cluster(workers=0))
    first, again = (design_gloves(glove, study, [30], options=options, **kw) for _ in range(2))
    size = first["sizes"][30]
    assert set(size["starts"]) == {"greedy", "the glove's own"}
    assert size["designed"] == max(size["starts"].values(), key=lambda d: d["validation_bits"])
    assert again["sizes"][30]["designed"]["places"] == size["designed"]["places"]
    assert {s: d["places"] for s, d in again["sizes"][30]["starts"].items()} == \
        {s: d["places"] for s, d in size["starts"].items()}
    no_swaps = design_gloves(glove, study, [30], options=msgspec.structs.replace(options, rounds=0),
                             **kw)["sizes"][30]["starts"]["the glove's own"]
    assert set(own) < set(no_swaps["places"]) and len(no_swaps["places"]) == 30   # its 29 places, one added


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
    result = design_gloves(glove, study, [2], options=DesignOptions(noise=HUMAN_NOISE, random_layouts=2, rounds=0,
                                                                     scenes=3, positions=3),
                           candidates=palm, progress=False, cluster=Cluster(workers=0))
    assert set(result["sizes"][2]["designed"]["places"]) <= set(palm)
    assert main(["glove", "design", "--motors", "2", "--study", STUDY, "--regions", "wrist", "--workers", "0",
                 "-o", "x.yaml"]) != 0
    assert "--regions': expected regions of the hand: palm, back, thumb" in capsys.readouterr().err


def test_the_designs_examples_feel_each_sample_with_the_noise_of_its_skin():
    # the same seed draws the same scenes and hand places; what the noise adds is the difference
    from touch4d.study.glovedesign import examples, sample_regions
    from touch4d.study.psychophysics import THENAR_WEBER, noise_for_weber

    glove, study = load_glove(), load_study("tests/data/studies/lookalikes.yaml")
    settings = {"scenes": 4, "positions": 6, "seed": 3}
    task = study.tasks[0].id
    noisy = examples(glove, study, [task], noise=HUMAN_NOISE, **settings).tasks[task][0]
    clean = examples(glove, study, [task], noise=0.0, **settings).tasks[task][0]
    regions = sample_regions(glove)
    added = noisy - clean
    assert np.std(added[:, regions["palm"]]) == pytest.approx(noise_for_weber(THENAR_WEBER), rel=0.05)
    fingers = regions["thumb"] + regions["index"] + regions["middle"] + regions["ring"] + regions["little"]
    assert np.std(added[:, fingers + regions["back"]]) == pytest.approx(HUMAN_NOISE, rel=0.05)


@pytest.mark.timeout(200)
def test_glove_design_prints_the_bits_study_transfer_gives_its_written_file(tmp_path, capsys):
    """The design's table scores layouts on its own test examples; what it prints for the written file
    is what `study transfer --glove` of that file prints, and the text says why the table differs."""
    out = tmp_path / "designed.yaml"
    design = ["glove", "design", "--motors", "2", "--study", STUDY, "--random", "0", "--rounds", "0", "--scenes",
              "3", "--positions", "3", "--seed", "3", "--workers", "0", "-o", str(out)]
    assert main([*design, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["transfer_command"].endswith(f"--glove {out} --seed 3")
    assert main(["study", "transfer", STUDY, "--glove", str(out), "--seed", "3", "--json"]) == 0
    transfer = json.loads(capsys.readouterr().out)
    assert result["transfer"] == {r["task"]: r["bits"] for r in transfer["results"]}
    assert main(design) == 0
    text = capsys.readouterr().out
    line = next(line for line in text.splitlines() if line.startswith("touch4d study transfer"))
    assert f"lookalikes {transfer['results'][0]['bits']:.3f}" in line and "sampling error" in line, text

"""A pilot fitted: over 100 simulated pilots with known parameters the profile intervals cover the
truth at about their nominal rate; a pilot simulated by model observers of known noise is fitted
end to end by `touch4d study fit`; bad pilots are clear errors."""
import json
import math

import numpy as np
import pytest

from touch4d.cli import main
from touch4d.study.design import load_study
from touch4d.study.pilotfit import Surface, dense_accuracy, fit_participant, population_of
from touch4d.study.simulate import simulate_study
from touch4d.study.observer import ModelObserver
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.tactile import load_glove

STUDY = "tests/data/studies/lookalikes.yaml"


def closed_form_surface() -> Surface:
    """Known synthetic accuracies (3 options): 1/3 + 2/3 (1 - exp(-d)), d = 0.5 / touch noise by touch,
    2 / visual noise by sight, their sum when both are there."""
    log_touch, log_visual = np.linspace(math.log(0.02), math.log(5.0), 7), np.linspace(math.log(0.1), math.log(8.0), 7)

    def accuracy(d):
        return 1 / 3 + 2 / 3 * (1 - np.exp(-d))

    touch, visual = np.meshgrid(np.exp(log_touch), np.exp(log_visual), indexing="ij")
    values = {"t|touch": accuracy(0.5 / np.exp(log_touch)), "t|visual": accuracy(2.0 / np.exp(log_visual)),
              "t|visual+touch": accuracy(0.5 / touch + 2.0 / visual)}
    return Surface("synthetic", log_touch, log_visual, values, {cell: 3 for cell in values})


def test_over_100_simulated_pilots_the_intervals_cover_the_truth_at_about_95_percent():
    surface = closed_form_surface()
    dense = dense_accuracy(surface)
    truth = {"noise": 0.5, "visual_noise": 2.0, "lapse": 0.05}
    rng = np.random.default_rng(0)
    covered = {name: 0 for name in truth}
    estimates = []
    for _ in range(100):
        counts = {}
        for cell in surface.values:
            p = truth["lapse"] / 3 + (1 - truth["lapse"]) * surface.accuracy(cell, math.log(truth["noise"]),
                                                                                math.log(truth["visual_noise"]))
            counts[cell] = (int(rng.binomial(60, p)), 60)
        fit = fit_participant(surface, counts, dense)
        estimates.append(fit["noise"]["estimate"])
        for name, value in truth.items():
            low, high = fit[name]["ci95"]
            covered[name] += low <= value <= high
    # 95% nominal: 100 pilots cover it 95 +- 2.2 times (binomial sd); 88 lies 3 sd below
    assert all(88 <= count <= 100 for count in covered.values()), covered
    assert abs(math.log(np.median(estimates)) - math.log(truth["noise"])) < 0.25


def test_the_population_spread_is_the_spread_of_the_noise_beyond_each_estimates_error():
    rng = np.random.default_rng(1)
    noises = np.exp(rng.normal(math.log(0.3), 0.4, 400))
    # intervals 2 x 1.96 x 0.1 wide on the log scale: each estimate's own error has sd 0.1
    fits = {f"P{i}": {"noise": {"estimate": float(x * math.exp(rng.normal(0, 0.1))),
                                "ci95": [float(x * math.exp(-0.196)), float(x * math.exp(0.196))]},
                      "visual_noise": {"estimate": 1.0}, "lapse": {"estimate": 0.02}} for i, x in enumerate(noises)}
    population = population_of(fits, bootstrap=200)
    assert population["spread"] == pytest.approx(0.4, abs=0.04)
    assert population["noise"] == pytest.approx(0.3, rel=0.06)
    low, high = population["spread_ci95"]
    assert low < population["spread"] < high and high - low < 0.15


@pytest.mark.timeout(400)
def test_fit_recovers_the_touch_noise_of_a_simulated_pilot_and_feeds_power(tmp_path, capsys):
    study, glove = load_study(STUDY), load_glove()
    trained = ModelObserver(glove, study, noise=HUMAN_NOISE).train()   # trained as the fit trains its own
    pilot = tmp_path / "pilot"
    truth = 1.0                                             # touch noise: accuracy well below ceiling
    simulate_study(study, ["P01", "P02", "P03"], pilot, glove=glove, spread=0.0,
                   observer=trained.with_noise(truth / trained.noise))
    out = tmp_path / "fit.json"
    assert main(["study", "fit", str(pilot), "--points", "5", "--trials", "24", "--workers", "0", "--out", str(out),
                 "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    assert fit["study"] == "lookalikes" and sorted(fit["participants"]) == ["P01", "P02", "P03"]
    covered = [own["noise"]["ci95"][0] <= truth <= own["noise"]["ci95"][1] for own in fit["participants"].values()]
    assert sum(covered) >= 2, fit["participants"]
    assert json.loads(out.read_text())["population"] == fit["population"]
    assert list((tmp_path / "cache").iterdir())                # the surface's simulations are kept
    from touch4d.study.power import Population

    population = Population.from_fit(fit, study, out)
    assert population.noise == pytest.approx(fit["population"]["noise"]) and population.source == str(out)


def test_an_empty_pilot_or_a_pilot_of_another_study_is_a_clear_error(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["study", "fit", str(empty), "--workers", "0"]) != 0
    assert "a folder with at least one trials.csv" in capsys.readouterr().err
    header = tmp_path / "header" / "P01"
    header.mkdir(parents=True)
    from touch4d.study.table import COLUMNS

    (header / "trials.csv").write_text(",".join(COLUMNS) + "\n")
    assert main(["study", "fit", str(header.parent), "--study", STUDY, "--workers", "0"]) != 0
    assert "expected a pilot with trials" in capsys.readouterr().err
    pilot = tmp_path / "pilot"
    study, glove = load_study(STUDY), load_glove()
    simulate_study(study, ["P01"], pilot, glove=glove, quick=True,
                   observer=ModelObserver(glove, study, train_scenes=3, train_positions=6, view_scenes=6))
    assert main(["study", "fit", str(pilot), "--study", "config/studies/paper.yaml", "--workers", "0"]) != 0
    assert "expected the study of the pilot's sessions (lookalikes), got 'paper'" in capsys.readouterr().err


def test_an_interval_at_a_parameters_bound_says_it_is_open_there_not_certain():
    from touch4d.study.pilotfit import summary_text

    surface = closed_form_surface()
    perfect = fit_participant(surface, {cell: (60, 60) for cell in surface.values})   # no lapse seen: lapse 0
    assert perfect["lapse"]["estimate"] == 0.0
    # three participants with the same estimate: the noises vary less than their own error, spread 0
    alike = {f"P{i}": {"noise": {"estimate": 0.3, "ci95": [0.2, 0.45]}, "visual_noise": {"estimate": 1.0},
                       "lapse": {"estimate": 0.02}} for i in range(3)}
    population = population_of(alike, bootstrap=50)
    assert population["spread"] == 0.0 and population["spread_ci95"] == [0.0, 0.0]
    text = summary_text({"study": "synthetic", "participants": {"P01": perfect}, "population": population})
    assert "[0, 0]" not in text and "<0," not in text, text
    assert "spread 0 [0 (bound), 0 (bound)] at the bound" in text, text
    participant = next(line for line in text.splitlines() if line.startswith("P01"))
    assert "0 [0 (bound), " in participant and "at the bound" in participant, participant


QUEST = "config/gloves/quest-controller.yaml"


@pytest.fixture(scope="module")
def quest_pilot(tmp_path_factory):
    """A small pilot simulated with the controller as its glove (its manifests name it), and its fit
    by `study fit` with no --glove (a coarse surface: the glove it used is the point, not the noise)."""
    tmp = tmp_path_factory.mktemp("quest")
    study, glove = load_study(STUDY), load_glove(QUEST)
    pilot = tmp / "pilot"
    simulate_study(study, ["P01", "P02"], pilot, glove=glove, quick=True,
                   observer=ModelObserver(glove, study, train_scenes=3, train_positions=6, view_scenes=6))
    out = tmp / "fit.json"
    code = main(["study", "fit", str(pilot), "--points", "2", "--trials", "2", "--workers", "0", "--out", str(out)])
    return pilot, out, code


def test_fit_reads_the_pilots_glove_from_its_manifest_and_records_it(quest_pilot):
    import hashlib

    pilot, out, code = quest_pilot
    assert code == 0
    fit = json.loads(out.read_text())
    assert fit["glove"].endswith("quest-controller.yaml"), fit["glove"]
    assert fit["glove_sha256"] == hashlib.sha256(open(QUEST, "rb").read()).hexdigest()


def test_fit_refuses_another_glove_than_the_pilots_unless_told(quest_pilot, capsys):
    pilot, _, _ = quest_pilot
    capsys.readouterr()
    assert main(["study", "fit", str(pilot), "--glove", "config/glove.yaml", "--workers", "0"]) != 0
    err = capsys.readouterr().err
    assert "--glove" in err and "quest-controller.yaml" in err and "--glove-differs-ok" in err, err


def test_power_refuses_a_fit_of_another_glove_unless_told(quest_pilot, tmp_path, capsys):
    _, fit, _ = quest_pilot
    capsys.readouterr()
    assert main(["study", "power", STUDY, "--fit", str(fit), "--glove", "config/glove.yaml", "--quick",
                 "--participants", "2", "--simulations", "1", "--samples", "5", "--bootstrap", "0",
                 "--out", str(tmp_path / "power"), "--workers", "0"]) != 0
    err = capsys.readouterr().err
    assert str(fit) in err and "quest-controller.yaml" in err and "--glove-differs-ok" in err, err
    from touch4d.commands.study.planning import check_fit_glove, read_fit

    check_fit_glove(read_fit(fit), load_glove(QUEST), fit)          # the pilot's own glove: accepted
    check_fit_glove(read_fit(fit), load_glove(), fit, differs_ok=True)
    assert "fitted with" in capsys.readouterr().err


def test_fit_with_another_glove_on_purpose_warns_and_records_that_glove(quest_pilot, tmp_path, capsys):
    pilot, _, _ = quest_pilot
    out = tmp_path / "other.json"
    assert main(["study", "fit", str(pilot), "--glove", "config/glove.yaml", "--glove-differs-ok", "--points", "2",
                 "--trials", "2", "--workers", "0", "--out", str(out)]) == 0
    assert "not the glove the pilot ran with" in capsys.readouterr().err
    assert json.loads(out.read_text())["glove"].endswith("config/glove.yaml")

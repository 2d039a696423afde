"""Power by simulation: where the answer is known (a difference of two binomial proportions) it
matches statsmodels' power within simulation error; participants answering by the observer's answer
shares are right as often as the observer run on every trial; the command writes its curves, report
and JSON; a fit file of another study is a clear error."""
import json
import warnings

import numpy as np
import pandas as pd
import pytest
from statsmodels.stats.power import NormalIndPower
from statsmodels.stats.proportion import proportion_confint, proportion_effectsize

from touch4d.cli import main
from touch4d.study.answers import answer_model, answered_rows
from touch4d.study.design import load_study
from touch4d.study.fanout import Cluster
from touch4d.study.observer import ModelObserver
from touch4d.study.plan import participant_ids, plan_session
from touch4d.study.power import Population, study_outcome, summarise
from touch4d.study.simulate import session_rows
from touch4d.tactile import load_glove

STUDY = "tests/data/studies/lookalikes.yaml"


def two_proportions(rng, participants: int, trials: int, p_visual: float, p_both: float):
    """Known synthetic data: every trial independent, correct with p_visual (visual) or p_both (visual+touch)."""
    rows = []
    for i in range(participants):
        for condition, p in (("visual", p_visual), ("visual+touch", p_both)):
            rows += [{"participant": f"P{i + 1:02d}", "task": "t", "kind": "look-alikes", "condition": condition,
                      "correct": bool(k)} for k in rng.random(trials) < p]
    return pd.DataFrame(rows)


@pytest.mark.timeout(300)
def test_the_power_of_a_difference_of_two_proportions_matches_statsmodels_within_simulation_error():
    simulations, participants, trials, p_visual, p_both = 60, 20, 5, 0.6, 0.75
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        outcomes = [study_outcome(two_proportions(np.random.default_rng(s), participants, trials, p_visual, p_both),
                                  mixed=False)
                    for s in range(simulations)]
    power = summarise({participants: outcomes})["t"]["effects"]["visual+touch"]["gee"][0]
    expected = NormalIndPower().power(proportion_effectsize(p_both, p_visual), nobs1=participants * trials,
                                      alpha=0.05)
    assert 0.5 < expected < 0.75                       # a design whose power is neither 0 nor 1
    low, high = proportion_confint(round(power["power"] * simulations), simulations, alpha=0.002, method="wilson")
    assert low <= expected <= high, (power, expected)
    # no effect: the test rejects at about its level, not at the power of the effect above
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        null = [study_outcome(two_proportions(np.random.default_rng(1000 + s), participants, trials, 0.6, 0.6),
                              mixed=False)
                for s in range(30)]
    assert summarise({participants: null})["t"]["effects"]["visual+touch"]["gee"][0]["power"] <= 0.2


@pytest.mark.timeout(400)
def test_answer_shares_are_right_as_often_as_the_observer_run_on_every_trial():
    """The observer's whole pipeline on every trial of 16 sessions against draws from its answer
    shares (measured on other trials), per condition, at its own noise and at twice it (a point
    between the shares' grid points): the accuracies agree within their joint sampling error."""
    study, glove = load_study(STUDY), load_glove()
    observer = ModelObserver(glove, study, noise=0.3, lapse=0.0, train_scenes=3, train_positions=6,
                             view_scenes=6).train()
    model = answer_model(observer, study, spread=0.4, samples=200, cluster=Cluster(workers=0), progress=False)
    assert len(model.log_factors) == 9 and not np.isclose(np.log(2.0), model.log_factors).any()
    for factor in (1.0, 2.0):
        exact, drawn = [], []
        for i, participant in enumerate(participant_ids(16)):
            trials = plan_session(study, participant)
            exact += session_rows(observer.with_noise(factor), glove, study, participant, trials, seed=i)
            drawn += answered_rows(model, factor, 0.0, participant, trials, seed=i, touches=6)
        exact, drawn = pd.DataFrame(exact), pd.DataFrame(drawn)
        assert (drawn[["condition", "stimulus", "answer"]] == exact[["condition", "stimulus", "answer"]]).all().all()
        for condition, rows in exact.groupby("condition"):
            k, n = int(rows["correct"].sum()), len(rows)
            shares = [model.probabilities("lookalikes", condition, s, factor, 0.0)[model.options["lookalikes"].index(a)]
                      for s, a in zip(rows["stimulus"], rows["answer"])]
            expected = float(np.mean(shares))
            spread = np.sqrt(expected * (1 - expected) * (1 / n + 1 / 200) + 1e-4)
            assert abs(k / n - expected) < 3.5 * spread, (factor, condition, k / n, expected)
            assert abs(drawn.loc[drawn["condition"] == condition, "correct"].mean() - expected) < 3.5 * spread
    assert exact.groupby("condition")["correct"].mean().max() - exact.groupby("condition")["correct"].mean().min() > 0.2


@pytest.mark.timeout(400)
def test_power_command_writes_curves_report_and_json_and_resumes(tmp_path, capsys):
    out = tmp_path / "power"
    args = ["study", "power", STUDY, "--participants", "2,3", "--simulations", "2", "--bootstrap", "0",
            "--workers", "0", "--quick", "--samples", "30", "--out", str(out), "--json"]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["sizes"] == [2, 3] and result["simulations"] == 2 and result["study"] == "lookalikes"
    effects = result["curves"]["lookalikes"]["effects"]
    assert set(effects) == {"touch", "visual+touch"}
    for share in effects["touch"]["gee"]:
        assert 0.0 <= share["power"] <= 1.0 and share["simulations"] == 2
    assert json.loads((out / "power.json").read_text())["curves"] == result["curves"]
    page = (out / "report.html").read_text()
    assert "data:image/png;base64," in page and "power, GEE" in page
    # the same command again: every simulation comes from the cache, the answer is the same
    cached = sorted(p.stat().st_mtime_ns for p in (out / "cache").rglob("*.json"))
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["curves"] == result["curves"]
    assert sorted(p.stat().st_mtime_ns for p in (out / "cache").rglob("*.json")) == cached



@pytest.mark.timeout(400)
def test_a_glove_whose_motors_moved_to_other_skin_does_not_reuse_the_power_cache(tmp_path, capsys):
    # the same glove file, its two motors moved from a finger to the palm: felt with other noise, so
    # the simulations cached for the finger must not answer for the palm
    from touch4d.study.glovedesign import write_glove

    glove, path, out = load_glove(), tmp_path / "glove.yaml", tmp_path / "power"
    regions = glove.hand.regions(glove.samples)
    args = ["study", "power", STUDY, "--glove", str(path), "--participants", "2", "--simulations", "1",
            "--bootstrap", "0", "--workers", "0", "--quick", "--samples", "10", "--out", str(out), "--json"]
    for region in ("index", "palm"):
        write_glove(path, glove.path, glove, regions[region][:2])
        assert main(args) == 0
        capsys.readouterr()
    assert len([d for d in (out / "cache").iterdir() if d.is_dir()]) == 2


def test_a_fit_of_another_study_is_a_clear_error(tmp_path, capsys):
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"study": "paper", "population": {"noise": 0.1, "visual_noise": 0.5, "lapse": 0.02,
                                                                "spread": 0.2}}))
    assert main(["study", "power", STUDY, "--fit", str(fit), "--simulations", "1", "--workers", "0"]) != 0
    assert "fit.json: key 'study': expected a fit of study 'lookalikes'" in capsys.readouterr().err
    population = Population.from_fit(json.loads(fit.read_text()), load_study("config/studies/paper.yaml"))
    assert (population.noise, population.visual_noise, population.lapse, population.spread) == (0.1, 0.5, 0.02, 0.2)
    fit.write_text("[1, 2]")
    assert main(["study", "power", STUDY, "--fit", str(fit), "--simulations", "1", "--workers", "0"]) != 0
    assert "fit.json: key '(file)': expected a JSON object" in capsys.readouterr().err

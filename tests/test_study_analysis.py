"""The analysis recovers known effects from synthetic trial tables drawn with known probabilities;
information transfer matches its closed forms."""
import json
import math

import numpy as np
import pandas as pd
import pytest
from scipy.special import ndtr

from touch4d.cli import main
from touch4d.study.analysis import analyze, cell_summary, fit_psychometric, fit_psychometric_many, load, psychometric
from touch4d.study.infotransfer import information_transfer, transfer_beyond_chance
from touch4d.study.table import COLUMNS, write_rows

CONDITIONS = ("visual", "touch", "visual+touch")


def synthetic(rng, participants, trials, p_correct, *, task="looks", options=("a", "b", "c"), spread=0.0):
    """Rows of a trials.csv: each participant answers `trials` trials per condition, correct with
    probability p_correct[condition] (on the logit scale shifted by a participant effect of sd `spread`),
    otherwise one of the other options at random."""
    rows = []
    for i in range(participants):
        shift = rng.normal(0, spread)
        for c, condition in enumerate(CONDITIONS):
            p = 1 / (1 + math.exp(-(math.log(p_correct[condition] / (1 - p_correct[condition])) + shift)))
            for t in range(trials):
                answer = options[rng.integers(len(options))]
                correct = rng.random() < p
                response = answer if correct else rng.choice([o for o in options if o != answer])
                rows.append(row(f"P{i + 1:02d}", c, t, task, "look-alikes", condition, answer, answer, response,
                                math.nan, rt=float(rng.lognormal(1.0, 0.3))))
    return rows


def row(participant, block, trial, task, kind, condition, stimulus, answer, response, level, rt=2.0, practice=False):
    timed_out = response is None
    return {"participant": participant, "session": "1", "block": block, "trial": trial, "index": block * 1000 + trial,
            "practice": practice, "task": task, "kind": kind, "condition": condition, "stimulus": stimulus,
            "level": level, "transform": "[]", "answer": answer, "response": "" if timed_out else response,
            "correct": (not timed_out) and response == answer, "rt_s": math.nan if timed_out else rt,
            "timed_out": timed_out, "time_touching_s": 1.0, "mean_intensity": 0.3, "path_length": 0.5,
            "onset_stamp": 0.0, "response_stamp": rt, "seed": 0, "response_received": math.nan, "clock_suspect": False}


def write_sessions(tmp_path, rows):
    for participant in sorted({r["participant"] for r in rows}):
        write_rows(tmp_path / participant / "trials.csv", [r for r in rows if r["participant"] == participant])
    return tmp_path


# ---- accuracy and intervals -----------------------------------------------------------------------------


def test_accuracy_per_cell_recovers_the_generating_probabilities(tmp_path):
    truth = {"visual": 0.4, "touch": 0.8, "visual+touch": 0.9}
    rows = synthetic(np.random.default_rng(1), 8, 60, truth)
    rows.append(row("P01", 0, 999, "looks", "look-alikes", "visual", "a", "a", "b", math.nan, practice=True))
    data = load(write_sessions(tmp_path, rows))
    assert len(data) == 8 * 60 * 3                      # the practice trial is left out
    result = analyze(data, bootstrap=0, tests=False)
    for condition, p in truth.items():
        cell = result["tasks"]["looks"][condition]
        assert cell["n"] == 480
        assert abs(cell["accuracy"] - p) < 3 * math.sqrt(p * (1 - p) / 480)
        assert cell["ci95"][0] < p < cell["ci95"][1]
        assert cell["chance"] == pytest.approx(1 / 3)
        rt = data.loc[data["condition"] == condition, "rt_s"]
        assert cell["rt_s"] == pytest.approx(np.median(rt))
        assert cell["rt_iqr_s"] == pytest.approx(list(np.percentile(rt, [25, 75])))
    assert result["tasks"]["looks"]["visual"]["p_above_chance"] < 0.05
    counts = np.array(result["confusion"]["looks"]["touch"]["counts"])
    assert counts.sum() == 480 and np.trace(counts) == result["tasks"]["looks"]["touch"]["correct"]


def test_wilson_intervals_cover_the_true_accuracy_about_95_percent_of_the_time():
    rng = np.random.default_rng(7)
    p, n, runs = 0.7, 40, 400
    hits = 0
    for _ in range(runs):
        correct = rng.random(n) < p
        cell = pd.DataFrame({"correct": correct, "timed_out": False, "clock_suspect": False, "rt_s": 1.0,
                             "participant": "P01",
                             "time_touching_s": 0.0, "mean_intensity": 0.0, "path_length": 0.0})
        low, high = cell_summary(cell, 0.5)["ci95"]
        hits += low <= p <= high
    assert 0.92 <= hits / runs <= 0.98                  # 0.95 +- 2.7 standard errors of 400 runs


def test_timeouts_count_as_wrong_and_have_their_own_column(tmp_path):
    rows = [row("P01", 0, t, "looks", "look-alikes", "touch", "a", "a", "a" if t < 6 else None, math.nan)
            for t in range(10)]
    result = analyze(load(write_sessions(tmp_path, rows)), bootstrap=0, tests=False)
    cell = result["tasks"]["looks"]["touch"]
    assert (cell["accuracy"], cell["timed_out"]) == (0.6, 4)
    assert result["confusion"]["looks"]["touch"]["responses"] == ["a", "(timed out)"]


def test_answer_times_leave_out_a_page_clock_that_claimed_too_much_and_say_so(tmp_path, capsys):
    rows = [row("P01", 0, t, "looks", "look-alikes", "touch", "a", "a", "a", math.nan, rt=3.0) for t in range(5)]
    lying = [row("P02", 0, t, "looks", "look-alikes", "touch", "a", "a", "b", math.nan, rt=0.15) for t in range(3)]
    for r in lying:                                   # answered 3 s after onset, stamped 0.15 s after it
        r.update(response_received=3.0, clock_suspect=True)
    write_sessions(tmp_path, rows + lying)
    result = analyze(load(tmp_path), bootstrap=0, tests=False)
    cell = result["tasks"]["looks"]["touch"]
    assert cell["rt_s"] == 3.0 and cell["rt_iqr_s"] == [3.0, 3.0]      # the honest times only
    assert (cell["n"], cell["correct"]) == (8, 5)                    # the answers still count
    assert any("3 answer(s) (P02)" in w and "clock_suspect" in w for w in result["warnings"])
    assert main(["study", "analyze", str(tmp_path), "--bootstrap", "0"]) == 0
    assert "warning: 3 answer(s) (P02)" in capsys.readouterr().out


# ---- psychometric function ------------------------------------------------------------------------------


def tilt_rows(rng, pse, sigma, lapse, per_level, condition="touch", participant="P01", block=3):
    """A tilt block (after synthetic()'s three): each trial once, as a session writes it."""
    rows = []
    for level in (-16, -8, -4, -2, 2, 4, 8, 16):
        p = lapse / 2 + (1 - lapse) * ndtr((level - pse) / sigma)
        for t in range(per_level):
            answer = "right" if level > 0 else "left"
            response = "right" if rng.random() < p else "left"
            rows.append(row(participant, block, len(rows), "tilt", "tilt", condition, f"tilt{level:+d}", answer,
                            response, float(level)))
    return rows


def test_the_psychometric_fit_recovers_threshold_pse_and_lapse():
    rng = np.random.default_rng(3)
    data = pd.DataFrame(tilt_rows(rng, pse=1.0, sigma=4.0, lapse=0.04, per_level=150))
    data["timed_out"] = False
    fit = psychometric(data, bootstrap=60, seed=1)
    assert fit["positive"] == "right"
    assert fit["threshold_deg"] == pytest.approx(0.6745 * 4.0, abs=0.35)
    assert fit["pse_deg"] == pytest.approx(1.0, abs=0.5)
    assert fit["lapse"] < 0.1
    low, high = fit["ci95"]["threshold_deg"]
    assert low < 0.6745 * 4.0 < high and high - low < 1.5


def test_a_steeper_observer_gets_a_lower_threshold():
    rng = np.random.default_rng(4)
    for sigma in (1.5, 6.0):
        rows = tilt_rows(rng, 0.0, sigma, 0.0, 80)
        level = np.array([r["level"] for r in rows])
        positive = np.array([r["response"] == "right" for r in rows], dtype=float)
        assert fit_psychometric(level, positive)["sigma_deg"] == pytest.approx(sigma, rel=0.3)


def test_fitting_many_resamples_at_once_finds_each_ones_maximum_likelihood():
    """Against scipy's Nelder-Mead from a grid of starts on each resample alone (an independent
    optimiser): the batch's log-likelihood is never lower, and its estimates agree where both agree."""
    from scipy.optimize import minimize
    from scipy.special import xlogy

    rng = np.random.default_rng(11)
    levels = np.repeat([-12.0, -8, -4, -2, 2, 4, 8, 12], 6)
    truth = 0.03 + 0.94 * ndtr((levels - 1.0) / 3.0)
    samples = [(levels, (rng.random(levels.size) < truth).astype(float)) for _ in range(12)]
    level, positive = np.array([s[0] for s in samples]), np.array([s[1] for s in samples])
    batch = fit_psychometric_many(level, positive, (1.0, 3.0, 0.03))

    def nll(theta, lv, pos):
        pse, sigma, lapse = theta
        if not (sigma > 1e-3 and 0.0 <= lapse <= 0.2):
            return 1e9
        p = np.clip(lapse / 2 + (1 - lapse) * ndtr((lv - pse) / sigma), 1e-12, 1 - 1e-12)
        return -float(np.sum(xlogy(pos, p) + xlogy(1 - pos, 1 - p)))

    for i, (lv, pos) in enumerate(samples):
        best = min((minimize(nll, start, args=(lv, pos), method="Nelder-Mead",
                             options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
                    for start in [(0.0, s, l) for s in (0.5, 2.0, 6.0) for l in (0.01, 0.1)]), key=lambda f: f.fun)
        ours = (batch["pse_deg"][i], batch["sigma_deg"][i], batch["lapse"][i])
        assert nll(ours, lv, pos) <= best.fun + 1e-6
        if nll(ours, lv, pos) > best.fun - 1e-6:             # the same maximum: the same estimates
            assert np.allclose(ours, best.x, atol=2e-3 * max(1.0, best.x[1]))
    single = fit_psychometric(level[0], positive[0])
    assert single["threshold_deg"] == pytest.approx(batch["threshold_deg"][0], rel=1e-4)


# ---- the effect of condition --------------------------------------------------------------------------------


def test_the_tests_detect_a_planted_condition_effect(tmp_path):
    rows = synthetic(np.random.default_rng(11), 10, 40, {"visual": 0.45, "touch": 0.75, "visual+touch": 0.8},
                     spread=0.5)
    test = analyze(load(write_sessions(tmp_path, rows)), bootstrap=0)["tests"]["looks"]
    assert test["reference"] == "visual"
    assert test["gee"]["p"] < 1e-3 and test["gee"]["df"] == 2
    assert test["gee"]["effects"]["touch"]["log_odds"] > 0.5
    assert test["mixed"]["effects"]["touch"]["credible"] and test["mixed"]["effects"]["visual+touch"]["credible"]


def test_the_tests_find_no_effect_where_none_was_planted(tmp_path):
    rows = synthetic(np.random.default_rng(12), 10, 40, {c: 0.7 for c in CONDITIONS}, spread=0.5)
    test = analyze(load(write_sessions(tmp_path, rows)), bootstrap=0)["tests"]["looks"]
    assert test["gee"]["p"] > 0.05
    assert not any(e["credible"] for e in test["mixed"]["effects"].values())


# ---- information transfer ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [2, 3, 8])
def test_information_transfer_of_a_perfect_identification_is_log2_n(n):
    assert information_transfer(np.eye(n) * 7) == pytest.approx(math.log2(n))


def test_information_transfer_of_answers_unrelated_to_the_stimulus_is_zero():
    assert information_transfer(np.full((3, 3), 5)) == pytest.approx(0.0, abs=1e-12)
    assert information_transfer(np.outer([1, 2, 3], [4, 1, 1])) == pytest.approx(0.0, abs=1e-12)


def test_information_transfer_of_a_symmetric_binary_channel():
    e = 0.2   # 1 - H(e) bits
    expected = 1 + e * math.log2(e) + (1 - e) * math.log2(1 - e)
    assert information_transfer([[80, 20], [20, 80]]) == pytest.approx(expected)


def test_three_trials_answered_three_ways_transfer_the_maximum_and_nothing_beyond_chance():
    # every pairing of 3 stimuli with 3 distinct answers gives log2(3) bits, right or wrong
    for table in (np.eye(3), np.eye(3)[[1, 2, 0]]):
        out = transfer_beyond_chance(table)
        assert out["bits"] == pytest.approx(math.log2(3))
        assert out["chance_bits"] == pytest.approx(math.log2(3))
        assert out["bits_beyond_chance"] == 0.0 and out["p"] == 1.0


def test_the_chance_bits_of_unrelated_answers_match_millers_bias():
    # answers independent of the stimulus: the estimate's bias is (r-1)(c-1) / (2 n ln 2) to first order
    rng = np.random.default_rng(4)
    n, rows, cols = 600, 3, 4
    table = np.zeros((rows, cols), int)
    np.add.at(table, (rng.integers(rows, size=n), rng.integers(cols, size=n)), 1)
    out = transfer_beyond_chance(table, shuffles=4000)
    assert out["chance_bits"] == pytest.approx((rows - 1) * (cols - 1) / (2 * n * math.log(2)), rel=0.15)
    assert out["p"] > 0.01


def test_a_real_identification_stands_above_chance():
    out = transfer_beyond_chance(np.eye(3) * 10)
    assert out["bits"] == pytest.approx(math.log2(3))
    assert 0 < out["chance_bits"] < 0.2 and out["bits_beyond_chance"] > 1.3 and out["p"] < 0.001


def test_a_threshold_below_the_smallest_or_above_the_largest_level_is_flagged():
    from touch4d.study.analysis import summary_text

    rng = np.random.default_rng(9)
    sharp = pd.DataFrame(tilt_rows(rng, 0.0, 0.2, 0.0, 12, participant="P01")
                         + tilt_rows(rng, 0.0, 0.2, 0.0, 12, participant="P02"))
    flat = pd.DataFrame(tilt_rows(rng, 0.0, 400.0, 0.0, 12, participant="P01"))
    for data in (sharp, flat):
        data["timed_out"] = False
    low, high = psychometric(sharp, bootstrap=0), psychometric(flat, bootstrap=0)
    assert low["threshold_deg"] < 2 and low["threshold_range"] == "below" and not low["within_range"]
    assert low["threshold_outside_by_participant"] == {"P01": "below", "P02": "below"}
    assert all(0 < t < 2 for t in low["threshold_by_participant"].values())       # kept, flagged
    assert high["threshold_by_participant"] == {"P01": None}
    assert high["threshold_outside_by_participant"] == {"P01": "above"}
    assert high["threshold_deg"] > 16 and high["threshold_range"] == "above" and not high["within_range"]
    assert low["levels_shown_deg"] == [2.0, 16.0]
    text = summary_text({"trials": 1, "participants": ["P01"], "cells": [], "tests": {},
                         "psychometric": {"tilt": {"touch": low, "visual": high}}})
    assert "below the smallest level shown, 2 deg" in text and "P01 below, P02 below" in text
    assert "no threshold within the levels shown" in text and "the largest level, 16 deg" in text


def perfectly_separated(tmp_path):
    """Look-alikes answered all wrong by sight and all right by touch, by three participants."""
    rows = []
    for i in range(3):
        for c, condition in enumerate(CONDITIONS):
            for t, answer in enumerate(("a", "b", "c")):
                response = {"a": "b", "b": "c", "c": "a"}[answer] if condition == "visual" else answer
                rows.append(row(f"P{i + 1:02d}", c, t, "looks", "look-alikes", condition, answer, answer, response,
                                math.nan))
    return write_sessions(tmp_path, rows)


def test_perfect_separation_reaches_the_terminal_and_the_json(tmp_path, capsys):
    where = perfectly_separated(tmp_path)
    assert main(["study", "analyze", str(where), "--no-report", "--bootstrap", "0"]) == 0
    out = capsys.readouterr().out
    assert "not valid: perfect separation" in out
    assert "warning: looks: perfect separation (visual all wrong, touch all correct, visual+touch all correct)" in out
    assert main(["study", "analyze", str(where), "--json", "--no-report", "--bootstrap", "0"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["tests"]["looks"]["separation"] == {"visual": "all wrong", "touch": "all correct",
                                                      "visual+touch": "all correct"}
    assert any("perfect separation" in w for w in result["warnings"])
    # 0 of 9 right by sight, yet a consistent confusion: the bits say so, beside what chance gives
    cell = result["tasks"]["looks"]["visual"]
    assert cell["accuracy"] == 0 and cell["information_bits"] == pytest.approx(math.log2(3))
    assert 0 < cell["information_chance_bits"] < cell["information_bits"]
    assert cell["information_bits_beyond_chance"] == pytest.approx(math.log2(3) - cell["information_chance_bits"])


def test_the_report_names_its_columns_and_axes_and_writes_a_dash_for_what_is_missing(tmp_path):
    from touch4d.study.analysis import figure_confusions, report_html

    rng = np.random.default_rng(9)
    rows = synthetic(rng, 2, 6, {"visual": 0.4, "touch": 0.8, "visual+touch": 0.9})
    rows += tilt_rows(rng, 0.0, 0.2, 0.0, 6, participant="P01") + tilt_rows(rng, 0.0, 3.0, 0.0, 6, participant="P02")
    data = load(write_sessions(tmp_path, rows))
    result = analyze(data, bootstrap=0)
    page = report_html(result, data)
    assert "None" not in page and "nan" not in page
    for raw in ("p_above_chance", "time_touching_s", "information_bits", "rt_s", "threshold_deg", "pse_deg"):
        assert raw not in page
    assert "<th>time touching, median (s)</th>" in page and "<th>p (above chance)</th>" in page
    assert "(below 2)</td>" in page                         # P01's threshold, below the smallest level
    assert "perfect separation" not in page
    axes = [ax for ax in figure_confusions(result).axes if ax.get_title()]
    assert axes and all(ax.get_xlabel() == "answer given" and ax.get_ylabel() == "truth (correct answer)"
                        for ax in axes)
    page = report_html(*(lambda d: (analyze(d, bootstrap=0), d))(load(perfectly_separated(tmp_path / "sep"))))
    assert "warning: looks: perfect separation" in page


# ---- the command ----------------------------------------------------------------------------------------------


def test_analyze_prints_json_with_the_agreed_names_and_writes_a_report(tmp_path, capsys):
    rng = np.random.default_rng(5)
    rows = synthetic(rng, 3, 12, {"visual": 0.4, "touch": 0.8, "visual+touch": 0.9})
    rows += tilt_rows(rng, 0.0, 3.0, 0.0, 6, participant="P02")
    write_sessions(tmp_path, rows)
    assert main(["study", "analyze", str(tmp_path), "--json", "--bootstrap", "20"]) == 0
    out = json.loads(capsys.readouterr().out)
    cell = out["tasks"]["looks"]["touch"]
    assert {"accuracy", "n", "ci95", "rt_s"} <= set(cell) and cell["n"] == 36
    assert out["psychometric"]["tilt"]["touch"]["threshold_deg"] > 0
    report = (tmp_path / "report.html").read_text()
    assert out["report"] == str(tmp_path / "report.html")
    assert report.count("<img") >= 4 and "data:image/png;base64," in report
    # one session folder, or its trials.csv, is analysed alone
    assert main(["study", "analyze", str(tmp_path / "P02" / "trials.csv"), "--json", "--no-report",
                 "--bootstrap", "0"]) == 0
    assert json.loads(capsys.readouterr().out)["participants"] == ["P02"]


def test_analyze_names_a_folder_without_tables(tmp_path, capsys):
    assert main(["study", "analyze", str(tmp_path)]) == 2
    assert "trials.csv" in capsys.readouterr().err


def test_a_table_without_the_columns_is_named(tmp_path, capsys):
    (tmp_path / "trials.csv").write_text("participant,correct\nP01,1\n")
    assert main(["study", "analyze", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "trials.csv") in err and "missing" in err and COLUMNS[1] in err


def test_each_participant_gets_a_threshold_of_their_own():
    rng = np.random.default_rng(8)
    rows = tilt_rows(rng, 0.0, 1.5, 0.0, 40, participant="P01") + tilt_rows(rng, 0.0, 6.0, 0.0, 40, participant="P02")
    data = pd.DataFrame(rows)
    data["timed_out"] = False
    own = psychometric(data, bootstrap=0)["threshold_by_participant"]
    assert own["P01"] == pytest.approx(0.6745 * 1.5, rel=0.4) and own["P02"] == pytest.approx(0.6745 * 6.0, rel=0.4)


def test_a_bad_cell_names_file_line_and_column(tmp_path, capsys):
    rows = synthetic(np.random.default_rng(1), 1, 3, {c: 0.5 for c in CONDITIONS})
    write_sessions(tmp_path, rows)
    path = tmp_path / "P01" / "trials.csv"
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[COLUMNS.index("correct")] = "yes"
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    assert main(["study", "analyze", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "line 4, column correct" in err and "'yes'" in err


def test_the_report_leaves_the_callers_matplotlib_backend_and_pyplot_alone(tmp_path):
    import matplotlib
    import matplotlib.pyplot as plt

    from touch4d.study.analysis import figure_summary, report_html

    rng = np.random.default_rng(5)
    rows = synthetic(rng, 2, 6, {"visual": 0.4, "touch": 0.8, "visual+touch": 0.9})
    rows += tilt_rows(rng, 0.0, 3.0, 0.0, 4, participant="P02")
    data = load(write_sessions(tmp_path, rows))
    before = matplotlib.get_backend()
    matplotlib.use("svg")                    # a notebook user's choice, say
    try:
        figures = plt.get_fignums()
        result = analyze(data, bootstrap=0, tests=False)
        assert report_html(result, data).count("data:image/png;base64,") >= 3
        figure_summary(result).savefig(tmp_path / "summary.png")
        assert matplotlib.get_backend() == "svg" and plt.get_fignums() == figures
        assert (tmp_path / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        matplotlib.use(before)

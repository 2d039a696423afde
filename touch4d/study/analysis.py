"""The analysis of a study's trials (`touch4d study analyze DIR`): what touch adds, with intervals.

Per task x condition (practice trials left out): accuracy with its 95% Wilson interval and a
binomial test against chance, answer times (median, IQR), the confusion matrix and the information
it transfers (bits). Per tilt task and condition: a psychometric function, P(answering the option of
positive tilts) = lapse/2 + (1 - lapse) Phi((level - pse) / sigma), fitted by maximum likelihood,
with percentile-bootstrap intervals; threshold = the tilt answered correctly 75% of the time (lapses
aside), sigma Phi^-1(0.75). Per task, the effect of condition: a GEE logistic model (participants as
clusters, exchangeable correlation) with a joint Wald test, and a mixed-effects logistic model
(condition fixed, participant random; statsmodels' BinomialBayesMixedGLM, variational Bayes).
Statistics are statsmodels', scipy's and pandas'; plots matplotlib's.
"""
from __future__ import annotations

import base64
import html
import io
import math
import warnings

import numpy as np
from scipy.stats import norm

from touch4d.errors import Touch4dError, Unavailable

from .conditions import ALL_CONDITIONS
from .design import kind_class, task_kinds
from .infotransfer import transfer_beyond_chance
from .psychometric import fit_psychometric, fit_psychometric_many, psychometric_curve
from .table import read_trials

CONDITION_ORDER = ALL_CONDITIONS     # visual, touch, visual+touch; then the same in the slice, both views
TIMED_OUT = "(timed out)"


class AnalysisError(Touch4dError):
    """Trials that cannot be analysed as asked (says why)."""


def _require():
    try:
        import pandas  # noqa: F401
        import scipy  # noqa: F401
        import statsmodels  # noqa: F401
    except ImportError as exc:
        raise Unavailable(f"the analysis needs {exc.name}: pip install 'touch4d[study]'") from None


def load(where):
    """The trials at or below `where`, practice trials left out."""
    _require()
    data = read_trials(where)
    return data[~data["practice"]].reset_index(drop=True)


def conditions_in(data) -> list[str]:
    """The conditions present, in the usual order (visual, touch, visual+touch, then in the slice and
    both views), others after."""
    present = list(dict.fromkeys(data["condition"]))
    return [c for c in CONDITION_ORDER if c in present] + [c for c in present if c not in CONDITION_ORDER]


def tasks_in(data) -> list[str]:
    """The tasks present, in the order their kinds are defined (front element, look-alikes, tilt:
    `task_kinds`), then by id."""
    kinds = {k: i for i, k in enumerate(task_kinds())}
    first = data.drop_duplicates("task")
    return [str(t) for t in sorted(first["task"], key=lambda t: (
        kinds.get(first.loc[first["task"] == t, "kind"].iloc[0], len(kinds)), str(t)))]


def analyze(data, *, bootstrap: int = 200, seed: int = 0, tests: bool = True) -> dict:
    """Everything the report shows, as plain data (JSON-ready)."""
    _require()
    if len(data) == 0:
        raise AnalysisError("no trials to analyse (only practice trials, or empty tables)")
    conditions = conditions_in(data)
    tasks = tasks_in(data)
    result = {
        "trials": int(len(data)), "participants": sorted(map(str, data["participant"].unique())),
        "conditions": conditions, "tasks": {}, "cells": [], "confusion": {}, "psychometric": {}, "tests": {},
        "by_participant": [],
    }
    for task in tasks:
        rows = data[data["task"] == task]
        chance = 1.0 / rows["answer"].nunique()
        result["tasks"][task] = {}
        result["confusion"][task] = {}
        for condition in conditions:
            cell = rows[rows["condition"] == condition]
            if len(cell) == 0:
                continue
            summary = cell_summary(cell, chance)
            confusion = confusion_matrix(cell)
            transfer = transfer_beyond_chance(confusion.to_numpy(), seed=seed)
            summary["information_bits"] = transfer["bits"]
            summary["information_chance_bits"] = transfer["chance_bits"]
            summary["information_bits_beyond_chance"] = transfer["bits_beyond_chance"]
            summary["information_p"] = transfer["p"]
            summary["max_bits"] = math.log2(max(2, cell["answer"].nunique()))
            result["tasks"][task][condition] = summary
            result["cells"].append({"task": task, "condition": condition, **summary})
            result["confusion"][task][condition] = {
                "answers": list(confusion.index), "responses": list(confusion.columns),
                "counts": confusion.to_numpy().astype(int).tolist()}
            for participant, own in cell.groupby("participant"):
                result["by_participant"].append({"task": task, "condition": condition, "participant": str(participant),
                                                 "n": int(len(own)), "accuracy": float(own["correct"].mean())})
        if fits_psychometric(rows):
            result["psychometric"][task] = {
                condition: psychometric(rows[rows["condition"] == condition], bootstrap=bootstrap, seed=seed)
                for condition in conditions if (rows["condition"] == condition).any()}
        if tests:
            result["tests"][task] = condition_tests(rows, conditions)
    result["warnings"] = condition_test_warnings(result["tests"]) + clock_warnings(data)
    return result


def fits_psychometric(rows) -> bool:
    """Whether a task's trials are of a kind whose levels are one signed quantity (a tilt), fitted by a
    psychometric function per condition (the kind's `psychometric`)."""
    return any(getattr(kind_class(str(kind)), "psychometric", False) for kind in rows["kind"].unique())


def answer_times(frame):
    """The answer times (s) of `frame`'s answered trials that can be trusted: a time stamped by a page
    whose clock claimed too much (`clock_suspect`, see touch4d.study.table) is left out."""
    return frame.loc[~frame["timed_out"] & ~frame["clock_suspect"], "rt_s"].dropna()


def clock_warnings(data) -> list[str]:
    """What the answer times leave out, said once."""
    suspect = data["clock_suspect"] & ~data["timed_out"]
    if not suspect.any():
        return []
    who = ", ".join(sorted(map(str, data.loc[suspect, "participant"].unique())))
    return [f"{int(suspect.sum())} answer(s) ({who}) stamped by a page whose clock claimed more than its answer's "
            "arrival (clock_suspect in trials.csv): their answer times are left out; their answers count"]


def cell_summary(cell, chance: float) -> dict:
    """Accuracy (Wilson 95% interval, binomial test against chance), answer times, exploration."""
    from scipy.stats import binomtest
    from statsmodels.stats.proportion import proportion_confint

    n, k = int(len(cell)), int(cell["correct"].sum())
    low, high = proportion_confint(k, n, alpha=0.05, method="wilson")
    answered = answer_times(cell)
    quartiles = answered.quantile([0.25, 0.5, 0.75]).tolist() if len(answered) else [math.nan] * 3
    return {
        "accuracy": k / n, "n": n, "correct": k, "ci95": [float(low), float(high)], "chance": chance,
        "p_above_chance": float(binomtest(k, n, chance, alternative="greater").pvalue),
        "rt_s": _num(quartiles[1]), "rt_iqr_s": [_num(quartiles[0]), _num(quartiles[2])],
        "timed_out": int(cell["timed_out"].sum()), "participants": int(cell["participant"].nunique()),
        "time_touching_s": _num(cell["time_touching_s"].median()),
        "mean_intensity": _num(cell["mean_intensity"].mean()),
        "path_length": _num(cell["path_length"].median()),
    }


def confusion_matrix(cell):
    """Counts of each response (columns; timed-out trials as their own column) per correct answer (rows)."""
    import pandas as pd

    responses = cell["response"].where(~cell["timed_out"] & (cell["response"] != ""), TIMED_OUT)
    table = pd.crosstab(cell["answer"], responses)
    labels = list(dict.fromkeys(sorted(cell["answer"].unique()) + sorted(set(responses) - {TIMED_OUT})))
    columns = labels + ([TIMED_OUT] if TIMED_OUT in set(responses) else [])
    return table.reindex(index=sorted(cell["answer"].unique()), columns=columns, fill_value=0)


# ---- psychometric function (fitted in touch4d.study.psychometric) -----------------------------------

_Z975 = float(norm.ppf(0.975))    # a two-sided 95% interval: 1.96 standard deviations each side
_PSYCHOMETRIC_KEYS = ("pse_deg", "threshold_deg", "sigma_deg", "slope_per_deg", "lapse")


def psychometric(cell, *, bootstrap: int = 200, seed: int = 0, by_participant: bool = True) -> dict:
    """The psychometric fit of one tilt task x condition, with percentile-bootstrap 95% intervals
    (scipy.stats.bootstrap, trials resampled; the resamples fitted together, from the fit of all
    trials), and each participant's own threshold (unless `by_participant` is False)."""
    from scipy.stats import bootstrap as scipy_bootstrap

    cell = cell[~cell["timed_out"] & cell["level"].notna()]
    if len(cell) < 4 or cell["level"].nunique() < 2:
        return {"error": "too few trials or levels for a psychometric fit", "n": int(len(cell))}
    positive_option = _positive_option(cell)
    level = cell["level"].to_numpy(float)
    positive = (cell["response"] == positive_option).to_numpy(float)
    fit = fit_psychometric(level, positive)
    out = {**fit, "positive": positive_option, "n": int(len(cell))}
    levels = np.unique(level)
    shown = np.abs(levels[levels != 0])
    # A threshold outside the levels shown is no measurement of one: past the largest the answers barely
    # follow the level; below the smallest it is the fitted curve's extrapolation.
    out["threshold_range"] = _threshold_range(fit["threshold_deg"], shown)
    out["within_range"] = out["threshold_range"] == "within"
    out["levels_shown_deg"] = [float(shown.min()), float(shown.max())]
    out["levels"] = levels.tolist()
    out["p_positive"] = [float(positive[level == x].mean()) for x in levels]
    out["trials_per_level"] = [int((level == x).sum()) for x in levels]
    # Each participant's own threshold (no interval): what a paired comparison across conditions takes.
    own, outside = {}, {}
    for participant, rows in cell.groupby("participant") if by_participant else ():
        lv = rows["level"].to_numpy(float)
        if len(rows) >= 4 and len(np.unique(lv)) >= 2:
            f = fit_psychometric(lv, (rows["response"] == positive_option).to_numpy(float))
            where = _threshold_range(f["threshold_deg"], shown)
            own[str(participant)] = f["threshold_deg"] if where != "above" else None   # below: extrapolated
            if where != "within":
                outside[str(participant)] = where
    out["threshold_by_participant"] = own
    out["threshold_outside_by_participant"] = outside
    if bootstrap > 0:
        def statistic(lv, pos, axis=-1):
            lv, pos = np.atleast_2d(lv), np.atleast_2d(pos)
            f = fit_psychometric_many(lv, pos, (fit["pse_deg"], fit["sigma_deg"], fit["lapse"]))
            values = np.array([f[key] for key in _PSYCHOMETRIC_KEYS])
            values[:, (np.diff(np.sort(lv, axis=1), axis=1) > 0).sum(axis=1) < 1] = np.nan   # one level: no fit
            return values

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            boot = scipy_bootstrap((level, positive), statistic, paired=True, vectorized=True,
                                   n_resamples=bootstrap, method="percentile", confidence_level=0.95,
                                   random_state=np.random.default_rng(seed))
        out["ci95"] = {key: [float(boot.confidence_interval.low[i]), float(boot.confidence_interval.high[i])]
                       for i, key in enumerate(_PSYCHOMETRIC_KEYS)}
        out["bootstrap"] = bootstrap
    return out


def _threshold_range(threshold: float, shown) -> str:
    """Where a threshold lies against the (unsigned, nonzero) levels shown: below, within or above."""
    return "below" if threshold < shown.min() else "above" if threshold > shown.max() else "within"


def _positive_option(cell) -> str:
    """The option that positive levels answer (the correct answer of the positive-level trials)."""
    answers = cell.loc[cell["level"] > 0, "answer"]
    if answers.empty:
        raise AnalysisError(f"task {cell['task'].iloc[0]}: no trial with a positive level to tell the options apart")
    return str(answers.mode().iloc[0])


# ---- the effect of condition --------------------------------------------------------------------------


def condition_tests(rows, conditions: list[str], *, mixed: bool = True) -> dict:
    """GEE (joint Wald test of condition, odds ratios against the reference) and the mixed-effects
    logistic model (unless `mixed` is False), for one task. Reference: visual where present (the
    effect of adding touch)."""
    present = [c for c in conditions if (rows["condition"] == c).any()]
    if len(present) < 2:
        return {"error": "one condition only: nothing to compare"}
    reference = "visual" if "visual" in present else present[0]
    frame = rows[["participant", "condition", "correct"]].copy()
    frame["correct"] = frame["correct"].astype(float)
    frame["participant"] = frame["participant"].astype(str)
    out = {"reference": reference}
    if frame["participant"].nunique() < 2:
        out["gee"] = {"error": "one participant: a test across participants needs two or more"}
        out["mixed"] = {"error": "one participant: a random effect needs two or more"}
        return out
    formula = f"correct ~ C(condition, Treatment(reference={reference!r}))"
    out["gee"] = _gee(frame, formula, reference)
    out["mixed"] = _mixed(frame, formula, reference) if mixed else {"error": "mixed model not run"}
    # A condition answered all right (or all wrong) separates the outcome perfectly: its log odds have no
    # finite maximum-likelihood estimate, so the GEE's Wald test and odds ratios mean nothing.
    accuracy = frame.groupby("condition")["correct"].mean()
    separated = {c: "all correct" if accuracy[c] == 1 else "all wrong" for c in present if accuracy[c] in (0.0, 1.0)}
    if separated:
        out["separation"] = separated
    return out


def condition_test_warnings(tests: dict) -> list[str]:
    """Every warning of the tests of condition, one line each, naming the task and the model."""
    lines = []
    for task, test in tests.items():
        if test.get("separation"):
            cells = ", ".join(f"{c} {how}" for c, how in test["separation"].items())
            lines.append(f"{task}: perfect separation ({cells}): the GEE's Wald test and odds ratios are not "
                         f"estimates (its p means nothing); the mixed model's prior keeps its effects finite")
        for label, key in (("GEE", "gee"), ("mixed model", "mixed")):
            lines += [f"{task}: {label}: {w}" for w in test.get(key, {}).get("warnings", [])]
    return lines


def _term_name(name: str, reference: str) -> str:
    """`C(condition, Treatment(...))[T.touch]` -> `touch`."""
    return name.split("[T.", 1)[1].rstrip("]") if "[T." in name else name


def _gee(frame, formula: str, reference: str) -> dict:
    import statsmodels.api as sm
    import statsmodels.formula.api as smf

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = smf.gee(formula, groups="participant", data=frame, family=sm.families.Binomial(),
                            cov_struct=sm.cov_struct.Exchangeable())
            fit = model.fit()
            terms = fit.wald_test_terms(skip_single=False, scalar=True)
            ci, pvalues = fit.conf_int(), fit.pvalues         # computed lazily: inside, so warnings are kept
        except (ValueError, np.linalg.LinAlgError) as exc:
            return {"error": f"GEE failed: {exc}"}
    table = terms.table
    row = [name for name in table.index if name.startswith("C(condition")]
    wald = table.loc[row[0]] if row else None
    effects = {}
    for name in fit.params.index:
        if name.startswith("C(condition"):
            effects[_term_name(name, reference)] = {
                "log_odds": float(fit.params[name]), "ci95": [float(ci.loc[name, 0]), float(ci.loc[name, 1])],
                "odds_ratio": float(math.exp(fit.params[name])) if abs(fit.params[name]) < 700 else math.inf,
                "p": float(pvalues[name])}
    clusters = frame["participant"].nunique()
    note = (f"only {clusters} participants: GEE's robust errors are too small with fewer than about 10"
            if clusters < 10 else None)
    return {
        "test": "GEE logistic, exchangeable within participant; joint Wald test of condition",
        "chi2": float(wald["statistic"]) if wald is not None else math.nan,
        "df": int(wald["df_constraint"]) if wald is not None else 0,
        "p": float(wald["pvalue"]) if wald is not None else math.nan,
        "effects": effects, "warnings": sorted({str(w.message).splitlines()[0] for w in caught})[:5],
        **({"note": note} if note else {}),
    }


def _mixed(frame, formula: str, reference: str) -> dict:
    from statsmodels.genmod.bayes_mixed_glm import BinomialBayesMixedGLM

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = BinomialBayesMixedGLM.from_formula(formula, {"participant": "0 + C(participant)"}, frame)
            fit = model.fit_vb()
        except (ValueError, np.linalg.LinAlgError) as exc:
            return {"error": f"mixed model failed: {exc}"}
    effects = {}
    for name, mean, sd in zip(model.exog_names, fit.fe_mean, fit.fe_sd):
        if name.startswith("C(condition"):
            effects[_term_name(name, reference)] = {
                "log_odds": float(mean), "sd": float(sd),
                "ci95": [float(mean - _Z975 * sd), float(mean + _Z975 * sd)],
                "credible": bool(mean - _Z975 * sd > 0 or mean + _Z975 * sd < 0)}
    return {
        "test": "mixed-effects logistic (BinomialBayesMixedGLM, variational Bayes): condition fixed, "
                "participant random",
        "effects": effects, "participant_sd": float(np.exp(fit.vcp_mean[0])) if len(fit.vcp_mean) else math.nan,
        "warnings": sorted({str(w.message).splitlines()[0] for w in caught})[:5],
    }


def _num(value) -> float | None:
    value = float(value)
    return None if math.isnan(value) else value


# ---- text and HTML ------------------------------------------------------------------------------------


def summary_text(result: dict) -> str:
    """A terminal summary: accuracy with intervals, answer times, psychometric thresholds, tests and
    what they cannot tell (chance's share of the bits, thresholds outside the levels, separation)."""
    lines = [f"{result['trials']} trials, {len(result['participants'])} participants "
             f"({', '.join(result['participants'][:8])}{' ...' if len(result['participants']) > 8 else ''})"]
    lines.append(f"{'task':<12} {'condition':<13} {'n':>5} {'accuracy':>8}  {'95% CI':<15} {'chance':>6} "
                 f"{'bits':>5} {'shuffled':>8} {'beyond':>6} {'rt median':>9}")
    for cell in result["cells"]:
        lo, hi = cell["ci95"]
        rt = f"{cell['rt_s']:.2f} s" if cell["rt_s"] is not None else "-"
        lines.append(f"{cell['task']:<12} {cell['condition']:<13} {cell['n']:>5} {cell['accuracy']:>8.3f}  "
                     f"[{lo:.3f}, {hi:.3f}]  {cell['chance']:>6.3f} {cell['information_bits']:>5.2f} "
                     f"{cell['information_chance_bits']:>8.2f} {cell['information_bits_beyond_chance']:>6.2f} {rt:>9}")
    if result["cells"]:
        lines.append("bits: information transfer, biased upwards with few trials; shuffled: the mean bits of the same "
                     "answers shuffled against the stimuli (what chance gives); beyond: bits less shuffled")
    for task, fits in result["psychometric"].items():
        for condition, fit in fits.items():
            if "error" in fit:
                lines.append(f"{task} {condition}: {fit['error']}")
                continue
            lines.append(f"{task} {condition}: {threshold_text(fit)}")
            outside = fit.get("threshold_outside_by_participant", {})
            if outside:
                low, high = fit["levels_shown_deg"]
                lines.append(f"{task} {condition}: per participant outside the levels shown ({low:g} to {high:g} deg): "
                             + ", ".join(f"{p} {where}" for p, where in sorted(outside.items())))
    for task, test in result["tests"].items():
        gee = test.get("gee", {})
        if "p" in gee:
            lines.append(f"{task}: condition effect (GEE Wald chi2({gee['df']}) = {gee['chi2']:.2f}, "
                         f"p = {gee['p']:.3g}; reference {test['reference']})"
                         + ("; not valid: perfect separation (see the warnings)" if test.get("separation") else "")
                         + (f"; {gee['note']}" if gee.get("note") else ""))
        elif "error" in test or "error" in gee:
            lines.append(f"{task}: {test.get('error') or gee.get('error')}")
    lines += [f"warning: {w}" for w in result.get("warnings", [])]
    return "\n".join(lines)


def threshold_text(fit: dict) -> str:
    """A psychometric fit's threshold in words, or the bound it gives when outside the levels shown."""
    low, high = fit.get("levels_shown_deg", [math.nan, math.nan])
    where = fit.get("threshold_range", "within" if fit["within_range"] else "above")
    if where == "above":
        return (f"no threshold within the levels shown (answers barely follow the level; fitted "
                f"{fit['threshold_deg']:.3g} deg > the largest level, {high:g} deg; lapse {fit['lapse']:.3f})")
    ci = fit.get("ci95", {}).get("threshold_deg")
    interval = f" [{ci[0]:.2f}, {ci[1]:.2f}]" if ci else ""
    below = (f" (below the smallest level shown, {low:g} deg: extrapolated by the fitted curve, not measured)"
             if where == "below" else "")
    return (f"threshold {fit['threshold_deg']:.2f} deg{interval}{below}, pse {fit['pse_deg']:+.2f} deg, "
            f"lapse {fit['lapse']:.3f}")


def _new_figure(rows: int = 1, columns: int = 1, *, figsize, **options):
    """A Figure and its axes from matplotlib's object API: no pyplot, so the caller's backend (a
    notebook's, say) is left as it was and no figure lingers in pyplot's registry."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, columns, **options)


def figure_accuracy(result: dict, ax=None):
    """Accuracy per task and condition with 95% intervals and the chance level (a matplotlib Figure)."""
    tasks = list(result["tasks"])
    conditions = result["conditions"]
    fig, ax = _new_figure(figsize=(1.9 + 1.9 * len(tasks), 3.6)) if ax is None else (ax.figure, ax)
    width = 0.8 / max(1, len(conditions))
    colors = {"visual": "#5b8bd0", "touch": "#e08a3c", "visual+touch": "#5aa85a"}
    for j, condition in enumerate(conditions):
        xs, ys, err = [], [], [[], []]
        for i, task in enumerate(tasks):
            cell = result["tasks"][task].get(condition)
            if cell is None:
                continue
            xs.append(i + (j - (len(conditions) - 1) / 2) * width)
            ys.append(cell["accuracy"])
            err[0].append(max(0.0, cell["accuracy"] - cell["ci95"][0]))   # Wilson's ends may round past it
            err[1].append(max(0.0, cell["ci95"][1] - cell["accuracy"]))
        ax.bar(xs, ys, width * 0.92, yerr=err, capsize=3, label=condition, color=colors.get(condition))
    for i, task in enumerate(tasks):
        chance = next(iter(result["tasks"][task].values()))["chance"]
        ax.hlines(chance, i - 0.45, i + 0.45, colors="k", linestyles="dashed", linewidth=1)
    ax.set_xticks(range(len(tasks)), tasks)
    ax.set_ylim(0, 1.2)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel("proportion correct (95% CI)")
    ax.set_title(f"accuracy, {len(result['participants'])} participants (95% Wilson CI; dashed: chance)", fontsize=10)
    ax.legend(loc="upper center", ncol=len(conditions), fontsize=8, frameon=False)
    fig.tight_layout()
    return fig


def figure_psychometric(result: dict, task: str, ax=None):
    """The psychometric data and fits of a tilt task, one curve per condition."""
    fits = result["psychometric"][task]
    fig, ax = _new_figure(figsize=(5.2, 3.6)) if ax is None else (ax.figure, ax)
    colors = {"visual": "#5b8bd0", "touch": "#e08a3c", "visual+touch": "#5aa85a"}
    for condition, fit in fits.items():
        if "error" in fit:
            continue
        levels = np.asarray(fit["levels"])
        ax.plot(levels, fit["p_positive"], "o", color=colors.get(condition), label=condition)
        grid = np.linspace(levels.min(), levels.max(), 200)
        ax.plot(grid, psychometric_curve(grid, fit["pse_deg"], fit["sigma_deg"], fit["lapse"]),
                color=colors.get(condition))
    positive = next((f["positive"] for f in fits.values() if "positive" in f), "positive")
    ax.set_xlabel(f"{task} level (degrees)")
    ax.set_ylabel(f"P(answer '{positive}')")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("psychometric functions (ML fit with lapses)", fontsize=10)
    ax.legend(fontsize=8, frameon=False)
    fig.tight_layout()
    return fig


def figure_summary(result: dict):
    """Accuracy per task and condition beside the first tilt task's psychometric functions."""
    tilt = next(iter(result["psychometric"]), None)
    width = 1.9 + 1.9 * len(result["tasks"])
    if tilt is None:
        return figure_accuracy(result)
    fig, (left, right) = _new_figure(1, 2, figsize=(width + 4.6, 3.8), width_ratios=[width, 4.6])
    figure_accuracy(result, ax=left)
    figure_psychometric(result, tilt, ax=right)
    fig.tight_layout()
    return fig


def figure_confusions(result: dict):
    tasks = list(result["confusion"])
    conditions = result["conditions"]
    fig, axes = _new_figure(len(tasks), len(conditions), figsize=(3.0 * len(conditions), 2.6 * len(tasks)),
                            squeeze=False)
    for i, task in enumerate(tasks):
        for j, condition in enumerate(conditions):
            ax = axes[i][j]
            table = result["confusion"][task].get(condition)
            if table is None:
                ax.axis("off")
                continue
            counts = np.asarray(table["counts"], dtype=float)
            rates = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)
            ax.imshow(rates, vmin=0, vmax=1, cmap="Blues")
            ax.set_xticks(range(len(table["responses"])), table["responses"], rotation=45, fontsize=7, ha="right")
            ax.set_yticks(range(len(table["answers"])), table["answers"], fontsize=7)
            for (r, c), value in np.ndenumerate(counts):
                ax.text(c, r, int(value), ha="center", va="center", fontsize=7,
                        color="white" if rates[r, c] > 0.6 else "black")
            ax.set_xlabel("answer given", fontsize=7)
            ax.set_ylabel("truth (correct answer)", fontsize=7)
            ax.set_title(f"{task}, {condition}", fontsize=8)
    fig.tight_layout()
    return fig


def figure_times(data):
    conditions = conditions_in(data)
    tasks = tasks_in(data)
    fig, ax = _new_figure(figsize=(1.9 + 1.9 * len(tasks), 3.4))
    groups, labels = [], []
    for task in tasks:
        for condition in conditions:
            groups.append(answer_times(data[(data["task"] == task) & (data["condition"] == condition)]).to_numpy())
            labels.append(f"{task}\n{condition}")
    ax.boxplot(groups, showfliers=False)
    ax.set_xticks(range(1, len(labels) + 1), labels, fontsize=6)
    ax.set_ylabel("answer time (s)")
    fig.tight_layout()
    return fig


def _own_threshold(fit: dict, participant: str) -> str:
    """One participant's threshold as the report shows it: the value, or the bound when outside the levels."""
    where = fit.get("threshold_outside_by_participant", {}).get(participant)
    low, high = fit["levels_shown_deg"]
    value = fit["threshold_by_participant"][participant]
    if where == "above":
        return f"> {high:g}"
    if value is None:
        return "-"
    return f"{value:.2f} (below {low:g})" if where == "below" else f"{value:.2f}"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return base64.b64encode(buf.getvalue()).decode()


# The cells' keys as the report's column headings say them.
CELL_COLUMNS = {
    "task": "task", "condition": "condition", "n": "trials", "accuracy": "accuracy", "95% CI": "95% CI",
    "chance": "chance", "p_above_chance": "p (above chance)", "information_bits": "bits",
    "information_chance_bits": "bits by chance", "information_bits_beyond_chance": "bits beyond chance",
    "rt_s": "answer time, median (s)", "RT IQR (s)": "answer time, IQR (s)", "timed_out": "timed out",
    "time_touching_s": "time touching, median (s)", "mean_intensity": "mean intensity",
    "path_length": "hand path, median",
}
PSYCHOMETRIC_COLUMNS = {"pse_deg": "PSE (deg)", "threshold_deg": "threshold (deg)", "sigma_deg": "sigma (deg)",
                        "slope_per_deg": "slope (per deg)", "lapse": "lapse rate"}


def report_html(result: dict, data, title: str = "touch4d study") -> str:
    """A self-contained HTML report (plots embedded as PNG) of `analyze`'s result."""
    import pandas as pd

    esc = html.escape
    cells = pd.DataFrame(result["cells"])
    if not cells.empty:
        cells["95% CI"] = cells["ci95"].map(lambda c: f"[{c[0]:.3f}, {c[1]:.3f}]")
        cells["RT IQR (s)"] = cells["rt_iqr_s"].map(
            lambda c: "-" if c[0] is None else f"[{c[0]:.2f}, {c[1]:.2f}]")
        cells = cells[list(CELL_COLUMNS)].rename(columns=CELL_COLUMNS)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
             "img{max-width:100%}</style></head><body>",
             f"<h1>{esc(title)}</h1>",
             f"<p>{result['trials']} trials (practice left out) from {len(result['participants'])} participants: "
             f"{esc(', '.join(result['participants']))}.</p>",
             "<h2>Accuracy</h2>", f"<img alt='accuracy' src='data:image/png;base64,{_png(figure_accuracy(result))}'>",
             cells.to_html(index=False, float_format=lambda v: f"{v:.3g}", na_rep="-") if not cells.empty else "",
             "<p><small>Bits: the information transferred (maximum likelihood), biased upwards with few trials; "
             "bits by chance: their mean with the same answers shuffled against the stimuli (what answers that "
             "carry nothing would show); bits beyond chance: the difference.</small></p>"]
    for task in result["psychometric"]:
        parts.append(f"<h2>Psychometric function: {esc(task)}</h2>")
        parts.append(f"<img alt='psychometric {esc(task)}' "
                     f"src='data:image/png;base64,{_png(figure_psychometric(result, task))}'>")
        rows = []
        for condition, fit in result["psychometric"][task].items():
            if "error" in fit:
                rows.append({"condition": condition, "note": fit["error"]})
                continue
            row = {"condition": condition, "trials": fit["n"]}
            for key in _PSYCHOMETRIC_KEYS:
                ci = fit.get("ci95", {}).get(key)
                row[PSYCHOMETRIC_COLUMNS[key]] = f"{fit[key]:.3g}" + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci else "")
            row["note"] = "" if fit["within_range"] else threshold_text(fit)
            rows.append(row)
        parts.append(pd.DataFrame(rows).fillna("").to_html(index=False))
        fits = {c: f for c, f in result["psychometric"][task].items() if "error" not in f}
        own = pd.DataFrame({c: {p: _own_threshold(f, p) for p in f["threshold_by_participant"]}
                            for c, f in fits.items()})
        if not own.empty:
            low, high = next(iter(fits.values()))["levels_shown_deg"]
            parts.append(f"<p>Threshold (degrees) per participant; outside the levels shown ({low:g} to {high:g}) "
                         f"it is no measurement: below {low:g} the fitted curve's extrapolation, &gt; {high:g} where "
                         f"the answers barely follow the level; - where too few trials:</p>")
            parts.append(own.sort_index().fillna("-").to_html())
    parts.append("<h2>Effect of condition</h2>")
    if result.get("warnings"):
        parts.append("<ul>" + "".join(f"<li>warning: {esc(w)}</li>" for w in result["warnings"]) + "</ul>")
    for task, test in result["tests"].items():
        parts.append(f"<h3>{esc(task)}</h3>")
        if "error" in test:
            parts.append(f"<p>{esc(test['error'])}</p>")
            continue
        gee, mixed = test.get("gee", {}), test.get("mixed", {})
        if "p" in gee:
            parts.append(f"<p>{esc(gee['test'])}: chi2({gee['df']}) = {gee['chi2']:.2f}, p = {gee['p']:.3g} "
                         f"(reference: {esc(test['reference'])}).</p>")
        rows = []
        for name, effect in gee.get("effects", {}).items():
            mixed_effect = mixed.get("effects", {}).get(name, {})
            rows.append({"condition vs " + test["reference"]: name,
                         "GEE log odds [95% CI]": f"{effect['log_odds']:.2f} [{effect['ci95'][0]:.2f}, "
                                                  f"{effect['ci95'][1]:.2f}]",
                         "GEE p": f"{effect['p']:.3g}",
                         "mixed model log odds [95% CrI]": (f"{mixed_effect['log_odds']:.2f} "
                                                            f"[{mixed_effect['ci95'][0]:.2f}, "
                                                            f"{mixed_effect['ci95'][1]:.2f}]")
                         if mixed_effect else "-"})
        if rows:
            parts.append(pd.DataFrame(rows).to_html(index=False))
        for label, part in (("GEE", gee), ("mixed model", mixed)):
            if part.get("error"):
                parts.append(f"<p>{label}: {esc(part['error'])}</p>")
            elif part.get("note"):
                parts.append(f"<p><small>{label}: {esc(part['note'])}</small></p>")
    parts.append("<h2>Confusion matrices</h2>")
    parts.append(f"<img alt='confusions' src='data:image/png;base64,{_png(figure_confusions(result))}'>")
    parts.append("<h2>Answer times</h2>")
    parts.append(f"<img alt='times' src='data:image/png;base64,{_png(figure_times(data))}'>")
    if result["by_participant"]:
        table = pd.DataFrame(result["by_participant"]).pivot_table(
            index="participant", columns=["task", "condition"], values="accuracy")
        parts.append("<h2>Accuracy per participant</h2>")
        parts.append(table.to_html(float_format=lambda v: f"{v:.2f}", na_rep="-"))
    parts.append("</body></html>")
    return "\n".join(parts)

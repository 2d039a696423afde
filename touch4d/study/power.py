"""Power by simulation (`touch4d study power`): how many participants a study needs.

For each sample size N, `simulations` whole studies are simulated, participants drawn from a
population (the model observers' noise and lapse, from a pilot's fit or the defaults), and each is
analysed with the models of `touch4d study analyze` (GEE and the mixed-effects logistic model, the
psychometric fit of tilt tasks). The power to find an effect is the share of simulated studies that
find it: GEE p < alpha, or a 95% credible interval of the mixed model that excludes 0 (`mixed`: the
slower model, off by default); a tilt task also reports its threshold's bootstrap interval width.
Participant i of simulation s is the same person at every N (seeds of (study, "power", participant,
simulation)): the curve's points share their random numbers, so it is smooth in N. A participant
answers by draws from the observer's answer shares (`touch4d.study.answers`, measured once per run);
`exact` runs the observer's whole pipeline on every trial instead (the same answers in distribution,
a hundred times slower).
"""
from __future__ import annotations

import base64
import contextlib
import io
from dataclasses import dataclass, field, replace

import numpy as np

from touch4d.errors import ConfigError
from touch4d.tactile import Glove

from .design import Study
from .fanout import Cluster, dask_client, fan_out, seed_of, signature
from .answers import SAMPLES, AnswerModel, answer_model, answered_rows
from .observer import ModelObserver
from .plan import participant_ids, plan_session, quick_plan
from .psychophysics import HUMAN_NOISE
from .simulate import session_rows

DESIGN = "power"
ALPHA = 0.05


@dataclass(frozen=True)
class Population:
    """Participants to draw: typical touch and visual noise, lapse, and the spread (sd of the log of
    each participant's noise factor, as in `simulate`)."""

    noise: float = HUMAN_NOISE       # the fingertip's amplitude discrimination (psychophysics)
    visual_noise: float = 0.5
    lapse: float = 0.03
    spread: float = 0.25
    source: str = "defaults (touch noise from published vibrotactile thresholds)"

    @classmethod
    def from_fit(cls, fit: dict, study: Study, path="FIT.json") -> "Population":
        """The population of a pilot's fit (`touch4d study fit --out`); it must be of this study."""
        if fit.get("study") != study.name:
            raise ConfigError(path, "study", f"a fit of study '{study.name}' (refit the pilot of this study)",
                              got=fit.get("study"))
        try:
            population = fit["population"]
            return cls(noise=float(population["noise"]), visual_noise=float(population["visual_noise"]),
                       lapse=float(population["lapse"]), spread=float(population["spread"]), source=str(path))
        except (KeyError, TypeError, ValueError):
            raise ConfigError(path, "population", "noise, visual_noise, lapse and spread (numbers) as "
                              "touch4d study fit writes them") from None

    def factor(self, rng: np.random.Generator) -> float:
        """One participant's noise factor: exp(N(0, spread))."""
        return float(np.exp(rng.normal(0.0, self.spread))) if self.spread > 0 else 1.0

    def participant(self, observer: ModelObserver, rng: np.random.Generator) -> ModelObserver:
        """One participant: the population's trained observer with its noise times `factor`."""
        return observer.with_noise(self.factor(rng))


@dataclass
class PowerSetup:
    """Everything a worker needs to simulate and analyse one study (sent to each worker once)."""

    observer: ModelObserver
    glove: Glove
    study: Study
    population: Population
    quick: bool = False
    bootstrap: int = 100
    seed: int = 0
    alpha: float = ALPHA
    mixed: bool = False               # also the mixed-effects model (slow; its intervals too narrow, see docs)
    exact: bool = False               # the observer's pipeline on every trial, not its answer shares
    samples: int = SAMPLES            # trials per stimulus behind the answer shares
    answers: AnswerModel | None = None
    _plans: dict = field(default_factory=dict, repr=False)

    def trials(self, participant: str):
        """A participant's planned trials (the same in every simulation: kept once per process)."""
        if participant not in self._plans:
            self._plans[participant] = (quick_plan if self.quick else plan_session)(self.study, participant)
        return self._plans[participant]


def simulated_data(setup: PowerSetup, n: int, simulation: int):
    """The trials (a DataFrame, practice left out) of one simulated study of `n` participants."""
    import pandas as pd

    if not setup.exact and setup.answers is None:
        raise ValueError("PowerSetup: answer shares are needed unless exact (power_curves measures them)")
    rows = []
    for participant in participant_ids(n):
        seed = seed_of(setup.study, DESIGN, participant, simulation, setup.seed)
        rng = np.random.default_rng(seed)
        trials = setup.trials(participant)
        if setup.exact:
            own = setup.population.participant(setup.observer, rng)
            rows += session_rows(own, setup.glove, setup.study, participant, trials, seed=seed)
        else:
            rows += answered_rows(setup.answers, setup.population.factor(rng), setup.population.lapse, participant,
                                  trials, seed=seed, touches=setup.observer.exploration.touches)
    data = pd.DataFrame(rows)
    return data[~data["practice"]].reset_index(drop=True)


def study_outcome(data, *, bootstrap: int = 100, seed: int = 0, alpha: float = ALPHA, mixed: bool = True) -> dict:
    """What one (simulated) study finds, per task: each condition effect's GEE p and whether the mixed
    model's 95% interval excludes 0 (None if `mixed` is False), and per tilt condition the threshold's
    95% interval width."""
    from .analysis import conditions_in, condition_tests, fits_psychometric, psychometric, tasks_in

    conditions = conditions_in(data)
    outcome = {}
    for task in tasks_in(data):
        rows = data[data["task"] == task]
        tests = condition_tests(rows, conditions, mixed=mixed)
        gee, mixed_fit = tests.get("gee", {}), tests.get("mixed", {})
        found = {"joint_p": gee.get("p"), "effects": {}}
        for name, effect in gee.get("effects", {}).items():
            credible = mixed_fit.get("effects", {}).get(name, {}).get("credible")
            found["effects"][name] = {"gee_p": effect["p"], "gee_found": bool(effect["p"] < alpha),
                                      "mixed_found": bool(credible) if credible is not None else None}
        if fits_psychometric(rows):
            widths = {}
            for condition in conditions:
                fit = psychometric(rows[rows["condition"] == condition], bootstrap=bootstrap, seed=seed,
                                 by_participant=False)
                ci = fit.get("ci95", {}).get("threshold_deg")
                widths[condition] = (ci[1] - ci[0]) if ci and fit.get("within_range") else None
            found["threshold_ci_width_deg"] = widths
        outcome[task] = found
    return outcome


def simulate_outcome(setup: PowerSetup, n: int, simulation: int) -> dict:
    """One simulation of a study of `n` participants: simulated, then analysed (a worker's job)."""
    import warnings

    data = simulated_data(setup, n, simulation)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return study_outcome(data, bootstrap=setup.bootstrap, seed=simulation, alpha=setup.alpha, mixed=setup.mixed)


def summarise(outcomes: dict[int, list[dict]]) -> dict:
    """Power per N, task and effect (GEE and mixed model; Wilson 95% intervals of the simulation
    error) and the tilt threshold's median interval width, from each N's list of `study_outcome`s."""
    from statsmodels.stats.proportion import proportion_confint

    def share(flags):
        flags = [f for f in flags if f is not None]
        if not flags:
            return {"power": None, "ci95": None, "simulations": 0}
        k, n = int(sum(flags)), len(flags)
        low, high = proportion_confint(k, n, alpha=0.05, method="wilson")
        return {"power": k / n, "ci95": [float(low), float(high)], "simulations": n}

    curves: dict = {}
    for n, found in sorted(outcomes.items()):
        for task in found[0]:
            entry = curves.setdefault(task, {"effects": {}, "threshold_ci_width_deg": {}})
            for name in found[0][task]["effects"]:
                effect = entry["effects"].setdefault(name, {"sizes": [], "gee": [], "mixed": []})
                effect["sizes"].append(n)
                effect["gee"].append(share([f[task]["effects"].get(name, {}).get("gee_found") for f in found]))
                effect["mixed"].append(share([f[task]["effects"].get(name, {}).get("mixed_found") for f in found]))
            for condition in found[0][task].get("threshold_ci_width_deg", {}):
                widths = [f[task]["threshold_ci_width_deg"].get(condition) for f in found]
                measured = [w for w in widths if w is not None]
                width = entry["threshold_ci_width_deg"].setdefault(condition, {"sizes": [], "median": [],
                                                                               "measured": []})
                width["sizes"].append(n)
                width["median"].append(float(np.median(measured)) if measured else None)
                width["measured"].append(len(measured) / len(widths))
    return curves


def power_curves(setup: PowerSetup, sizes: list[int], simulations: int, *, cluster: Cluster = Cluster(),
                 out=None, progress: bool = True) -> dict:
    """Simulate and analyse `simulations` studies at each of `sizes` on `cluster`; the summary (and,
    with `out`, a cache of each simulation under out/cache so an interrupted run resumes)."""
    from pathlib import Path

    if not sizes or min(sizes) < 2:
        raise ConfigError("command line", "--participants", "sizes of 2 or more participants (a test across "
                          "participants needs two)", got=sizes)
    run = {"design": DESIGN, "study": setup.study.name, "study_seed": setup.study.seed, "glove": setup.glove.path,
           "motors": len(setup.glove.motor_names), "population": setup.population.__dict__, "quick": setup.quick,
           "noise_per_motor": setup.observer.noise_per_motor.tolist(),   # another skin, another cache
           "bootstrap": setup.bootstrap, "seed": setup.seed, "alpha": setup.alpha, "mixed": setup.mixed,
           "exact": setup.exact, **({} if setup.exact else {"samples": setup.samples})}
    cache = Path(out) / "cache" / signature(run) if out is not None else None
    jobs = {f"n{n}-s{s}": (n, s) for n in sizes for s in range(simulations)}
    with contextlib.ExitStack() as stack:          # one Dask client for the answer shares and the studies
        client = None if cluster.workers == 0 and not cluster.scheduler else stack.enter_context(dask_client(cluster))
        if not setup.exact and setup.answers is None:
            setup = replace(setup, answers=answer_model(
                setup.observer, setup.study, spread=setup.population.spread, samples=setup.samples,
                seed=setup.seed, cluster=cluster, cache=None if cache is None else cache / "answers",
                progress=progress, client=client))
        done = fan_out(simulate_outcome, jobs, shared=setup, cluster=cluster, cache=cache, label="studies",
                       progress=progress, client=client)
    outcomes = {n: [done[f"n{n}-s{s}"] for s in range(simulations)] for n in sizes}
    return {**run, "sizes": list(sizes), "simulations": simulations, "curves": summarise(outcomes),
            "population_source": setup.population.source}


def figure_power(result: dict):
    """Power curves (one panel per task; GEE solid, mixed model dashed) and tilt interval widths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = result["curves"]
    tilt = [t for t in curves if curves[t]["threshold_ci_width_deg"]]
    panels = len(curves) + len(tilt)
    fig, axes = plt.subplots(1, panels, figsize=(4.2 * panels, 3.6), squeeze=False)
    for ax, (task, entry) in zip(axes[0], curves.items()):
        for i, (name, effect) in enumerate(entry["effects"].items()):
            color = f"C{i}"
            for model, style in (("gee", "-"), ("mixed", "--")):
                points = [(n, p["power"], p["ci95"]) for n, p in zip(effect["sizes"], effect[model])
                          if p["power"] is not None]
                if not points:
                    continue
                ns, ps, cis = zip(*points)
                ax.plot(ns, ps, style, marker="o", color=color, label=f"{name} vs visual ({model})")
                ax.fill_between(ns, [c[0] for c in cis], [c[1] for c in cis], color=color, alpha=0.12)
        ax.axhline(0.8, color="k", linewidth=0.8, linestyle=":")
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("participants")
        ax.set_ylabel(f"power (alpha {result['alpha']})")
        ax.set_title(task, fontsize=10)
        ax.legend(fontsize=7, frameon=False)
    for ax, task in zip(axes[0][len(curves):], tilt):
        for condition, width in curves[task]["threshold_ci_width_deg"].items():
            points = [(n, w) for n, w in zip(width["sizes"], width["median"]) if w is not None]
            if points:
                ax.plot(*zip(*points), marker="o", label=condition)
        ax.set_xlabel("participants")
        ax.set_ylabel("threshold 95% CI width (deg), median")
        ax.set_title(f"{task}: threshold precision", fontsize=10)
        ax.legend(fontsize=7, frameon=False)
    fig.tight_layout()
    return fig


def report_html(result: dict) -> str:
    """A self-contained HTML page: the power curves and the table behind them."""
    import html

    import matplotlib.pyplot as plt

    fig = figure_power(result)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    rows = []
    for task, entry in result["curves"].items():
        for name, effect in entry["effects"].items():
            for n, gee, mixed in zip(effect["sizes"], effect["gee"], effect["mixed"]):
                rows.append(f"<tr><td>{html.escape(task)}</td><td>{html.escape(name)} vs visual</td><td>{n}</td>"
                            f"<td>{_pct(gee)}</td><td>{_pct(mixed)}</td></tr>")
    population = result["population"]
    return "\n".join([
        "<!doctype html><html><head><meta charset='utf-8'><title>touch4d study power</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:3px 6px}img{max-width:100%}</style></head><body>",
        f"<h1>Power by simulation: {html.escape(result['study'])}</h1>",
        f"<p>{result['simulations']} simulated studies per size; participants drawn from "
        f"{html.escape(str(result['population_source']))}: touch noise {population['noise']:.3g}, visual noise "
        f"{population['visual_noise']:.3g}, lapse {population['lapse']:.3g}, spread {population['spread']:.3g}; "
        f"glove {html.escape(str(result['glove']))} ({result['motors']} motors). Power: the share of studies where "
        f"GEE gives p &lt; {result['alpha']} (or the mixed model's 95% interval excludes 0), with the Wilson 95% "
        f"interval of the simulation error.</p>",
        f"<img alt='power curves' src='data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}'>",
        "<table><tr><th>task</th><th>effect</th><th>participants</th><th>power, GEE</th><th>power, mixed model"
        "</th></tr>", *rows, "</table></body></html>"])


def _pct(share: dict) -> str:
    if share["power"] is None:
        return "-"
    return f"{share['power']:.2f} [{share['ci95'][0]:.2f}, {share['ci95'][1]:.2f}]"


def summary_text(result: dict) -> str:
    """The curves as a terminal table."""
    lines = [f"{result['study']}: power by simulation ({result['simulations']} studies per size, alpha "
             f"{result['alpha']}; GEE / mixed model)"]
    for task, entry in result["curves"].items():
        for name, effect in entry["effects"].items():
            cells = "  ".join(f"N={n}: {_pct(g).split(' ')[0]}/{_pct(m).split(' ')[0]}"
                              for n, g, m in zip(effect["sizes"], effect["gee"], effect["mixed"]))
            lines.append(f"  {task:<11} {name + ' vs visual':<24} {cells}")
        for condition, width in entry["threshold_ci_width_deg"].items():
            cells = "  ".join(f"N={n}: {'-' if w is None else f'{w:.2f}'}" for n, w in zip(width["sizes"],
                                                                                        width["median"]))
            lines.append(f"  {task:<11} {'threshold CI width ' + condition:<24} {cells} (deg)")
    return "\n".join(lines)


__all__ = ["Population", "PowerSetup", "simulated_data", "study_outcome", "simulate_outcome", "summarise",
           "power_curves", "report_html", "summary_text", "figure_power"]

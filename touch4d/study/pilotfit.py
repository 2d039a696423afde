"""A pilot fitted (`touch4d study fit PILOT_DIR`): each participant's touch noise, visual noise and
lapse by maximum likelihood under the model observer, with profile-likelihood intervals, and the
population's spread.

The model observer has no closed-form likelihood, so the fit uses its accuracy surface: per task x
condition, the lapse-free probability of a correct answer at each touch noise and visual noise of a
log-spaced grid, simulated once (on Dask) and interpolated in log noise. A touch cell depends on the
touch noise alone, a visual cell on the visual noise, a visual+touch cell on both. A participant who
answers k_c of n_c trials of cell c correctly (timed out: wrong) then has the binomial likelihood
prod_c Binom(k_c | n_c, lapse/m_c + (1 - lapse) a_c(touch noise, visual noise)), m_c options,
evaluated at once on a fine grid (noises x lapses: vectorised, a few ms a participant). Intervals:
the parameter values whose profile log-likelihood lies within chi2_1(0.95)/2 of the
maximum (Wilks); one that reaches the grid's end is open there (`open_low`/`open_high`).
Population: the geometric means of the noises, the mean lapse, and the spread (sd of the log touch
noise across participants less its estimation variance, method of moments), with a participant
bootstrap interval.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from touch4d.errors import ConfigError

from .fanout import Cluster, fan_out, seed_of, signature
from .observer import ModelObserver
from .plan import participant_ids, plan_session
from .simulate import Timing, simulate_trial

DESIGN = "fit-surface"
TOUCH_GRID = (0.02, 5.0)          # touch noise range (units of full drive), log-spaced
VISUAL_GRID = (0.1, 8.0)          # visual noise range (the view's feature units), log-spaced
LAPSE_MAX = 0.5
_WILKS = 0.5 * 3.841458820694124  # chi2_1(0.95) / 2


def observer_with(observer: ModelObserver, noise: float, visual_noise: float, lapse: float) -> ModelObserver:
    """`observer`'s trained cues felt and seen with these noises and this lapse rate."""
    other = copy.copy(observer)
    other.noise, other.visual_noise, other.lapse = float(noise), float(visual_noise), float(lapse)
    return other


@dataclass
class Surface:
    """Lapse-free accuracy per cell ("task|condition") on the grid of log touch noise x log visual
    noise: `values[cell]` is (touch grid,) for touch cells, (visual grid,) for visual ones, (touch,
    visual) for visual+touch ones; `options[cell]`: the number of options."""

    study: str
    log_touch: np.ndarray
    log_visual: np.ndarray
    values: dict
    options: dict
    _both: dict = field(default_factory=dict, repr=False)    # the visual+touch cells' interpolators

    def uses(self, cell: str) -> str:
        condition = cell.split("|", 1)[1]
        return {"touch": "touch", "visual": "visual"}.get(condition, "both")

    def accuracy(self, cell: str, log_touch: float, log_visual: float) -> float:
        """The interpolated lapse-free accuracy of a cell (linear in log noise, clamped to the grid)."""
        values = self.values[cell]
        t = float(np.clip(log_touch, self.log_touch[0], self.log_touch[-1]))
        v = float(np.clip(log_visual, self.log_visual[0], self.log_visual[-1]))
        uses = self.uses(cell)
        if uses == "touch":
            return float(np.interp(t, self.log_touch, values))
        if uses == "visual":
            return float(np.interp(v, self.log_visual, values))
        if cell not in self._both:
            from scipy.interpolate import RegularGridInterpolator

            self._both[cell] = RegularGridInterpolator((self.log_touch, self.log_visual), np.asarray(values))
        return float(self._both[cell]([t, v])[0])

    def to_json(self) -> dict:
        return {"study": self.study, "log_touch": self.log_touch.tolist(), "log_visual": self.log_visual.tolist(),
                "values": {k: np.asarray(v).tolist() for k, v in self.values.items()}, "options": self.options}


@dataclass
class SurfaceSetup:
    """What a worker needs to simulate one grid point of one cell."""

    observer: ModelObserver
    glove: object
    study: object
    trials: dict            # cell -> list of Trial
    seed: int = 0


def cell_trials(study, participants: int = 6) -> dict:
    """The main trials of `participants` planned sessions, per cell ("task|condition")."""
    cells: dict = {}
    for participant in participant_ids(participants):
        for trial in plan_session(study, participant):
            if not trial.practice:
                cells.setdefault(f"{trial.task}|{trial.condition}", []).append(trial)
    return cells


def _grid_point(setup: SurfaceSetup, cell: str, noise: float, visual_noise: float, count: int) -> dict:
    """Share of `count` trials of a cell answered correctly by the lapse-free observer at these noises."""
    own = observer_with(setup.observer, noise, visual_noise, 0.0)
    trials = setup.trials[cell]
    seed = seed_of(setup.study, DESIGN, f"{cell}|{noise:.6g}|{visual_noise:.6g}", 0, setup.seed)
    correct = 0
    for i in range(count):
        trial = trials[i % len(trials)]
        result = simulate_trial(own, setup.glove, setup.study, trial, seed=seed + i, timing=Timing())
        correct += result["response"] == trial.answer
    return {"correct": int(correct), "n": int(count)}


def accuracy_surface(observer: ModelObserver, glove, study, *, points: int = 7, trials: int = 60, seed: int = 0,
                     cluster: Cluster = Cluster(), cache=None, progress: bool = True) -> Surface:
    """The observer's lapse-free accuracy per cell on a `points`-per-axis log grid of touch and visual
    noise, `trials` simulated trials per grid point (see the module docstring)."""
    from pathlib import Path

    log_touch = np.linspace(*np.log(TOUCH_GRID), points)
    log_visual = np.linspace(*np.log(VISUAL_GRID), points)
    planned = cell_trials(study)
    setup = SurfaceSetup(observer, glove, study, planned, seed)
    jobs, where = {}, {}
    for cell in planned:
        condition = cell.split("|", 1)[1]
        touches = range(points) if condition != "visual" else [None]
        views = range(points) if condition != "touch" else [None]
        for i in touches:
            for j in views:
                noise = math.exp(log_touch[i]) if i is not None else observer.noise
                visual = math.exp(log_visual[j]) if j is not None else observer.visual_noise
                key = f"{cell.replace('|', '.').replace('+', '-')}-{i}-{j}"
                jobs[key] = (cell, noise, visual, trials)
                where[key] = (cell, i, j)
    run = {"design": DESIGN, "study": study.name, "study_seed": study.seed, "glove": getattr(glove, "path", ""),
           "noise": observer.noise, "noise_per_motor": observer.noise_per_motor.tolist(),
           "visual_noise": observer.visual_noise, "seed": seed, "points": points,
           "trials": trials, "observer_seed": observer.seed}
    cache = Path(cache) / signature(run) if cache is not None else None
    done = fan_out(_grid_point, jobs, shared=setup, cluster=cluster, cache=cache, label="accuracy surface",
                   progress=progress)
    values, options = {}, {}
    for key, (cell, i, j) in where.items():
        share = done[key]["correct"] / done[key]["n"]
        uses = cell.split("|", 1)[1]
        if uses in ("touch", "visual"):
            values.setdefault(cell, np.zeros(points))[i if uses == "touch" else j] = share
        else:
            values.setdefault(cell, np.zeros((points, points)))[i, j] = share
        options[cell] = len(planned[cell][0].options)
    return Surface(study.name, log_touch, log_visual, values, options)


# ---- the likelihood and its maximum -----------------------------------------------------------------


def cell_counts(data) -> dict:
    """{participant: {cell: (correct, trials)}} of a trials table (practice left out; timed out: wrong)."""
    counts: dict = {}
    for (participant, task, condition), rows in data.groupby(["participant", "task", "condition"]):
        counts.setdefault(str(participant), {})[f"{task}|{condition}"] = (int(rows["correct"].sum()), int(len(rows)))
    return counts


FINE = 61                           # the likelihood's grid: points per log noise axis
LAPSES = np.linspace(0.0, LAPSE_MAX, 51)


def dense_accuracy(surface: Surface, fine: int = FINE) -> tuple[np.ndarray, np.ndarray, dict]:
    """The surface interpolated onto a fine grid: (log touch (T,), log visual (V,), {cell: (T, V)})."""
    t = np.linspace(surface.log_touch[0], surface.log_touch[-1], fine)
    v = np.linspace(surface.log_visual[0], surface.log_visual[-1], fine)
    out = {}
    for cell, values in surface.values.items():
        uses = surface.uses(cell)
        if uses == "touch":
            out[cell] = np.repeat(np.interp(t, surface.log_touch, values)[:, None], fine, axis=1)
        elif uses == "visual":
            out[cell] = np.repeat(np.interp(v, surface.log_visual, values)[None, :], fine, axis=0)
        else:
            from scipy.interpolate import RegularGridInterpolator

            mesh = np.stack(np.meshgrid(t, v, indexing="ij"), axis=-1)
            out[cell] = RegularGridInterpolator((surface.log_touch, surface.log_visual), np.asarray(values))(mesh)
    return t, v, out


def log_likelihood(surface: Surface, counts: dict, dense=None) -> np.ndarray:
    """Binomial log-likelihood of one participant's cell counts at every (log touch noise, log visual
    noise, lapse) of the fine grid: an array (T, V, LAPSES)."""
    from scipy.special import xlogy

    _, _, accuracy = dense if dense is not None else dense_accuracy(surface)
    total = 0.0
    for cell, (k, n) in counts.items():
        p = LAPSES / surface.options[cell] + (1.0 - LAPSES) * accuracy[cell][:, :, None]
        p = np.clip(p, 1e-9, 1.0 - 1e-9)
        total = total + xlogy(k, p) + xlogy(n - k, 1.0 - p)
    return total


def _interval(axis: np.ndarray, profile: np.ndarray) -> tuple[float, float, bool, bool]:
    """The ends of {x: profile(x) >= max - chi2_1(0.95)/2}, linearly interpolated between grid points;
    open where the set reaches the grid's end."""
    inside = profile >= profile.max() - _WILKS
    first, last = int(np.argmax(inside)), len(inside) - 1 - int(np.argmax(inside[::-1]))
    level = profile.max() - _WILKS

    def cross(a, b):            # where the profile crosses the level between grid points a and b
        pa, pb = profile[a], profile[b]
        return float(axis[a] + (axis[b] - axis[a]) * (level - pa) / (pb - pa)) if pb != pa else float(axis[a])

    low = float(axis[0]) if first == 0 else cross(first - 1, first)
    high = float(axis[-1]) if last == len(axis) - 1 else cross(last + 1, last)
    return low, high, first == 0, last == len(axis) - 1


def fit_participant(surface: Surface, counts: dict, dense=None) -> dict:
    """Maximum-likelihood touch noise, visual noise and lapse of one participant with profile
    intervals (see the module docstring), on the fine grid."""
    dense = dense if dense is not None else dense_accuracy(surface)
    t, v, _ = dense
    grid = log_likelihood(surface, counts, dense)
    best = np.unravel_index(int(np.argmax(grid)), grid.shape)
    out = {"trials": int(sum(n for _, n in counts.values())), "log_likelihood": float(grid[best])}
    for index, (name, axis) in enumerate((("noise", t), ("visual_noise", v), ("lapse", LAPSES))):
        others = tuple(i for i in range(3) if i != index)
        low, high, open_low, open_high = _interval(axis, grid.max(axis=others))
        scale = (lambda x: float(x)) if name == "lapse" else (lambda x: float(math.exp(x)))
        out[name] = {"estimate": scale(axis[best[index]]), "ci95": [scale(low), scale(high)], "open_low": open_low,
                     "open_high": open_high}
    return out


def fit_pilot(surface: Surface, data, *, seed: int = 0, bootstrap: int = 500) -> dict:
    """Each participant's fit and the population's (see the module docstring)."""
    if len(data) == 0:
        raise ConfigError("command line", "PILOT_DIR", "a pilot with trials (not only practice trials)", got="none")
    counts = cell_counts(data)
    unknown = sorted({cell for own in counts.values() for cell in own} - set(surface.values))
    if unknown:
        raise ConfigError("command line", "PILOT_DIR", f"the tasks and conditions of study '{surface.study}' "
                          f"({', '.join(sorted(surface.values))})", got=", ".join(unknown))
    dense = dense_accuracy(surface)
    participants = {p: fit_participant(surface, own, dense) for p, own in sorted(counts.items())}
    return {"study": surface.study, "participants": participants,
            "population": population_of(participants, seed=seed, bootstrap=bootstrap)}


def population_of(participants: dict, *, seed: int = 0, bootstrap: int = 500) -> dict:
    """The population behind the participants' fits: geometric-mean noises, mean lapse, and the spread
    of the log touch noise beyond each estimate's own error (method of moments; bootstrap interval)."""
    fits = list(participants.values())
    log_noise = np.log([f["noise"]["estimate"] for f in fits])
    log_visual = np.log([f["visual_noise"]["estimate"] for f in fits])
    # an estimate's variance from its interval's width on the log scale (a 95% interval spans 2 x 1.96 sd)
    error = np.array([((math.log(f["noise"]["ci95"][1]) - math.log(f["noise"]["ci95"][0])) / 3.92) ** 2
                      for f in fits])

    def spread(index):
        if len(index) < 2:
            return 0.0
        return math.sqrt(max(0.0, float(np.var(log_noise[index], ddof=1) - error[index].mean())))

    everyone = np.arange(len(fits))
    rng = np.random.default_rng(seed)
    draws = [spread(rng.choice(everyone, len(everyone))) for _ in range(bootstrap)] if len(fits) >= 2 else []
    return {"noise": float(np.exp(log_noise.mean())), "visual_noise": float(np.exp(log_visual.mean())),
            "lapse": float(np.mean([f["lapse"]["estimate"] for f in fits])), "spread": spread(everyone),
            "spread_ci95": [float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))] if draws else None,
            "participants": len(fits)}


def interval_text(estimate: float, low: float, high: float, *, open_low: bool = False, open_high: bool = False,
                  bound: float | None = None) -> str:
    """`estimate [low, high]`, an end open at the grid's end marked < or >, an end at the parameter's
    least value `bound` (a lapse or a spread of 0) marked `(bound)` and an estimate there `at the bound`:
    the data put it below what they can tell apart, which is not certainty that it is exactly that."""
    at = (lambda x: bound is not None and x <= bound)
    lo = f"{low:.3g} (bound)" if at(low) else ("<" if open_low else "") + f"{low:.3g}"
    hi = f"{high:.3g} (bound)" if at(high) else (">" if open_high else "") + f"{high:.3g}"
    return f"{estimate:.3g} [{lo}, {hi}]" + (" at the bound" if at(estimate) else "")


def summary_text(fit: dict) -> str:
    lines = [f"{fit['study']}: {len(fit['participants'])} participants fitted (maximum likelihood, 95% profile "
             f"intervals; < or > marks an interval open at the grid's end, (bound) one open at the parameter's "
             f"least value: the true value may lie above it)"]
    lines.append(f"{'participant':<12} {'trials':>6}  {'touch noise':<24} {'visual noise':<24} {'lapse':<22}")

    def show(p, bound=None):
        return interval_text(p["estimate"], *p["ci95"], open_low=p["open_low"], open_high=p["open_high"],
                             bound=bound)

    for name, own in fit["participants"].items():
        lines.append(f"{name:<12} {own['trials']:>6}  {show(own['noise']):<24} {show(own['visual_noise']):<24} "
                     f"{show(own['lapse'], bound=0.0):<22}")
    population = fit["population"]
    ci = population["spread_ci95"]
    spread = interval_text(population["spread"], *ci, bound=0.0) if ci else f"{population['spread']:.3g}"
    lines.append(f"population: touch noise {population['noise']:.3g}, visual noise {population['visual_noise']:.3g}, "
                 f"lapse {population['lapse']:.3g}, spread {spread}"
                 + (" (no spread beyond the estimates' own error found, not proof of none)"
                    if population["spread"] <= 0 else ""))
    return "\n".join(lines)


__all__ = ["Surface", "accuracy_surface", "dense_accuracy", "cell_counts", "log_likelihood", "fit_participant",
           "fit_pilot",
           "population_of", "observer_with", "interval_text", "summary_text"]

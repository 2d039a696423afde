"""The model observer's answers as probabilities: many simulated participants without re-running its
pipeline on every trial.

A participant of a population is the trained observer with its noise (touch and sight) times a factor
f (`ModelObserver.with_noise`). Lapse aside, its answer to a trial is a random draw whose
distribution depends only on the task, the condition, the stimulus and f (each trial draws its own
jitter, hand positions and noise). `answer_model` measures that distribution once, at a grid of
log f, by running the observer's whole pipeline - the trial's jittered scene, the scripted hand's
positions, the motor patterns of paper eq. 1-3, the view, the trained cues - on `samples` trials per
stimulus; each trial's noise draws are shared by every f of the grid (common random numbers, so the
shares are smooth in f). A simulated participant then answers each trial by one uniform draw
against the shares interpolated at its log f, with the lapse mixed in as `ModelObserver.respond`
does (a random option with probability lapse). The pipeline runs samples x stimuli times in all,
instead of once per trial of every simulated participant.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from .conditions import BY_NAME
from .design import Study
from .fanout import Cluster, fan_out, seed_of
from .observer import ModelObserver, best_options, patterns_at, view_features
from .plan import Trial, draw_jitter, stimuli_of
from .simulate import Timing, answer_time, table_rows
from .stimuli import in_view, stimulus_scene

DESIGN = "answers"
SAMPLES = 1000          # trials per stimulus: a share's simulation error is at most 0.5/sqrt(1000) = 0.016
GRID = 9                # points of the log noise-factor grid
REACH_SD = 4.0          # the grid spans +-4 sd of the population's log noise factor


@dataclass
class AnswerModel:
    """Per "task|condition|stimulus", the share of each of the task's `options` the observer answers
    (lapse aside) at each point of `log_factors`, from `samples` simulated trials."""

    log_factors: np.ndarray
    shares: dict[str, np.ndarray]        # (len(log_factors), options)
    options: dict[str, list[str]]        # by task
    samples: int

    def probabilities(self, task: str, condition: str, stimulus: str, factor: float, lapse: float) -> np.ndarray:
        """P(each option) of a participant whose noise is `factor` x the observer's, with its lapse."""
        table = self.shares[f"{task}|{condition}|{stimulus}"]
        x = min(max(math.log(factor), self.log_factors[0]), self.log_factors[-1])
        free = np.array([np.interp(x, self.log_factors, table[:, j]) for j in range(table.shape[1])])
        return lapse / table.shape[1] + (1.0 - lapse) * free

    def to_json(self) -> dict:
        return {"log_factors": self.log_factors.tolist(), "options": self.options, "samples": self.samples,
                "shares": {key: value.tolist() for key, value in self.shares.items()}}


def factor_grid(spread: float, points: int = GRID) -> np.ndarray:
    """The log noise factors the shares are measured at: +-REACH_SD sd of the population's spread
    (one point, f = 1, without spread). A participant beyond them (p < 1e-4) is clipped to the end."""
    return np.linspace(-REACH_SD * spread, REACH_SD * spread, points) if spread > 0 else np.zeros(1)


@dataclass
class _Job:
    observer: ModelObserver
    study: Study
    log_factors: np.ndarray
    samples: int
    seed: int


def stimulus_shares(job: _Job, task_id: str, index: int) -> dict:
    """The shares of one stimulus of a task, per condition of the study (a worker's job): the scene of
    each sample trial is shared by the conditions, its hand positions and noise by those of a view."""
    observer, study = job.observer, job.study
    task = study.task(task_id)
    name, level, _ = stimuli_of(task)[index]
    rng = np.random.default_rng(seed_of(study, DESIGN, f"{task_id}|{name}", 0, job.seed))
    conditions = [BY_NAME[c] for c in study.conditions]
    views = list(dict.fromkeys(c.view for c in conditions))
    felt = {v: [] for v in views}
    seen = {v: [] for v in views}
    for _ in range(job.samples):
        scene = stimulus_scene(study, task_id, name, level, draw_jitter(task, rng))
        for view in views:
            shown = in_view(copy.copy(scene), view)
            positions = observer.exploration.positions(rng)
            patterns = patterns_at(observer.glove, shown, positions)
            felt[view].append((patterns, rng.standard_normal(patterns.shape)))
            features = view_features(shown)
            seen[view].append((features, rng.standard_normal(features.shape)))
    options = list(task.options)
    out = {}
    for condition in conditions:
        patterns, touch_z = (np.stack(a) for a in zip(*felt[condition.view]))
        features, view_z = (np.stack(a) for a in zip(*seen[condition.view]))
        rows = []
        for log_factor in job.log_factors:
            factor, total = math.exp(log_factor), np.zeros((job.samples, len(options)))
            if condition.motors:
                total += observer.touch_cue(task_id, condition.view).log_posteriors(
                    patterns + factor * observer.noise_per_motor * touch_z)
            if condition.objects:
                total += observer.view_cue(task_id, condition.view).log_posteriors(
                    (features + factor * observer.visual_noise * view_z)[:, None, :])
            best = best_options(total)                      # ties: each best option equally likely
            rows.append((best / best.sum(axis=1, keepdims=True)).mean(axis=0).tolist())
        out[condition.name] = rows
    return out


def answer_model(observer: ModelObserver, study: Study, *, spread: float, samples: int = SAMPLES, seed: int = 0,
                 cluster: Cluster = Cluster(), cache=None, progress: bool = True, client=None) -> AnswerModel:
    """The observer's answer shares for every task x condition x stimulus of `study` (see the module
    docstring), one Dask job per stimulus (`client`: one open on `cluster`, if any); `cache`: a folder
    that keeps finished stimuli."""
    log_factors = factor_grid(spread)
    jobs = {f"{task.id}-{k}": (task.id, k) for task in study.tasks for k in range(len(stimuli_of(task)))}
    done = fan_out(stimulus_shares, jobs, shared=_Job(observer, study, log_factors, samples, seed), cluster=cluster,
                   cache=cache, label="answer shares", progress=progress, client=client)
    shares = {}
    for task in study.tasks:
        for k, (name, _, _) in enumerate(stimuli_of(task)):
            for condition, rows in done[f"{task.id}-{k}"].items():
                shares[f"{task.id}|{condition}|{name}"] = np.array(rows)
    return AnswerModel(log_factors, shares, {t.id: list(t.options) for t in study.tasks}, samples)


def answered_rows(model: AnswerModel, factor: float, lapse: float, participant: str, trials: list[Trial], *,
                  seed: int, touches: int, timing: Timing = Timing(), session: str = "1") -> list[dict]:
    """The table rows of a participant (noise `factor`, `lapse`) answering `trials` by draws from
    `model`; the exploration measures (time touching, intensity, path) are not simulated (NaN)."""
    rng = np.random.default_rng(seed)
    cells: dict[tuple[str, str, str], np.ndarray] = {}

    def result(trial: Trial) -> dict:
        key = (trial.task, trial.condition, trial.stimulus)
        if key not in cells:
            cells[key] = np.cumsum(model.probabilities(*key, factor, lapse))
        cumulative, options = cells[key], model.options[trial.task]
        response = options[min(int(np.searchsorted(cumulative, rng.random() * cumulative[-1], side="right")),
                               len(options) - 1)]
        rt = answer_time(timing, trial, touches, rng)
        return {"response": None if rt > trial.time_limit_s else response, "rt_s": min(rt, trial.time_limit_s),
                "time_touching_s": math.nan, "mean_intensity": math.nan, "path_length": math.nan}

    return table_rows(trials, participant, result, timing=timing, session=session)


__all__ = ["AnswerModel", "answer_model", "answered_rows", "stimulus_shares", "factor_grid", "SAMPLES"]

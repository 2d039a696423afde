"""The offline simulation of a study: model observers run every trial of their plans without a bus
(the tactile model and the scene directly), writing the same session folders as a real study
(`OUT/<participant>/trials.csv`, `manifest.json`), in a fraction of a second per participant.

Each simulated participant shares the trained cues of one `ModelObserver` (the population's
perceptual learning) and has its own sensory noise: the run's `noise` times exp(N(0, spread)), drawn
from (seed, participant), so the analysis sees participants that differ as real ones do. Time is the
simulation's own clock: an answer takes `look_s` to see and `dwell_s` per touch, times a
log-normal factor; a trial starts `iti_s` after the previous answer.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from touch4d.tactile import Glove

from .design import Study
from .gate import allowed
from .observer import ModelObserver, patterns_at
from .plan import Trial, condition_order, participant_hash, plan_session, quick_plan
from .psychophysics import HUMAN_NOISE
from .stimuli import trial_scene
from .table import TRIALS, trial_row, write_rows

MANIFEST = "manifest.json"


@dataclass(frozen=True)
class Timing:
    """The simulated clock: seconds to look, per touch, between trials, and the spread of answer times."""

    look_s: float = 1.2
    dwell_s: float = 0.6
    decide_s: float = 0.5
    rt_spread: float = 0.25          # sd of the log of the answer-time factor
    break_s: float = 30.0            # a pause offered (break_every) is taken, this long
    iti_s: float = 1.0


def participant_observer(observer: ModelObserver, study: Study, participant: str, seed: int,
                         spread: float) -> ModelObserver:
    """`observer`'s trained cues with this participant's own sensory noise (see the module docstring)."""
    rng = np.random.default_rng([int(seed), participant_hash(participant), int(study.seed)])
    return observer.with_noise(float(np.exp(rng.normal(0.0, spread))) if spread > 0 else 1.0)


def answer_time(timing: Timing, trial: Trial, touches: int, rng: np.random.Generator) -> float:
    """Seconds from a trial's onset to the simulated answer: `look_s` when the condition draws the
    objects, `dwell_s` per touch when the motors run, and `decide_s`, times a log-normal factor (one
    draw from `rng`). The offline simulation and the observer on the bus (nodes/study_observer.py)
    both take their time from here."""
    gate = allowed(trial.condition)
    rt = (timing.look_s if gate.objects else 0.0) + (timing.dwell_s * touches if gate.motors else 0.0) + timing.decide_s
    return rt * float(np.exp(rng.normal(0.0, timing.rt_spread)))


def simulate_trial(observer: ModelObserver, glove: Glove, study: Study, trial: Trial, *, seed: int,
                   timing: Timing) -> dict:
    """One trial: the hand explores, the observer answers from what the condition lets through.
    Returns the response (None: timed out), answer time and the exploration measures."""
    rng = np.random.default_rng([int(trial.seed), int(seed)])
    scene = trial_scene(study, trial)
    gate = allowed(trial.condition)                # visual: motors held off; touch: nothing drawn
    touch, view = gate.motors, gate.objects
    positions = observer.explore(trial, rng)
    patterns = patterns_at(glove, scene, positions) if touch else None
    response = observer.respond(trial, patterns, scene if view else None, rng)
    rt = answer_time(timing, trial, len(positions), rng)
    timed_out = rt > trial.time_limit_s
    felt = patterns if patterns is not None else np.zeros((len(positions), len(glove.motor_names)))
    touching = (felt > glove.touch_threshold).any(axis=1)   # felt: above the glove's touch threshold
    return {
        "response": None if timed_out else response,
        "rt_s": min(rt, trial.time_limit_s),
        "time_touching_s": float(timing.dwell_s * touching.sum()) if touch else 0.0,
        "mean_intensity": float(felt.mean()) if touch else 0.0,
        "path_length": float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()),
    }


def session_rows(own: ModelObserver, glove: Glove, study: Study, participant: str, trials: list[Trial], *,
                 seed: int = 0, timing: Timing = Timing(), session: str = "1") -> list[dict]:
    """The table rows (`table.trial_row`) of a participant's trials answered by the observer `own`."""
    return table_rows(trials, participant, lambda trial: simulate_trial(own, glove, study, trial, seed=seed,
                                                                        timing=timing), timing=timing, session=session)


def table_rows(trials: list[Trial], participant: str, result_of, *, timing: Timing = Timing(),
               session: str = "1") -> list[dict]:
    """The table rows of `trials` on the simulated clock, `result_of(trial)` giving each one's answer
    and measures (as `simulate_trial` returns them)."""
    rows, clock = [], 0.0
    for trial in trials:
        if trial.break_before:
            clock += timing.break_s
        result = result_of(trial)
        rows.append(trial_row(trial, participant=participant, session=session, response=result["response"],
                              onset=clock, response_stamp=None if result["response"] is None else clock + result["rt_s"],
                              time_touching_s=result["time_touching_s"], mean_intensity=result["mean_intensity"],
                              path_length=result["path_length"]))
        clock += result["rt_s"] + timing.iti_s
    return rows


def simulate_session(observer: ModelObserver, glove: Glove, study: Study, participant: str, out, *,
                     seed: int = 0, quick: bool = False, timing: Timing = Timing(), spread: float = 0.25,
                     session: str = "1", settings: dict | None = None) -> Path:
    """A participant's whole session, simulated; writes OUT/<participant>/trials.csv and manifest.json
    (with the run's `settings` as its `simulation`) and returns the session folder."""
    own = participant_observer(observer, study, participant, seed, spread)
    trials = quick_plan(study, participant) if quick else plan_session(study, participant)
    rows = session_rows(own, glove, study, participant, trials, seed=seed, timing=timing, session=session)
    folder = Path(out) / participant
    write_rows(folder / TRIALS, rows)
    manifest = {
        "software": "touch4d", "version": _version(), "mode": "offline simulation", "study": study.name,
        "study_file": study.path, "study_sha256": _sha256(study.path), "participant": participant,
        "session": session, "study_seed": int(study.seed), "seed": int(seed),
        "condition_order": condition_order(study, participant), "trials": len(trials), "quick": quick,
        "simulation": settings,
        "glove_file": glove.path, "glove_sha256": _sha256(glove.path), "motors": len(glove.motor_names),
        "observer": {"noise": own.noise, "visual_noise": own.visual_noise, "lapse": own.lapse,
                     "touches": own.exploration.touches, "spread": spread},
        "starts": [{"time": time.time(), "iso": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "resumed_at": 0}],
    }
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return folder


def simulate_study(study: Study, participants: list[str], out, *, glove: Glove, seed: int = 0, quick: bool = False,
                   noise: float = HUMAN_NOISE, visual_noise: float = 0.5, lapse: float = 0.03, spread: float = 0.25,
                   timing: Timing = Timing(), observer: ModelObserver | None = None, settings: dict | None = None,
                   echo=None) -> list[Path]:
    """Simulated participants, one session folder each under `out`; one observer trained for them all."""
    if observer is None:
        observer = ModelObserver(glove, study, noise=noise, visual_noise=visual_noise, lapse=lapse, seed=seed)
    folders = []
    for participant in participants:
        folder = simulate_session(observer, glove, study, participant, out, seed=seed, quick=quick, timing=timing,
                                  spread=spread, settings=settings)
        if echo:
            echo(f"{participant}: {folder / TRIALS}")
        folders.append(folder)
    return folders


def _sha256(path) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("touch4d")
    except PackageNotFoundError:
        return "unknown"


__all__ = ["Timing", "answer_time", "simulate_trial", "session_rows", "table_rows", "simulate_session", "simulate_study",
           "participant_observer"]

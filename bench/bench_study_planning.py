"""Benchmark: planning a study before recruiting, on Dask.

1. Simulated participants per second (whole sessions of the study, the model observer's pipeline on
   every trial) on 1 and on N local worker processes (`--workers`, default 2), measured in the same
   run: the speed-up and its ratio to linear.
2. Power: the observer's answer shares measured once (`touch4d.study.answers`), then seconds per
   simulated-and-analysed study at each of 5 sizes, answers drawn from the shares, against the same
   studies with the observer's pipeline on every trial (`--exact`, the slow path) measured in this
   run (`--power-simulations` each); and, with `--curve S`, the measured time of a whole S-simulation
   power curve at those 5 sizes on N workers (`touch4d study power`'s defaults: S = 500).
3. `--check-exact S`: the GEE power of S studies of 4 and 8 participants answered by the shares
   beside the same studies run through the observer's pipeline on every trial (Wilson intervals).
4. Power against a known answer: a difference of two binomial proportions, `--validation`
   simulated studies analysed by the GEE of `study analyze`, beside statsmodels' power.
5. Pilot fits: coverage of the 95% profile intervals over 100 pilots drawn from a known accuracy
   surface (closed form), per parameter.
6. Glove design (`--design`, or `--design-only`): bits per touch (mean over the study's tasks, scored
   on test examples neither the search nor its validation saw) of designed layouts of K = 1, 2, 6,
   10, 30 motors beside 10 random layouts of K (ratio designed / random mean) and the paper's 30
   (ratio designed / paper's), and which start the K = 30 design kept.

    .venv/bin/python bench/bench_study_planning.py [--workers 2] [--participants 8]
        [--power-simulations 2] [--curve 500] [--check-exact 60] [--validation 500] [--design]
    .venv/bin/python bench/bench_study_planning.py --design-only [--workers 2] [--seed 0]
    .venv/bin/python bench/bench_study_planning.py --speed-only [--workers 2] [--participants 8]
"""
from __future__ import annotations

import argparse
import math
from dataclasses import replace
import time
import warnings

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.study.design import load_study
from touch4d.study.fanout import Cluster, dask_client, fan_out, seed_of
from touch4d.study.observer import ModelObserver
from touch4d.study.plan import plan_session
from touch4d.study.answers import answer_model
from touch4d.study.power import Population, PowerSetup, power_curves, simulate_outcome, study_outcome, summarise
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.study.simulate import session_rows
from touch4d.tactile import load_glove


def _participant(setup: PowerSetup, participant: str, simulation: int) -> dict:
    """One whole simulated session: its accuracy (what a worker returns)."""
    seed = seed_of(setup.study, "bench", participant, simulation)
    own = setup.population.participant(setup.observer, np.random.default_rng(seed))
    rows = session_rows(own, setup.glove, setup.study, participant, plan_session(setup.study, participant), seed=seed)
    return {"accuracy": float(np.mean([r["correct"] for r in rows])), "trials": len(rows)}


def participants_per_second(setup, count: int, workers: int) -> tuple[float, float]:
    """Simulated participants per second on `workers` local worker processes once they run (each has
    imported, received the trained observer and simulated a participant), and the seconds it took to
    get there (the cluster's start, paid once per command)."""
    jobs = {f"p{i}": (f"P{i + 1:02d}", i) for i in range(count)}
    started = time.perf_counter()
    with dask_client(Cluster(workers=workers)) as client:
        warm = {f"warm{k}": ("P01", 10_000 + k) for k in range(2 * workers)}
        fan_out(_participant, warm, shared=setup, client=client, cluster=Cluster(workers=workers), progress=False)
        ready = time.perf_counter() - started
        started = time.perf_counter()
        fan_out(_participant, jobs, shared=setup, client=client, cluster=Cluster(workers=workers), progress=False)
        return count / (time.perf_counter() - started), ready


def power_timing(setup, sizes, simulations: int) -> dict:
    """Seconds per simulated-and-analysed study at each size (the mean of `simulations`)."""
    seconds = {}
    for n in sizes:
        started = time.perf_counter()
        for s in range(simulations):
            simulate_outcome(setup, n, s)
        seconds[n] = (time.perf_counter() - started) / simulations
    return seconds


def check_exact(setup, exact, simulations: int, workers: int) -> None:
    """GEE power at N = 4 and 8: answers drawn from the shares against the pipeline on every trial."""
    for name, each in (("answer shares", setup), ("every trial (exact)", exact)):
        started = time.perf_counter()
        curves = power_curves(each, [4, 8], simulations, cluster=Cluster(workers=workers), progress=False)["curves"]
        cells = [f"{task} {effect}: " + ", ".join(f"N={n} {p['power']:.2f} [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}]"
                                                 for n, p in zip(entry["sizes"], entry["gee"]))
                 for task, value in curves.items() for effect, entry in value["effects"].items()]
        print(f"power, {name} ({simulations} studies a size, {time.perf_counter() - started:.0f} s): " + "; ".join(cells))


def validation(simulations: int) -> None:
    import pandas as pd
    from statsmodels.stats.power import NormalIndPower
    from statsmodels.stats.proportion import proportion_effectsize

    participants, trials, p1, p2 = 20, 5, 0.6, 0.75
    outcomes = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in range(simulations):
            rng = np.random.default_rng(s)
            rows = [{"participant": f"P{i}", "task": "t", "kind": "look-alikes", "condition": c, "correct": bool(k)}
                    for i in range(participants) for c, p in (("visual", p1), ("visual+touch", p2))
                    for k in rng.random(trials) < p]
            outcomes.append(study_outcome(pd.DataFrame(rows)))
    effect = summarise({participants: outcomes})["t"]["effects"]["visual+touch"]
    expected = NormalIndPower().power(proportion_effectsize(p2, p1), nobs1=participants * trials, alpha=0.05)
    gee, mixed = effect["gee"][0], effect["mixed"][0]
    print(f"two proportions {p1} vs {p2}, {participants * trials} trials each, {simulations} simulated studies: "
          f"power GEE {gee['power']:.3f} [{gee['ci95'][0]:.3f}, {gee['ci95'][1]:.3f}], mixed model "
          f"{mixed['power']:.3f}; statsmodels NormalIndPower {expected:.3f}; ratio GEE / statsmodels "
          f"{gee['power'] / expected:.3f}")


def coverage() -> None:
    from touch4d.study.pilotfit import Surface, dense_accuracy, fit_participant

    log_touch, log_visual = np.linspace(math.log(0.02), math.log(5.0), 7), np.linspace(math.log(0.1), math.log(8.0), 7)
    touch, visual = np.meshgrid(np.exp(log_touch), np.exp(log_visual), indexing="ij")

    def accuracy(d):
        return 1 / 3 + 2 / 3 * (1 - np.exp(-d))

    values = {"t|touch": accuracy(0.5 / np.exp(log_touch)), "t|visual": accuracy(2.0 / np.exp(log_visual)),
              "t|visual+touch": accuracy(0.5 / touch + 2.0 / visual)}
    surface = Surface("synthetic", log_touch, log_visual, values, {c: 3 for c in values})
    dense = dense_accuracy(surface)
    truth = {"noise": 0.5, "visual_noise": 2.0, "lapse": 0.05}
    rng = np.random.default_rng(0)
    covered = dict.fromkeys(truth, 0)
    started = time.perf_counter()
    for _ in range(100):
        counts = {c: (int(rng.binomial(60, truth["lapse"] / 3 + (1 - truth["lapse"]) * surface.accuracy(
            c, math.log(truth["noise"]), math.log(truth["visual_noise"])))), 60) for c in values}
        fit = fit_participant(surface, counts, dense)
        for name, value in truth.items():
            covered[name] += fit[name]["ci95"][0] <= value <= fit[name]["ci95"][1]
    print(f"pilot fits: 95% intervals cover the truth in {covered} of 100 pilots "
          f"({(time.perf_counter() - started) * 10:.1f} ms a fit)")


def design(study, glove, workers: int, *, seed: int = 0, random_layouts: int = 10) -> None:
    from touch4d.study.glovedesign import DesignOptions, design_gloves

    started = time.perf_counter()
    result = design_gloves(glove, study, [1, 2, 6, 10, 30], options=DesignOptions(noise=HUMAN_NOISE,
                           random_layouts=random_layouts, seed=seed), cluster=Cluster(workers=workers), progress=False)
    own = result["own"]["mean_bits"]
    print(f"glove design ({time.perf_counter() - started:.0f} s, {workers} workers, seed {seed}): bits per touch on "
          f"test examples, mean over {', '.join(result['tasks'])}; the paper's 30 motors: {own:.3f}")
    print(f"{'K':>3} {'designed':>9} {'random mean':>11} {'random sd':>9} {'random best':>11} "
          f"{'designed / random':>17} {'designed / paper 30':>19}  start kept (test bits of each start)")
    for k, size in result["sizes"].items():
        designed = size["designed"]["mean_bits"]
        starts = ", ".join(f"{name} {d['mean_bits']:.3f}" for name, d in size["starts"].items())
        print(f"{k:>3} {designed:>9.3f} {size['random_mean_bits']:>11.3f} {size['random_sd_bits']:>9.3f} "
              f"{size['random_best_bits']:>11.3f} {designed / size['random_mean_bits']:>17.3f} {designed / own:>19.3f}"
              f"  {size['designed']['start']} ({starts})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="config/studies/paper.yaml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--participants", type=int, default=8, help="simulated participants per speed run")
    parser.add_argument("--power-simulations", type=int, default=2, help="simulations per size timed")
    parser.add_argument("--samples", type=int, default=1000, help="trials a stimulus behind the answer shares")
    parser.add_argument("--curve", type=int, default=0, metavar="S", help="also time a whole S-simulation curve")
    parser.add_argument("--check-exact", type=int, default=0, metavar="S", help="power of S studies both ways")
    parser.add_argument("--validation", type=int, default=500, help="simulated two-proportion studies")
    parser.add_argument("--design", action="store_true", help="also the glove designs (slow)")
    parser.add_argument("--design-only", action="store_true", help="only the glove designs")
    parser.add_argument("--speed-only", action="store_true", help="only simulated participants per second (1.)")
    parser.add_argument("--seed", type=int, default=0, help="the glove designs' seed")
    args = parser.parse_args(argv)
    study, glove = load_study(args.study), load_glove()
    if args.design_only:
        design(study, glove, args.workers, seed=args.seed)
        return 0
    population = Population()
    observer = ModelObserver(glove, study, noise=population.noise, visual_noise=population.visual_noise,
                             lapse=population.lapse).train()
    exact = PowerSetup(observer, glove, study, population, bootstrap=100, exact=True)

    one, ready_one = participants_per_second(exact, args.participants, 1)
    many, ready_many = participants_per_second(exact, args.participants, args.workers)
    print(f"simulated participants (whole {study.name} sessions, {args.participants} a run) per second: 1 worker "
          f"{one:.2f}, {args.workers} workers {many:.2f}; speed-up {many / one:.2f} ({many / one / args.workers:.0%} "
          f"of linear); the cluster up and warm in {ready_one:.1f} s and {ready_many:.1f} s, once per command")
    if args.speed_only:
        return 0

    started = time.perf_counter()
    answers = answer_model(observer, study, spread=population.spread, samples=args.samples,
                           cluster=Cluster(workers=args.workers), progress=False)
    shares_s = time.perf_counter() - started
    setup = PowerSetup(observer, glove, study, population, bootstrap=100, samples=args.samples, answers=answers)
    sizes = [4, 8, 12, 16, 24]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fast = power_timing(setup, sizes, args.power_simulations)
        slow = power_timing(exact, sizes, args.power_simulations)
    per_curve, per_curve_exact = 500 * sum(fast.values()), 500 * sum(slow.values())
    print(f"power: the answer shares ({answers.samples} trials a stimulus) in {shares_s:.0f} s on {args.workers} "
          f"workers; seconds per simulated and analysed study (bootstrap 100), answers drawn / every trial: "
          + ", ".join(f"N={n} {fast[n]:.2f} / {slow[n]:.1f}" for n in sizes)
          + f"; ratio {sum(slow.values()) / sum(fast.values()):.1f}x")
    print(f"500-simulation curve at N = {sizes}, estimated from {args.power_simulations} simulations a size: "
          f"{per_curve / 60:.0f} min on 1 worker ({per_curve_exact / 3600:.1f} h with every trial simulated)")
    if args.curve:
        started = time.perf_counter()
        power_curves(setup, sizes, args.curve, cluster=Cluster(workers=args.workers), progress=False)
        took = time.perf_counter() - started
        print(f"measured: a {args.curve}-simulation curve at N = {sizes} on {args.workers} workers in {took / 60:.1f} "
              f"min; the estimate above for it on 1 worker: {per_curve * args.curve / 500 / 60:.1f} min "
              f"(ratio {per_curve * args.curve / 500 / took:.2f})")
    if args.check_exact:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_exact(replace(setup, bootstrap=0), replace(exact, bootstrap=0), args.check_exact, args.workers)

    validation(args.validation)
    coverage()
    if args.design:
        design(study, glove, args.workers, seed=args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

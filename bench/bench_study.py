"""Benchmark: how well the paper's stimuli can be told apart by touch, per glove, and how fast a study
is simulated.

1. Information transfer (bits; maximum-likelihood estimate from the confusion matrix, Tan et al.
   1999) per task of config/studies/paper.yaml, by an LDA observer trained on noisy motor patterns at
   random hand positions and tested on new jittered scenes and positions: the default glove (30
   motors) beside the same glove with a motor at every one of its 247 samples (paper §7: actuator
   resolution). Ratio = every-sample bits / default bits. Then the tilt task's bits at four noise levels.
2. The offline simulation's speed (trials per CPU second: scene, exploration, the observer's answer)
   beside the bare tactile model on the same trials (scene and motor patterns only), measured in the
   same run.

    .venv/bin/python bench/bench_study.py [--noise N] [--scenes 20] [--positions 16] [--participants 3]
"""
from __future__ import annotations

import argparse
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

from touch4d.study.design import load_study
from touch4d.study.infotransfer import predicted_transfer
from touch4d.study.observer import ModelObserver, every_sample_glove, patterns_at
from touch4d.study.plan import participant_ids, quick_plan
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.study.simulate import Timing, simulate_trial
from touch4d.study.stimuli import trial_scene
from touch4d.tactile import load_glove


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", default="config/studies/paper.yaml")
    parser.add_argument("--noise", type=float, default=HUMAN_NOISE,
                        help="sensory noise of a finger's motors (full drive = 1; the palm's: x0.64); default: the "
                             "observers' one default")
    parser.add_argument("--scenes", type=int, default=20, help="jittered scenes per stimulus (half to test)")
    parser.add_argument("--positions", type=int, default=16, help="hand positions per scene")
    parser.add_argument("--participants", type=int, default=3, help="simulated participants (quick plans)")
    args = parser.parse_args(argv)
    study = load_study(args.study)
    glove = load_glove()
    dense = every_sample_glove(glove)

    print(f"information transfer per touch (one motor pattern), noise {args.noise:.3g} per finger motor (x0.64 on "
          f"the palm), {args.scenes} jittered scenes x {args.positions} hand positions per stimulus, half of the scenes held out")
    print(f"{'task':<12} {'stimuli':>7} {'max bits':>8} {'30 motors':>10} {'247 motors':>11} {'ratio':>6}   "
          f"accuracy 30 / 247")
    for task in study.tasks:
        few = predicted_transfer(glove, study, task.id, noise=args.noise, scenes=args.scenes, positions=args.positions)
        many = predicted_transfer(dense, study, task.id, noise=args.noise, scenes=args.scenes,
                                  positions=args.positions)
        ratio = many["bits"] / few["bits"] if few["bits"] > 0 else float("inf")
        print(f"{task.id:<12} {len(few['stimuli']):>7} {few['max_bits']:>8.2f} {few['bits']:>10.3f} "
              f"{many['bits']:>11.3f} {ratio:>5.2f}x   {few['accuracy']:.2f} / {many['accuracy']:.2f}")

    tilt = next((t.id for t in study.tasks if t.kind == "tilt"), None)
    if tilt is not None:
        cells = []
        for noise in (0.02, 0.05, 0.08, 0.15, round(HUMAN_NOISE, 3)):
            few, many = (predicted_transfer(g, study, tilt, noise=noise, scenes=args.scenes, positions=args.positions)
                         for g in (glove, dense))
            cells.append(f"{noise:g}: {few['bits']:.2f} / {many['bits']:.2f}")
        print(f"{tilt}, bits by noise per finger motor (30 / 247 motors): " + "; ".join(cells))

    observer = ModelObserver(glove, study, seed=1)
    cpu = time.process_time()
    observer.train()
    train_s = time.process_time() - cpu
    trials = [t for p in participant_ids(args.participants) for t in quick_plan(study, p)]
    timing = Timing()

    def simulated():
        for t in trials:
            simulate_trial(observer, glove, study, t, seed=0, timing=timing)

    def bare():
        rng = np.random.default_rng(0)
        for t in trials:
            scene = trial_scene(study, t)
            if t.condition != "visual":
                patterns_at(glove, scene, observer.exploration.positions(rng))

    best = {}
    for name, fn in (("simulation", simulated), ("bare tactile model", bare)):
        runs = []
        for _ in range(3):
            cpu = time.process_time()
            fn()
            runs.append(time.process_time() - cpu)
        best[name] = len(trials) / min(runs)
    print(f"offline simulation: {best['simulation']:.0f} trials per CPU second ({len(trials)} trials, "
          f"{args.participants} participants' quick plans, best of 3; the observer's training: {train_s:.1f} s CPU once)")
    print(f"baseline, the bare tactile model on the same trials (scenes and patterns, no observer): "
          f"{best['bare tactile model']:.0f} trials/s; simulation / baseline = "
          f"{best['simulation'] / best['bare tactile model']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Information transfer (Tan et al. 1999): how many bits a stimulus set carries to an observer, the
maximum-likelihood estimate from a confusion matrix, and its prediction for a glove before anyone is
recruited: an observer trained on the glove's motor patterns over random hand positions identifies
each task's stimuli from one pattern at new random positions.

The estimate is the mutual information of the stimulus-response table (counts n_ij, total n):
IT = sum_ij n_ij/n log2(n_ij n / (n_i. n_.j)): log2(N) bits for a perfect N x N identification, 0 for
answers that do not depend on the stimulus. From few trials it is biased upwards: answers that do not
depend on the stimulus at all give about (r-1)(c-1) / (2 n ln 2) bits for an r x c table of n trials
(Miller 1955), and 3 trials of 3 stimuli answered in 3 different ways give the maximum, log2(3), right
or wrong. `transfer_beyond_chance` says how much of an estimate chance alone would give.
"""
from __future__ import annotations

import math

import numpy as np

from touch4d.errors import Unavailable
from touch4d.tactile import Glove

from .design import Study
from .observer import Exploration, classifier, touch_examples
from .plan import stimuli_of
from .psychophysics import HUMAN_NOISE, motor_noise


def information_transfer(confusion) -> float:
    """Bits transferred: the maximum-likelihood estimate from a stimulus x response count table."""
    try:
        from sklearn.metrics import mutual_info_score
    except ImportError:
        raise Unavailable("information transfer needs scikit-learn: pip install 'touch4d[study]'") from None
    table = np.asarray(confusion, dtype=float)
    if table.sum() <= 0:
        return 0.0
    return max(0.0, float(mutual_info_score(None, None, contingency=table)) / math.log(2.0))


def transfer_beyond_chance(confusion, *, shuffles: int = 2000, seed: int = 0) -> dict:
    """The information transfer of a count table beside what chance gives with the same trials: the
    answers shuffled against the stimuli (both margins kept; every pairing when there are few trials)
    by scipy's permutation test. `chance_bits` is the mean bits of the shuffles (the estimate's bias
    when the answers carry nothing), `bits_beyond_chance` the estimate less that bias (at least 0),
    `p` the share of shuffles that transfer as much.

    A shuffle correction rather than Miller-Madow's (which counts only the cells seen, and so
    under-corrects the sparse tables of a small study) or a bootstrap interval (which resamples the
    same few trials and is centred on the biased figure)."""
    from scipy.stats import permutation_test

    table = np.asarray(confusion, dtype=int)
    bits = information_transfer(table)
    if table.sum() < 2 or min(table.shape) < 2:
        return {"bits": bits, "chance_bits": bits, "bits_beyond_chance": 0.0, "p": 1.0, "shuffles": 0}
    stimulus, answer = np.nonzero(table)
    counts = table[stimulus, answer]
    stimulus, answer = np.repeat(stimulus, counts), np.repeat(answer, counts)

    def statistic(s, a, axis=-1):
        return _bits(np.moveaxis(s, axis, -1), np.moveaxis(a, axis, -1), table.shape)

    test = permutation_test((stimulus, answer), statistic, permutation_type="pairings", vectorized=True,
                            n_resamples=shuffles, alternative="greater", rng=np.random.default_rng(seed))
    chance = float(np.mean(test.null_distribution))
    return {"bits": bits, "chance_bits": chance, "bits_beyond_chance": max(0.0, round(bits - chance, 12)),
            "p": float(test.pvalue), "shuffles": int(len(test.null_distribution))}


def _bits(stimulus, answer, shape) -> np.ndarray:
    """The information transfer of each row of paired (stimulus, answer) indices (..., n), in bits."""
    from scipy.special import xlogy

    rows, cols = shape
    n = stimulus.shape[-1]
    batch = stimulus.reshape(-1, n)
    cell = batch * cols + answer.reshape(-1, n) + (np.arange(len(batch)) * rows * cols)[:, None]
    counts = np.bincount(cell.ravel(), minlength=len(batch) * rows * cols).reshape(len(batch), rows, cols)
    p = counts / n
    expected = p.sum(axis=2, keepdims=True) * p.sum(axis=1, keepdims=True)
    mi = np.sum(xlogy(p, p) - xlogy(p, np.where(expected > 0, expected, 1.0)), axis=(1, 2)) / math.log(2.0)
    return np.maximum(mi, 0.0).reshape(stimulus.shape[:-1])


SCENES = 20           # jittered scenes per stimulus, half held out: `study transfer`'s default
POSITIONS = 16        # hand positions per scene
LEAST_SHARE = 0.1     # a task whose predicted bits are under this share of its maximum: the glove cannot tell it


def predicted_transfer(glove: Glove, study: Study, task_id: str, *, noise: float = HUMAN_NOISE, scenes: int = SCENES,
                       positions: int = POSITIONS, seed: int = 0, exploration: Exploration | None = None) -> dict:
    """What one touch tells about a task's stimuli with this glove: an LDA trained on noisy patterns
    (`noise` the fingertip's; per motor, `psychophysics.motor_noise`) of half the jittered scenes at
    random hand positions, tested on the other half; returns bits, their maximum log2(stimuli),
    accuracy and the confusion matrix."""
    task = study.task(task_id)
    rng = np.random.default_rng([int(seed), len(glove.motor_names)])
    x, k, groups = touch_examples(glove, study, task, rng, scenes=scenes, positions=positions, exploration=exploration)
    x = x + rng.normal(0.0, motor_noise(glove, noise), x.shape)
    test = groups % 2 == 1                     # scenes, not only positions, are new to the observer
    names = [name for name, _, _ in stimuli_of(task)]
    confusion = held_out_confusion(x, k, test, len(names))
    return {"task": task_id, "bits": information_transfer(confusion), "max_bits": math.log2(len(names)),
            "accuracy": float(np.trace(confusion) / confusion.sum()), "stimuli": names,
            "confusion": confusion.tolist(), "motors": len(glove.motor_names), "noise": noise,
            "test_patterns": int(test.sum())}


def glove_task_warnings(glove: Glove, study: Study, *, noise: float = HUMAN_NOISE, least: float = LEAST_SHARE,
                        scenes: int = SCENES, positions: int = POSITIONS, seed: int = 0) -> list[str]:
    """One line per task whose predicted bits with `glove` (`predicted_transfer`, what `study transfer
    --glove` prints) are under `least` of its maximum: its conditions with touch would measure the
    glove, not the participant. `study check --glove` prints them; a study server can call it before
    serving a study with a glove. Nothing to say for a study without a condition that runs the motors."""
    from .gate import allowed

    touched = [c for c in study.conditions if allowed(c).motors]
    if not touched:
        return []
    out = []
    for task in study.tasks:
        r = predicted_transfer(glove, study, task.id, noise=noise, scenes=scenes, positions=positions, seed=seed)
        if r["bits"] < least * r["max_bits"]:
            out.append(f"task {task.id}: one touch with {glove.path} ({r['motors']} motor{'s' if r['motors'] != 1 else ''}) tells {r['bits']:.2f} "
                       f"of {r['max_bits']:.2f} bits (accuracy {r['accuracy']:.2f} from touch alone, chance "
                       f"{1 / len(r['stimuli']):.2f}): its {', '.join(touched)} trials would measure the glove, "
                       "not the participant")
    return out


def held_out_confusion(x: np.ndarray, k: np.ndarray, test: np.ndarray, stimuli: int) -> np.ndarray:
    """The stimulus x answer counts of the observer's classifier trained on the rows of `x` not in
    `test` and tested on those in it (k: each row's stimulus index)."""
    guess = classifier().fit(x[~test], k[~test]).predict(x[test])
    confusion = np.zeros((stimuli, stimuli), dtype=int)
    np.add.at(confusion, (k[test], guess), 1)
    return confusion

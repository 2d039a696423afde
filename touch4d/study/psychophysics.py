"""The model observer's touch noise set from human data (sources in docs/planning.md).

The observer feels each motor's intensity (units of full drive) plus Gaussian noise of sd `noise`
(`ModelObserver.respond`). In a two-interval amplitude discrimination of a reference drive A and a
comparison A + d on one motor, an observer who answers the interval felt stronger is right with
probability Phi(d / (noise sqrt 2)): 75% correct at d = noise sqrt(2) Phi^-1(0.75), a Weber fraction
of that over A. `HUMAN_NOISE` is the noise whose Weber fraction at `REFERENCE_DRIVE` is the
fingertip's published one; `amplitude_discrimination` measures it by simulation (a psychometric fit,
`analysis.fit_psychometric`), the check that the observer lands inside the published range.
"""
from __future__ import annotations

import math
from statistics import NormalDist

# Published vibrotactile amplitude discrimination (see docs/planning.md for the sources).
FINGERTIP_WEBER_DB = (2.2, 2.5)       # dB: 20 log10(1 + Weber fraction)
THENAR_WEBER = 0.2                   # the thenar eminence at 125 Hz
REFERENCE_DRIVE = 0.5                # the drive (units of full drive) at which the fraction is matched


def weber_from_db(db: float) -> float:
    """A Weber fraction from its level in dB (20 log10(1 + fraction))."""
    return 10.0 ** (db / 20.0) - 1.0


def db_from_weber(fraction: float) -> float:
    return 20.0 * math.log10(1.0 + fraction)


def noise_for_weber(fraction: float, reference: float = REFERENCE_DRIVE) -> float:
    """The per-motor noise whose 75%-correct amplitude step at `reference` is `fraction` x reference."""
    return fraction * reference / (math.sqrt(2.0) * NormalDist().inv_cdf(0.75))


# The one default touch noise of every observer (simulate, power, fit, transfer, glove design, the node).
HUMAN_NOISE = noise_for_weber(weber_from_db(sum(FINGERTIP_WEBER_DB) / 2.0))   # ~0.16 of full drive


def amplitude_discrimination(noise: float, *, reference: float = REFERENCE_DRIVE, steps=None, trials: int = 400,
                             seed: int = 0) -> dict:
    """Two-interval amplitude discrimination through the observer's touch noise: comparisons at
    reference + step (steps signed, as fractions of the reference), `trials` each; the psychometric
    fit of P(comparison felt stronger) gives the 75% step, the Weber fraction and its level in dB."""
    import numpy as np

    from .analysis import fit_psychometric

    steps = np.asarray(steps if steps is not None else [-0.8, -0.5, -0.3, -0.15, 0.15, 0.3, 0.5, 0.8])
    rng = np.random.default_rng(seed)
    level = np.repeat(steps, trials)
    felt_reference = reference + rng.normal(0.0, noise, level.shape)
    felt_comparison = reference * (1.0 + level) + rng.normal(0.0, noise, level.shape)
    fit = fit_psychometric(level, (felt_comparison > felt_reference).astype(float))
    fraction = fit["threshold_deg"]      # the fit's 75% point, here in units of the reference
    return {"noise": noise, "reference": reference, "weber_fraction": fraction, "weber_db": db_from_weber(fraction),
            "trials": int(len(level))}


__all__ = ["HUMAN_NOISE", "FINGERTIP_WEBER_DB", "THENAR_WEBER", "REFERENCE_DRIVE", "noise_for_weber",
           "weber_from_db", "db_from_weber", "amplitude_discrimination"]

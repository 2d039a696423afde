"""The model observer's touch noise set from human data (sources in docs/planning.md).

The observer feels each motor's intensity (units of full drive) plus Gaussian noise of the sd of
the skin the motor sits on (`motor_noise`; `ModelObserver.feel`, in training and on each trial). In
a two-interval amplitude discrimination of a reference drive A and a comparison A + d on one motor,
an observer who answers the interval felt stronger is right with probability Phi(d / (noise sqrt 2)):
75% correct at d = noise sqrt(2) Phi^-1(0.75), a Weber fraction of that over A. `HUMAN_NOISE` is
the noise whose Weber fraction at `REFERENCE_DRIVE` is the fingertip's published one;
`amplitude_discrimination` measures it by simulation (a psychometric fit, `psychometric.fit_psychometric`),
the check that the observer lands inside the published range.

Where a vibration is felt: at its motor's place on the skin plus Gaussian noise of sd
`LOCALISATION_MM` on each axis of the palm's plane (the hand frame's x and y), so the mean distance
between where a motor is and where it is felt is LOCALISATION_MM sqrt(pi/2) (a Rayleigh mean), set
to the middle of the palm's published 5-15 mm; `vibration_localisation` runs that task.

Per motor: a participant has one free parameter, `noise`, the fingertip's sd. A motor on the palm's
side of the palm (the thenar eminence's skin) is felt with noise x `THENAR_RATIO` (its published
Weber fraction over the fingertip's); one on a finger with `noise`; any other (the back of the hand, a
held controller that vibrates the whole hand around its grip) with `noise` too: no published figure
says it is finer, and the coarser keeps the predictions from flattering the glove.
"""
from __future__ import annotations

import math
from statistics import NormalDist

# Published vibrotactile amplitude discrimination (see docs/planning.md for the sources).
FINGERTIP_WEBER_DB = (2.2, 2.5)       # dB: 20 log10(1 + Weber fraction)
THENAR_WEBER = 0.2                   # the thenar eminence at 125 Hz
REFERENCE_DRIVE = 0.5                # the drive (units of full drive) at which the fraction is matched
PALM_LOCALISATION_MM = (5.0, 15.0)    # vibration localisation on the palm: mean error, mm


def weber_from_db(db: float) -> float:
    """A Weber fraction from its level in dB (20 log10(1 + fraction))."""
    return 10.0 ** (db / 20.0) - 1.0


def db_from_weber(fraction: float) -> float:
    return 20.0 * math.log10(1.0 + fraction)


def noise_for_weber(fraction: float, reference: float = REFERENCE_DRIVE) -> float:
    """The per-motor noise whose 75%-correct amplitude step at `reference` is `fraction` x reference."""
    return fraction * reference / (math.sqrt(2.0) * NormalDist().inv_cdf(0.75))


# The one default touch noise of every observer, a finger's (simulate, power, fit, transfer, glove design, the node).
HUMAN_NOISE = noise_for_weber(weber_from_db(sum(FINGERTIP_WEBER_DB) / 2.0))   # ~0.16 of full drive
# The thenar eminence's noise (its Weber fraction at 125 Hz): finer than the fingertip's.
THENAR_NOISE = noise_for_weber(THENAR_WEBER)                                    # ~0.105 of full drive
# A palm motor's noise over a finger motor's, for any participant (`motor_noise`): their Weber fractions' ratio.
THENAR_RATIO = THENAR_NOISE / HUMAN_NOISE                                       # ~0.64
# Where a vibration is felt (module docstring): sd per axis whose mean error is the range's middle, 10 mm.
LOCALISATION_MM = sum(PALM_LOCALISATION_MM) / 2.0 / math.sqrt(math.pi / 2.0)   # ~7.98 mm


def motor_noise(glove, noise: float):
    """Each motor's noise sd (M,) for a participant of fingertip noise `noise` (module docstring): the
    palm's side of the palm noise x THENAR_RATIO, every other motor `noise`. A motor that covers
    other samples than its own (a held controller's, `covers`) vibrates the hand around it: `noise`."""
    import numpy as np

    skin = np.ones(len(glove.motor_names))
    own_sample = np.ones(len(skin), bool) if glove.motor_weights is None else (
        np.count_nonzero(glove.motor_weights, axis=1) == 1)
    palm = np.zeros(len(skin), bool)
    palm[glove.hand.regions(glove.motor_positions)["palm"]] = True
    skin[palm & own_sample] = THENAR_RATIO
    return float(noise) * skin


def amplitude_discrimination(noise: float, *, reference: float = REFERENCE_DRIVE, steps=None, trials: int = 400,
                             seed: int = 0) -> dict:
    """Two-interval amplitude discrimination through the observer's touch noise: comparisons at
    reference + step (steps signed, as fractions of the reference), `trials` each; the psychometric
    fit of P(comparison felt stronger) gives the 75% step, the Weber fraction and its level in dB."""
    import numpy as np

    from .psychometric import fit_psychometric

    steps = np.asarray(steps if steps is not None else [-0.8, -0.5, -0.3, -0.15, 0.15, 0.3, 0.5, 0.8])
    rng = np.random.default_rng(seed)
    level = np.repeat(steps, trials)
    felt_reference = reference + rng.normal(0.0, noise, level.shape)
    felt_comparison = reference * (1.0 + level) + rng.normal(0.0, noise, level.shape)
    fit = fit_psychometric(level, (felt_comparison > felt_reference).astype(float))
    fraction = fit["threshold_deg"]      # the fit's 75% point, here in units of the reference
    return {"noise": noise, "reference": reference, "weber_fraction": fraction, "weber_db": db_from_weber(fraction),
            "trials": int(len(level))}


def felt_positions(positions, sd_mm: float, rng):
    """Where vibrations at `positions` (N, 3; hand frame, metres) are felt: each moved by Gaussian noise
    of sd `sd_mm` millimetres along x and y, the palm's plane (module docstring)."""
    import numpy as np

    felt = np.array(positions, dtype=float, ndmin=2)
    felt[:, :2] += rng.normal(0.0, sd_mm / 1000.0, (len(felt), 2))
    return felt


def vibration_localisation(positions, sd_mm: float, *, trials: int = 2000, seed: int = 0) -> dict:
    """The localisation task: one of `positions` (motors, hand frame, metres), drawn at random, vibrates
    and the observer points where it felt it; the distances between the two, in mm."""
    import numpy as np

    rng = np.random.default_rng(seed)
    where = np.asarray(positions, dtype=float)[rng.integers(len(positions), size=trials)]
    error = 1000.0 * np.linalg.norm(felt_positions(where, sd_mm, rng) - where, axis=1)
    return {"sd_mm": sd_mm, "mean_error_mm": float(error.mean()), "median_error_mm": float(np.median(error)),
            "trials": int(trials)}


__all__ = ["HUMAN_NOISE", "THENAR_NOISE", "THENAR_RATIO", "motor_noise", "LOCALISATION_MM", "PALM_LOCALISATION_MM",
           "felt_positions", "vibration_localisation", "FINGERTIP_WEBER_DB", "THENAR_WEBER", "REFERENCE_DRIVE",
           "noise_for_weber", "weber_from_db", "db_from_weber", "amplitude_discrimination"]

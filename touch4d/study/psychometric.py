"""The psychometric function of a tilt task and its maximum-likelihood fit: P(answering the option of
positive tilts) = lapse/2 + (1 - lapse) Phi((level - pse) / sigma). What the analysis fits to a
study's answers and psychophysics to its simulated observer: below both, so each imports it."""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import norm

Z75 = float(norm.ppf(0.75))      # 75% correct lies 0.674 sigma from the pse
PHI0 = float(norm.pdf(0.0))      # the slope of Phi at the pse, per sigma

LAPSE_MAX = 0.2


def psychometric_curve(level, pse: float, sigma: float, lapse: float):
    """P(answering the positive option) at a signed level."""
    from scipy.special import ndtr

    return lapse / 2.0 + (1.0 - lapse) * ndtr((np.asarray(level, dtype=float) - pse) / sigma)


_STARTS = ((0.0, 0.3, 0.02), (0.0, 0.05, 0.02), (0.0, 2.0, 0.1))   # (pse, sigma / sd of the levels, lapse)


def fit_psychometric(level, positive) -> dict:
    """Maximum-likelihood pse, sigma and lapse (0..0.2) of `psychometric_curve` for trials at signed
    `level` answered positive (1) or not (0): the binomial log-likelihood maximised by scipy (L-BFGS-B)
    from three starts, the best kept."""
    fit = fit_psychometric_many(np.asarray(level, dtype=float)[None], np.asarray(positive, dtype=float)[None])
    return {key: float(value[0]) for key, value in fit.items()}


def fit_psychometric_many(level, positive, start=None) -> dict:
    """`fit_psychometric` of B data sets at once (level, positive: (B, n), as a bootstrap's resamples
    are), each from fit_psychometric's starts and `start` (pse, sigma, lapse) if given, the best kept
    per data set. The B likelihoods are independent, so each takes its own Fisher-scoring steps
    (Levenberg-damped, projected on the bounds, halved until the likelihood rises), all B at once in
    numpy: a bootstrap's hundred fits cost about what one scipy fit does."""
    from scipy.special import ndtr, xlogy

    level, positive = np.atleast_2d(np.asarray(level, dtype=float)), np.atleast_2d(np.asarray(positive, dtype=float))
    levels = np.unique(level)
    at = level[..., None] == levels                                   # (B, n, L): trials per level
    n = at.sum(axis=1).astype(float)
    k = (at * positive[..., None]).sum(axis=1)
    spread = np.maximum(np.std(level, axis=1), 1e-3)[:, None]          # sigma's scale: the levels' sd
    b = len(level)
    low = np.stack([level.min(axis=1) - spread[:, 0], np.full(b, math.log(1e-3)), np.zeros(b)], axis=1)
    high = np.stack([level.max(axis=1) + spread[:, 0], np.full(b, math.log(50.0)), np.full(b, LAPSE_MAX)], axis=1)

    def probability(x, rows):
        sigma = spread[rows] * np.exp(x[:, 1:2])
        z = (levels - x[:, 0:1]) / sigma
        phi = ndtr(z)
        return np.clip(x[:, 2:3] / 2.0 + (1.0 - x[:, 2:3]) * phi, 1e-12, 1.0 - 1e-12), sigma, z, phi

    def nll(x, rows):
        p = probability(x, rows)[0]
        return -np.sum(xlogy(k[rows], p) + xlogy(n[rows] - k[rows], 1.0 - p), axis=1)

    def fit_from(x):
        value, damping = nll(x, slice(None)), np.full(b, 1e-3)
        rows = np.arange(b)                                  # the fits not yet at their minimum
        for _ in range(100):
            xr, lo, hi, kr, nr = x[rows], low[rows], high[rows], k[rows], n[rows]
            p, sigma, z, phi = probability(xr, rows)
            density = (1.0 - xr[:, 2:3]) * np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
            dp = np.stack([-density / sigma, -density * z, 0.5 - phi], axis=2)     # (B, L, 3): dp / dtheta
            weight = nr / (p * (1.0 - p))
            grad = np.einsum("bl,blj->bj", weight * (p - kr / np.maximum(nr, 1e-300)), dp)
            info = np.einsum("bl,bli,blj->bij", weight, dp, dp)                      # Fisher information
            fixed = ((xr <= lo + 1e-12) & (grad > 0)) | ((xr >= hi - 1e-12) & (grad < 0))   # held at a bound
            grad = np.where(fixed, 0.0, grad)
            info = np.where(fixed[:, :, None] | fixed[:, None, :], 0.0, info) + np.eye(3) * fixed[:, None, :]
            newton = np.linalg.solve(info + 1e-9 * np.eye(3), grad[..., None])[..., 0]
            going = np.einsum("bj,bj->b", grad, newton) >= 1e-9          # Newton decrement: not yet at the minimum
            if not going.any():
                break
            rows, xr, lo, hi, grad, info = rows[going], xr[going], lo[going], hi[going], grad[going], info[going]
            scale = np.maximum(np.diagonal(info, axis1=1, axis2=2), 1e-9)[:, None, :]
            step = -np.linalg.solve(info + (damping[rows, None, None] + 1e-12) * np.eye(3) * scale,
                                    grad[..., None])[..., 0]
            improved, before = np.zeros(len(rows), bool), value[rows]
            for _ in range(10):                                      # halve each step until nll drops
                candidate = np.clip(xr + step, lo, hi)
                new = nll(candidate, rows)
                better = (new <= value[rows]) & ~improved
                x[rows[better]] = candidate[better]
                value[rows[better]] = new[better]
                improved |= better
                if improved.all():
                    break
                step = np.where(improved[:, None], step, step / 2.0)
            flat = improved & (before - value[rows] < 1e-9)          # a step that gains nothing: at the minimum
            damping[rows] = np.where(improved, damping[rows] / 3.0, damping[rows] * 10.0)
            rows = rows[(improved & ~flat) | (~improved & (damping[rows] < 1e3))]   # else: at its minimum
            if not len(rows):
                break
        return x, value

    starts = [(pse, sigma * spread[:, 0], lapse) for pse, sigma, lapse in _STARTS] + ([start] if start else [])
    best, best_value = None, None
    for pse0, sigma0, lapse0 in starts:
        x0 = np.stack([np.broadcast_to(pse0, b), np.log(np.broadcast_to(sigma0, b) / spread[:, 0]),
                       np.broadcast_to(lapse0, b)], axis=1)
        x, value = fit_from(np.clip(x0, low, high))
        if best is None:
            best, best_value = x, value
        else:
            better = value < best_value
            best[better], best_value[better] = x[better], value[better]
    pse, log_sigma, lapse = best.T
    sigma = spread[:, 0] * np.exp(log_sigma)
    return {"pse_deg": pse, "sigma_deg": sigma, "lapse": lapse, "threshold_deg": sigma * Z75,
            "slope_per_deg": (1.0 - lapse) * PHI0 / sigma}

"""How much a group of residuals weighs: their correlation in time, the variance factor of a random walk.

In: time-ordered residuals (normalised by their σ), and for the bearings their times, markers and which were
used; or the knot values of a random walk with their covariance and the prior σ of its increments. Out: the
variance inflation factor c ≥ 1 (n correlated residuals weigh like n / c independent ones) of one series
(:func:`correlation_factor`, its initial positive sequence of autocorrelations) and of a network's bearings
(:func:`bearings_correlation`: the larger of their pooled series and of each marker's own); Helmert's variance
factor of a walk's increments about their mean (:func:`walk_variance_factor`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["bearings_correlation", "correlation_factor", "walk_variance_factor"]

#: a walk's variance factor is estimated from at least this many increments beyond their mean
MIN_WALK_INCREMENTS = 10


def bearings_correlation(r: np.ndarray, t: np.ndarray, marker: np.ndarray, used: np.ndarray) -> float:
    """The bearings' variance inflation: the larger of the time series of all of them (a common error: the
    VO's walk, the platform) and of each marker's own (its error the same frame after frame: a centre its
    pattern biases, a seam), the markers' n_m / c_m summed to the effective count n / c."""
    order = np.argsort(t, kind="stable")
    order = order[used[order]]
    r, m = r[order], marker[order]
    pooled = correlation_factor(r)
    effective = sum(float(np.sum(m == k)) / correlation_factor(r[m == k]) for k in np.unique(m))
    return max(pooled, len(r) / effective) if effective > 0 else pooled


def correlation_factor(series: np.ndarray, max_lag: int = 200) -> float:
    """Variance inflation 1 + 2 Σ ρ_k (≥ 1) of the mean of a time-ordered series (n, c) of residuals: ρ_k
    its lag-k autocorrelation (the columns pooled), summed while positive (the initial positive sequence),
    up to ``max_lag`` or n/10 lags."""
    x = np.asarray(series, dtype=float)
    n = len(x)
    if n < 20:
        return 1.0
    x = x - x.mean(axis=0)
    var = float(np.sum(x * x))
    if var <= 0.0:
        return 1.0
    total = 0.0
    for k in range(1, min(max_lag, n // 10) + 1):
        rho = float(np.sum(x[k:] * x[:-k])) / var
        if rho <= 0.0:
            break
        total += rho
    return 1.0 + 2.0 * total


def walk_variance_factor(values: np.ndarray, cov: np.ndarray, sigma: float) -> float:
    """Helmert's estimate of the variance factor of a random walk about a free constant rate, its increments
    weighted by 1/``sigma``²: their squares less their mean against their redundancy (their count less the rate
    and what the data tell of them). ``values`` (K,) equally spaced knots of the walk as estimated, ``cov`` (K, K)
    their covariance; NaN when fewer than :data:`MIN_WALK_INCREMENTS` increments beyond the rate tell it."""
    rank = len(values) - 2
    if rank < MIN_WALK_INCREMENTS:
        return float("nan")
    w = 1.0 / sigma ** 2
    inc = np.diff(values)
    c = np.diff(np.diff(cov, axis=0), axis=1)                                 # the increments' covariance
    redundancy = max(rank - w * float(np.trace(c) - c.sum() / len(c)), 1e-3)  # its trace, their mean out
    return float(w * np.sum((inc - inc.mean()) ** 2) / redundancy)

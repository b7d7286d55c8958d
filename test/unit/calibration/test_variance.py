"""Helmert's variance factor of a random walk about a free rate (``calibration.variance.walk_variance_factor``)
against walks of known size: the factor is the walk's variance over the prior's, whatever the rate, and the
knots the data did not tell count for nothing."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.calibration.variance import MIN_WALK_INCREMENTS, walk_variance_factor


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), true_sigma=st.floats(1e-4, 1e-1), prior_sigma=st.floats(1e-4, 1e-1),
       rate=st.floats(-0.1, 0.1))
def test_a_walk_known_exactly_gives_its_variance_over_the_prior(seed, true_sigma, prior_sigma, rate):
    rng = np.random.default_rng(seed)
    k = 2001
    values = np.cumsum(np.concatenate([[0.0], rate + rng.normal(0.0, true_sigma, k - 1)]))
    factor = walk_variance_factor(values, np.zeros((k, k)), prior_sigma)
    # 1998 increments' squares about their mean: within 4 of their relative σ √(2/1998)
    assert abs(factor / (true_sigma / prior_sigma) ** 2 - 1.0) < 4.0 * np.sqrt(2.0 / 1998)


def test_knots_the_data_did_not_tell_add_no_redundancy():
    """Knots the data did not tell sit on the rate, with the prior's covariance: they add neither squares nor
    redundancy, and the factor is the told knots' alone."""
    rng = np.random.default_rng(3)
    sigma, k_told, k_free = 0.02, 400, 300
    told = np.cumsum(rng.normal(0.0, 2.0 * sigma, k_told))
    rate = float(np.mean(np.diff(told)))
    both = np.concatenate([told, told[-1] + rate * np.arange(1, k_free + 1)])
    cov = np.zeros((k_told + k_free, k_told + k_free))
    steps = np.arange(1, k_free + 1)
    cov[k_told:, k_told:] = sigma ** 2 * np.minimum.outer(steps, steps)    # a walk from the last told knot
    assert abs(walk_variance_factor(both, cov, sigma) / walk_variance_factor(told, cov[:k_told, :k_told], sigma)
               - 1.0) < 0.01


def test_too_short_a_walk_is_not_estimated():
    values = np.cumsum(np.full(MIN_WALK_INCREMENTS + 1, 0.5))
    assert np.isnan(walk_variance_factor(values, np.zeros((len(values), len(values))), 0.01))
    longer = np.concatenate([values, [values[-1] + 0.6]])
    assert walk_variance_factor(longer, np.zeros((len(longer), len(longer))), 0.01) > 1.0

"""The point rays meet at and its covariance from their own scatter (``mapping.rays``), against Monte Carlo truth:
rays from random places towards a known point, their directions off by a known angular noise."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.mapping.rays import scatter_covariance, triangulate


def _rays(rng, X, n, baseline, noise):
    """n rays from a track of ``baseline`` m 1-12 m beside the point ``X``, their directions off by ``noise`` rad
    per axis."""
    org = X + np.column_stack([rng.uniform(-0.5, 0.5, n) * baseline, -rng.uniform(1.0, 12.0, n),
                               rng.uniform(-1.0, 1.0, n)])
    d = X - org
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d += noise * rng.normal(size=d.shape)
    return org, d / np.linalg.norm(d, axis=1, keepdims=True)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 31), n=st.integers(30, 200), baseline=st.floats(1.0, 20.0),
       noise_deg=st.floats(0.002, 0.5))
def test_the_scatter_covariance_is_what_the_point_scatters_by(seed, n, baseline, noise_deg):
    """Over 200 bundles, the point's squared error normalised by the covariance its own rays give: χ² of 3
    degrees of freedom (mean 3); noise-free rays give the point itself and no covariance."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-20.0, 20.0, 3)
    org, d = _rays(rng, X, n, baseline, 0.0)
    P, inl = triangulate(org, d, math.radians(5.0), seed=seed)
    assert inl.all() and np.linalg.norm(P - X) < 1e-9
    assert np.all(np.abs(scatter_covariance(P, org, d)) < 1e-18)
    noise = math.radians(noise_deg)
    chi2 = []
    for _ in range(200):
        org, d = _rays(rng, X, n, baseline, noise)
        P, inl = triangulate(org, d, 30.0 * noise, seed=seed)
        assert P is not None and inl.mean() > 0.99
        e = P - X
        chi2.append(float(e @ np.linalg.solve(scatter_covariance(P, org[inl], d[inl]), e)))
    assert 2.4 <= np.mean(chi2) <= 3.8, np.mean(chi2)

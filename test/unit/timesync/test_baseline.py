"""timesync/baseline.py (the paper's cross-correlation) against synthetic signals with a known offset
(signals.py): whole-frame resolution, and worse than the coherence estimate on the nominal track."""

from __future__ import annotations

import numpy as np
import pytest

from aruco_abs_orient.timesync import cross_correlation_offset, estimate_offset

from .signals import FPS, scenario


def test_cross_correlation_baseline_is_limited_to_whole_frames():
    tau = 11.5 / FPS  # the paper's 11 frames, plus half a frame
    data = scenario(tau, seed=2, noise_xy=0.0005)  # a quiet track: the baseline at its best
    base = cross_correlation_offset(*data)
    ours = estimate_offset(*data)
    period = 1.0 / FPS
    assert base.offset / period == pytest.approx(round(base.offset / period), abs=1e-6)
    assert abs(base.offset - tau) >= 0.4 * period  # at best half a frame off
    assert abs(ours.offset - tau) <= 0.005
    assert base.taus.shape == base.curve.shape


def test_baseline_is_worse_on_the_nominal_track():
    errs_ours, errs_base = [], []
    for i, tau in enumerate((-0.65, 0.05, 0.55)):
        data = scenario(tau + 0.5 / FPS, seed=40 + i)
        errs_ours.append(abs(estimate_offset(*data).offset - tau - 0.5 / FPS))
        errs_base.append(abs(cross_correlation_offset(*data).offset - tau - 0.5 / FPS))
    assert max(errs_ours) <= 0.005
    assert np.mean(errs_base) > 3 * np.mean(errs_ours)

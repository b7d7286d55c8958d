"""timesync/coherence.py against synthetic signals with a known offset (signals.py): the offset
within 5 ms over the search range, invariance to the yaw offset, σ and confidence that follow the
noise, marker yaws, the reasons an offset is unobservable, braking in a turn."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.timesync import (
    TimeSyncError,
    TimeSyncParams,
    YawSeries,
    estimate_offset,
    estimate_offset_from_marker_yaws,
)

from .signals import FPS, YAW_OFFSET, A, B, scenario, true_heading


@settings(max_examples=5, deadline=None, derandomize=True)
@given(tau=st.floats(-0.99, 0.99), seed=st.integers(0, 10_000))
def test_offset_within_5ms_over_the_whole_range(tau, seed):
    est = estimate_offset(*scenario(tau, seed=seed))
    assert abs(est.offset - tau) <= 0.005
    assert est.method == "coherence"
    assert 0.0 < est.sigma < 0.01
    assert est.confidence > 0.5
    # the nuisance terms are recovered too: the constant yaw offset and the 3°/min drift
    assert abs(math.degrees(est.drift) * 60.0 - 3.0) < 0.5
    assert abs(np.angle(np.exp(1j * (est.yaw_offset - YAW_OFFSET)))) < math.radians(2.0)


def test_estimate_is_invariant_to_the_yaw_offset():
    t_vo, yaw, tp, xy = scenario(0.3, seed=11)
    a = estimate_offset(t_vo, yaw, tp, xy)
    b = estimate_offset(t_vo, np.angle(np.exp(1j * (yaw - 2.5))), tp, xy)
    assert b.offset == pytest.approx(a.offset, abs=1e-6)
    assert b.coherence == pytest.approx(a.coherence, abs=1e-9)


def test_noisier_track_gives_larger_sigma_and_lower_confidence():
    good = estimate_offset(*scenario(-0.4, seed=5))
    bad = estimate_offset(*scenario(-0.4, seed=5, noise_xy=0.05))
    assert bad.sigma > 3 * good.sigma
    assert bad.confidence < good.confidence
    assert abs(bad.offset + 0.4) < 5 * bad.sigma + 0.005  # honest σ: the error is within a few σ



def test_marker_yaws_alone_and_with_vo():
    tau = -0.27
    t_vo, yaw_vo, tp, xy = scenario(tau, seed=8)
    rng = np.random.default_rng(9)
    # marker yaws at every 3rd frame while a marker is in view (half of the time), absolute
    # (no yaw offset, no drift), a per-marker bias of up to 1°, 0.3° noise
    t_true = t_vo - tau
    seen = (np.sin(0.4 * t_true) > 0) & (np.arange(len(t_true)) % 3 == 0)
    ids = np.where(np.cos(0.1 * t_true) > 0, 3, 7)[seen]
    bias = np.where(ids == 3, math.radians(1.0), math.radians(-0.6))
    yaw_m = true_heading(t_true[seen]) + bias + rng.normal(0.0, math.radians(0.3), int(seen.sum()))
    alone = estimate_offset_from_marker_yaws(YawSeries(t_vo[seen], yaw_m, ids), tp, xy)
    assert alone.sigma < 0.01 and abs(alone.offset - tau) <= 3 * alone.sigma  # half the data: honest σ
    both = estimate_offset_from_marker_yaws(YawSeries(t_vo[seen], yaw_m, ids), tp, xy, YawSeries(t_vo, yaw_vo))
    assert abs(both.offset - tau) <= 0.005
    assert both.n_samples > alone.n_samples
    with pytest.raises(TimeSyncError, match="no markers seen"):
        estimate_offset_from_marker_yaws(YawSeries([], []), tp, xy)


@pytest.mark.parametrize("case, message", [
    ("standstill", "never moves"),
    ("short", "too short"),
    ("no_overlap", "no overlap"),
    ("straight", "does not change enough"),
    ("circle", "does not change enough"),
    ("edge", "edge of the search interval"),
    ("nan", "NaN"),
])
def test_unobservable_offsets_raise_with_the_reason(case, message):
    t_vo, yaw, tp, xy = scenario(0.2, seed=1)
    rng = np.random.default_rng(0)
    search = (-1.0, 1.0)
    if case == "standstill":
        xy = np.full_like(xy, 3.0) + rng.normal(0.0, 0.002, xy.shape)
    elif case == "short":
        t_vo, yaw = t_vo[:150], yaw[:150]
    elif case == "no_overlap":
        t_vo = t_vo + 100.0
    elif case == "straight":
        xy = np.column_stack([0.5 * tp, 0.2 * tp])
        yaw = np.full_like(yaw, math.atan2(0.2, 0.5))
    elif case == "circle":  # constant turn rate: a time offset is a yaw offset
        xy = np.column_stack([2.0 * np.cos(0.2 * tp), 2.0 * np.sin(0.2 * tp)])
        yaw = 0.2 * (t_vo - 0.2) + math.pi / 2
    elif case == "edge":
        search = (-1.0, 0.1)
    elif case == "nan":
        yaw = yaw.copy()
        yaw[10] = np.nan
    with pytest.raises(TimeSyncError, match=message):
        estimate_offset(t_vo, yaw, tp, xy, search=search)



def test_braking_in_a_turn_does_not_bias_the_offset():
    """Slowing down to a stop inside a curve makes the smoothed track heading lag asymmetrically
    (a bias of σ²·v'ψ'/v); the estimator removes it. Noise-free, so only a bias could show."""
    tau = 0.25
    t_true = np.arange(0.0, 40.0, 1.0 / FPS)

    def theta(t):  # ellipse parameter: cruise, then brake from 30 s to a stop at 36 s, near the tip
        t = np.asarray(t, dtype=float)
        brake = np.clip(t - 30.0, 0.0, 6.0)
        return 0.2 * np.minimum(t, 30.0) + 0.2 * (brake - brake**2 / 12.0)

    def pos(t):
        th = theta(t)
        return np.stack([A * np.cos(th), B * np.sin(th)], axis=-1)

    yaw = np.arctan2(B * np.cos(theta(t_true)), -A * np.sin(theta(t_true))) + YAW_OFFSET
    tp = np.arange(-1.0, 41.0, 1.0 / 19.0)
    est = estimate_offset(t_true + tau, yaw, tp, pos(tp))
    assert abs(est.offset - tau) < 0.001


def test_the_params_change_what_is_estimated():
    """TimeSyncParams (cfg/params.yaml's timesync section) reach the estimate: a longer required overlap than
    the recording refuses it; one window for the whole recording still finds the true offset."""
    tau = 0.3
    data = scenario(tau, seed=3)
    default = estimate_offset(*data)
    assert default.overlap < 1000.0
    with pytest.raises(TimeSyncError, match="need at least 1000.0 s"):
        estimate_offset(*data, params=TimeSyncParams(min_duration=1000.0))
    with pytest.raises(TimeSyncError, match="does not change enough"):
        estimate_offset(*data, params=TimeSyncParams(min_turn_rate_deg=1000.0))
    one_window = estimate_offset(*data, params=TimeSyncParams(window=0.0))
    assert abs(one_window.offset - tau) < 3 * max(one_window.sigma, 1.0 / FPS / 10)
    with pytest.raises(TimeSyncError, match=r"TimeSyncParams\.step: expected a positive number"):
        TimeSyncParams(step=0.0)

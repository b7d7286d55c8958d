"""Time-offset estimation against synthetic signals with a known offset (built here, not by the module).

The platform drives an ellipse (4 m × 1.5 m half-axes, varying curvature so the turn rate varies)
at 0.2–0.6 m/s; its true heading is the analytic tangent direction. The VO yaw is that heading
+ a constant offset + a drift of 3°/min + 0.2° noise, at 30 fps, stamped on the camera clock =
true time + τ. The prism (no lever arm: it sits on the path) is tracked at ~19 Hz with jittered
stamps, 10 % dropouts and a 1 s gap, with 5 mm noise, stamped in true time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.timesync import (
    OnlineOffsetEstimator,
    TimeSyncError,
    cross_correlation_offset,
    estimate_offset,
    estimate_offset_from_marker_yaws,
    heading_from_track,
)

FPS = 30.0
YAW_OFFSET = 1.234  # rad, VO yaw − true heading
A, B = 4.0, 1.5  # m, half-axes of the ellipse
NOISE_YAW = math.radians(0.2)  # rad, VO yaw noise per frame
DRIFT = math.radians(3.0) / 60.0  # rad/s, VO yaw drift


def ellipse_theta(t):
    return 0.15 * t + 0.3 * np.sin(0.2 * t)


def true_position(t):
    th = ellipse_theta(t)
    return np.stack([A * np.cos(th), B * np.sin(th)], axis=-1)


def true_heading(t):
    th = ellipse_theta(t)
    return np.arctan2(B * np.cos(th), -A * np.sin(th))  # d(th)/dt > 0 cancels


def true_speed(t):
    th = ellipse_theta(t)
    dth = 0.15 + 0.06 * np.cos(0.2 * t)
    return dth * np.hypot(A * np.sin(th), B * np.cos(th))


def scenario(tau, seed=0, duration=60.0, noise_xy=0.005, noise_yaw=NOISE_YAW, drift=DRIFT, prism_rate=19.0):
    """(t_vo on the camera clock, yaw_vo, t_prism on the true clock, xy_prism)."""
    rng = np.random.default_rng(seed)
    t_true = np.arange(0.0, duration, 1.0 / FPS)
    yaw = true_heading(t_true) + YAW_OFFSET + drift * t_true + rng.normal(0.0, noise_yaw, len(t_true))
    tp = np.cumsum(rng.uniform(0.8, 1.2, int(duration * prism_rate * 1.3)) / prism_rate) - 2.0
    tp = tp[(tp > -2.0) & (tp < duration + 2.0)]
    keep = (rng.random(len(tp)) > 0.1) & ~((tp > 20.0) & (tp < 21.0))
    tp = tp[keep]
    xy = true_position(tp) + rng.normal(0.0, noise_xy, (len(tp), 2))
    return t_true + tau, np.angle(np.exp(1j * yaw)), tp, xy


def test_heading_from_track_follows_the_true_tangent():
    rng = np.random.default_rng(3)
    tp = np.cumsum(rng.uniform(0.8, 1.2, 600) / 19.0)
    xyz = np.column_stack([true_position(tp), np.full(len(tp), 0.4)])  # a z column is ignored
    tq = np.linspace(2.0, 28.0, 200)
    h = heading_from_track(tp, xyz, tq, smooth=0.1)
    assert h.valid.all()
    err = np.angle(np.exp(1j * (h.heading - true_heading(tq))))
    assert np.max(np.abs(err)) < math.radians(0.05)
    assert np.max(np.abs(h.speed - true_speed(tq))) < 0.002
    # turn rate: the derivative of the true heading (numerical, from the analytic heading)
    d = 1e-4
    rate = np.angle(np.exp(1j * (true_heading(tq + d) - true_heading(tq - d)))) / (2 * d)
    assert np.max(np.abs(h.turn_rate - rate)) < 0.005


def test_heading_from_track_marks_gaps_and_standstill_invalid():
    tp = np.arange(0.0, 20.0, 0.05)
    tp = tp[(tp < 8.0) | (tp > 11.0)]  # 3 s dropout
    xy = np.column_stack([np.where(tp < 15.0, 0.5 * tp, 7.5), np.zeros_like(tp)])  # stops at 15 s
    h = heading_from_track(tp, xy, [5.0, 9.5, 18.0], smooth=0.2)
    assert h.valid.tolist() == [True, False, False]
    assert h.heading[0] == pytest.approx(0.0, abs=1e-9)
    assert h.speed[0] == pytest.approx(0.5, rel=1e-6)


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
    alone = estimate_offset_from_marker_yaws(t_vo[seen], yaw_m, tp, xy, marker_ids=ids)
    assert alone.sigma < 0.01 and abs(alone.offset - tau) <= 3 * alone.sigma  # half the data: honest σ
    both = estimate_offset_from_marker_yaws(t_vo[seen], yaw_m, tp, xy, marker_ids=ids, t_vo=t_vo, yaw_vo=yaw_vo)
    assert abs(both.offset - tau) <= 0.005
    assert both.n_samples > alone.n_samples
    with pytest.raises(TimeSyncError, match="no markers seen"):
        estimate_offset_from_marker_yaws([], [], tp, xy)


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


def test_online_estimator_applies_only_confident_estimates_with_bounded_memory():
    tau = 0.37
    t_vo, yaw, tp, xy = scenario(tau, seed=21, duration=90.0)
    online = OnlineOffsetEstimator(horizon=45.0, update_period=5.0)
    k = 0
    applied_at = None
    for t, y in zip(t_vo, yaw):
        online.add_vo(t, y)
        while k < len(tp) and tp[k] <= t - tau:  # the prism fixes that arrived by now
            online.add_track(tp[k], *xy[k])
            k += 1
        online.update()
        if t < 8.0:
            assert online.applied is None  # too little data: nothing applied, the reason kept
            assert online.last_error is None or "too short" in online.last_error
        if applied_at is None and online.applied is not None:
            applied_at = t
    assert applied_at is not None and applied_at < 40.0
    assert abs(online.applied - tau) <= 0.005
    assert 0.0 < online.applied_sigma <= online.max_sigma
    assert online.latest.confidence >= online.min_confidence
    assert online.correct_stamp(100.0) == pytest.approx(100.0 - online.applied)
    n_vo, n_track, _ = online.buffered
    assert n_vo <= 45.0 * FPS + 2 and n_track <= 45.0 * 19.0 * 1.3


def test_online_estimator_in_the_background_and_its_suggestion():
    """As the live node uses it: samples added from one thread, estimates in a worker thread; the
    suggestion replaces a wrong offset in use (0, forgotten) but not one within 5 σ or 20 ms."""
    tau = 0.37
    t_vo, yaw, tp, xy = scenario(tau, seed=22, duration=60.0)
    online = OnlineOffsetEstimator(horizon=45.0, update_period=5.0)
    started = 0
    k = 0
    for t, y in zip(t_vo, yaw):
        online.add_vo(t, y)
        while k < len(tp) and tp[k] <= t - tau:
            online.add_track(tp[k], *xy[k])
            k += 1
        started += online.update_in_background(t)
        if online._worker is not None:
            online._worker.join(10.0)  # a live node would go on; here: deterministic
    assert started >= 8
    assert online.applied is not None and abs(online.applied - tau) <= 0.005
    assert online.suggestion(0.0) == online.applied                # a forgotten offset is corrected
    assert online.suggestion(online.applied + 0.5 * online.applied_sigma) is None
    assert online.suggestion(online.applied + 0.015) is None       # within 20 ms: kept
    online.clear()
    assert online.buffered == (0, 0, 0) and online.applied is not None
    assert not online.update_in_background(100.0)                  # nothing buffered: nothing to do


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

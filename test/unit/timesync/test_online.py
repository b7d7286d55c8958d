"""timesync/online.py: the live estimator on synthetic signals with a known offset (signals.py):
only confident estimates applied, bounded memory, the background worker."""

from __future__ import annotations

import pytest

from aruco_abs_orient.timesync import OnlineOffsetEstimator

from .signals import FPS, scenario


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

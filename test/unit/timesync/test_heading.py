"""timesync/heading.py: the track heading follows the analytic tangent of the synthetic ellipse
(signals.py) and marks gaps and standstill invalid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aruco_abs_orient.timesync import heading_from_track

from .signals import true_heading, true_position, true_speed


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

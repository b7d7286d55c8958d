"""The start-up of MapOdomFilter (filter_startup.py) on simulated drives: anywhere, while moving from two markers
or one the prism track confirms, at a standstill when required, false ids left out, and why it waits."""

import math

import numpy as np
import pytest

from aruco_abs_orient.correction import FilterParams, MapOdomFilter, NotInitialisedError
from aruco_abs_orient.transforms import wrap_angle

from .filter_drive import PRISM_IN_BASE, SIGMA_PRISM, SIGMA_YAW, Drive


def test_starts_at_once_by_default_and_at_standstill_when_required():
    d = Drive(1, 20.0, drift_rate=math.radians(3.0) / 60.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    errs = d.run(f)
    assert errs[0][0] <= 0.3                       # 3 yaws of markers 3, 5, 8: no standstill needed
    assert abs(errs[0][1]) < math.radians(0.5) and f.stats.waiting_reason == ""
    f = MapOdomFilter(PRISM_IN_BASE, FilterParams(require_standstill=True))
    with pytest.raises(NotInitialisedError, match="no measurements"):
        f.map_T_odom(0.0)
    Drive(1, 1.0, drift_rate=math.radians(3.0) / 60.0).run(f)
    with pytest.raises(NotInitialisedError, match="standstill"):
        f.map_T_odom(1.0)
    f = MapOdomFilter(PRISM_IN_BASE, FilterParams(require_standstill=True))
    errs = Drive(1, 20.0, drift_rate=math.radians(3.0) / 60.0).run(f)
    assert f.initialised and f.stats.state == "tracking"
    t_init = errs[0][0]
    assert 1.8 <= t_init <= 3.0                    # during the 3 s standstill, after ~2 s of it
    yaw_err = np.array([e[1] for e in errs])
    pos_err = np.array([e[2] for e in errs])
    assert abs(yaw_err[0]) < math.radians(0.3)
    assert np.sqrt(np.mean(yaw_err[-100:] ** 2)) < math.radians(0.08)
    assert np.max(pos_err[-100:]) < 0.01
    assert f.stats.yaw_rejected <= 3 and f.stats.prism_rejected <= 3     # p = 0.001 gates
    assert set(f.stats.accepted_by_marker) == {3, 5, 8}


def test_starts_while_moving_from_two_markers_not_from_one():
    g = MapOdomFilter(PRISM_IN_BASE)
    errs = Drive(2, 6.0, still=0.0).run(g)
    assert g.initialised and errs[0][0] <= 0.3
    assert abs(errs[-1][1]) < math.radians(0.1) and errs[-1][2] < 0.01
    # one marker alone while moving starts only once the prism track (0.5 m) confirms it...
    f = MapOdomFilter(PRISM_IN_BASE)
    errs = Drive(2, 6.0, still=0.0).run(f, marker_ids=(3,))
    assert f.initialised and 0.4 <= errs[0][0] <= 1.0 and abs(errs[0][1]) < math.radians(0.5)
    # ...so a false id or a moved marker, 5° off, all there is in view, never starts it, and it says why
    f = MapOdomFilter(PRISM_IN_BASE)
    d = Drive(2, 6.0, still=0.0)
    for k, tk in enumerate(d.t):
        f.add_prism(tk, d.prism(k), SIGMA_PRISM, d.odom_T_base[k])
        f.add_yaw(tk, d.yaw(k) + math.radians(5.0), SIGMA_YAW, d.odom_T_base[k], marker_id=3)
    assert not f.initialised and "prism track" in f.stats.waiting_reason
    f = MapOdomFilter(PRISM_IN_BASE, FilterParams(require_standstill=True))
    Drive(2, 6.0, still=0.0).run(f)
    assert not f.initialised and "standstill" in f.stats.waiting_reason
    f = MapOdomFilter(PRISM_IN_BASE)
    assert f.stats.waiting_reason == "no measurements yet"
    d = Drive(2, 1.0, still=0.0)
    f.add_yaw(0.0, d.yaw(0), SIGMA_YAW, d.odom_T_base[0], marker_id=3)
    assert "no prism" in f.stats.waiting_reason


def test_false_ids_at_start_up_are_left_out():
    d = Drive(5, 4.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    for k, tk in enumerate(d.t):
        f.add_prism(tk, d.prism(k), SIGMA_PRISM, d.odom_T_base[k])
        if k % 2 == 0:
            f.add_yaw(tk, d.yaw(k), SIGMA_YAW, d.odom_T_base[k], marker_id=3)
        if k % 10 == 0:
            f.add_yaw(tk, d.heading[k] - math.radians(20.0), SIGMA_YAW, d.odom_T_base[k], marker_id=42)
    assert f.initialised
    assert abs(wrap_angle(f.x[0] - d.dpsi[-1])) < math.radians(0.2)
    assert 42 not in f.stats.accepted_by_marker

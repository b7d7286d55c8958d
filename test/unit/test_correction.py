"""MapOdomFilter's interface (correction.py): malformed and invalid inputs, UpdateResult, a tuning update.

The seams are tested in test_filter_core.py, test_filter_startup.py and test_filter_recovery.py, all on the
simulated drive of filter_drive.py."""

import numpy as np
import pytest

from aruco_abs_orient.correction import CorrectionError, FilterParams, MapOdomFilter

from .filter_drive import PRISM_IN_BASE, SIGMA_PRISM, SIGMA_YAW, Drive


def test_bad_inputs():
    f = MapOdomFilter(PRISM_IN_BASE)
    assert f.add_yaw(0.0, float("nan"), SIGMA_YAW, np.eye(4)).status == "invalid"
    bad = np.eye(4)
    bad[0, 3] = float("inf")
    assert f.add_prism(0.0, [1.0, 2.0, 3.0], SIGMA_PRISM, bad).status == "invalid"
    assert f.stats.invalid == 2
    with pytest.raises(CorrectionError, match="odom_T_base"):
        f.add_prism(0.0, [1.0, 2.0, 3.0], SIGMA_PRISM, np.eye(3))
    with pytest.raises(CorrectionError, match="yaw_random_walk"):
        MapOdomFilter(PRISM_IN_BASE, FilterParams(yaw_random_walk=-1.0))


def test_update_result_truthiness_and_params_update():
    d = Drive(10, 4.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    d.run(f)
    k = len(d.t) - 1
    assert f.add_yaw(d.t[k], d.heading[k], SIGMA_YAW, d.odom_T_base[k])
    assert not f.add_yaw(d.t[k], d.heading[k] + 0.1, SIGMA_YAW, d.odom_T_base[k])
    f.update_params(FilterParams(gate_chi2_yaw=1000.0))   # the widest gate: 0.1 rad is within 29 σ
    assert f.add_yaw(d.t[k], d.heading[k] + 0.1, SIGMA_YAW, d.odom_T_base[k]).status == "accepted"
    with pytest.raises(CorrectionError, match="gate_chi2_yaw"):
        f.update_params(FilterParams(gate_chi2_yaw=0.0))

"""The recovery of MapOdomFilter (filter_recovery.py) on simulated drives: re-initialisation after a long loss,
the lock-out recovery by markers that agree, a prism gap re-anchored."""

import math

import numpy as np

from aruco_abs_orient.correction import FilterParams, MapOdomFilter
from aruco_abs_orient.transforms import make_T, rot_z, rpy_to_matrix

from .filter_drive import PRISM_IN_BASE, SIGMA_PRISM, SIGMA_YAW, Drive


def test_reinitialises_after_a_long_loss_with_a_vo_jump():
    """VO relocalises during a 40 s marker loss: δψ jumps by 10°. Gating alone would never accept it."""
    jump = math.radians(10.0)

    def drive():
        d = Drive(7, 70.0)
        d.dpsi[d.t >= 20.0] += jump
        n = len(d.t)
        for k in range(1, n):
            d.p_odom[k] = d.p_odom[k - 1] + rot_z(-d.dpsi[k]) @ (d.p[k] - d.p[k - 1])
        d.odom_T_base = make_T(rpy_to_matrix(d.roll, d.pitch, d.heading - d.dpsi), d.p_odom)
        return d

    f = MapOdomFilter(PRISM_IN_BASE, FilterParams(reinit_after=30.0))
    errs = drive().run(f, yaw_gap=(15.0, 55.0), marker_ids=(3,))
    assert f.stats.reinitialisations == 1
    late = np.array([abs(e[1]) for e in errs if e[0] >= 60.0])
    assert np.max(late) < math.radians(0.2)
    # one marker that disagrees with the filter cannot overrule it: only the timer does
    stuck = MapOdomFilter(PRISM_IN_BASE, FilterParams(reinit_after=3600.0))   # never, in this drive
    drive().run(stuck, yaw_gap=(15.0, 55.0), marker_ids=(3,))
    assert stuck.stats.reinitialisations == 0 and stuck.stats.lockout_recoveries == 0
    assert stuck.stats.yaw_rejected > 50
    # several markers that agree with each other do, within a second of their return
    g = MapOdomFilter(PRISM_IN_BASE, FilterParams(reinit_after=3600.0))
    errs = drive().run(g, yaw_gap=(15.0, 55.0))
    assert g.stats.lockout_recoveries == 1
    assert np.max([abs(e[1]) for e in errs if e[0] >= 56.0]) < math.radians(0.2)


def test_prism_gap_of_minutes_with_a_vo_position_jump_is_reanchored():
    """No prism for 90 s, during which VO position jumps by 1.5 m: the first two agreeing prisms re-anchor."""
    d = Drive(9, 110.0, drift_rate=math.radians(3.0) / 60.0)
    jump = np.array([1.5, -0.5, 0.0])
    d.p_odom[d.t >= 40.0] += jump
    d.odom_T_base[:, :3, 3] = d.p_odom
    f = MapOdomFilter(make_T(np.eye(3), PRISM_IN_BASE), FilterParams(reinit_after=30.0))
    out = []
    for k, tk in enumerate(d.t):
        if not 10.0 <= tk < 100.0:
            f.add_prism(tk, d.prism(k), SIGMA_PRISM, d.odom_T_base[k])
        if k % 2 == 0:
            f.add_yaw(tk, d.yaw(k), SIGMA_YAW, d.odom_T_base[k], marker_id=1)
        if f.initialised:
            base = f.map_T_odom(tk)[0] @ d.odom_T_base[k]
            out.append((tk, np.linalg.norm(base[:3, 3] - d.p[k])))
    assert f.stats.prism_reanchors == 1
    assert max(e for tk, e in out if 40.0 <= tk < 100.0) > 1.0        # the jump was real and showed
    assert max(e for tk, e in out if tk >= 101.0) < 0.01

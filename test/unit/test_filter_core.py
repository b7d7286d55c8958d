"""The Kalman core of MapOdomFilter (filter_core.py) on simulated drives: tracking a drift, gating, coasting on
the drift rate, late measurements, an honest covariance, snapshot and restore."""

import math

import numpy as np
import pytest

from aruco_abs_orient.correction import FilterParams, MapOdomFilter
from aruco_abs_orient.transforms import wrap_angle

from .filter_drive import PRISM_IN_BASE, SIGMA_PRISM, SIGMA_YAW, Drive


def test_tracks_a_3_deg_per_minute_drift():
    d = Drive(3, 60.0, drift_rate=math.radians(3.0) / 60.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    errs = d.run(f, errors_from=5.0)
    yaw_err = np.array([e[1] for e in errs])
    assert math.degrees(d.dpsi[-1] - d.dpsi[0]) == pytest.approx(3.0)     # the truth really drifted 3°
    # 0.2° per yaw at 10 Hz: the random walk tuned for 3°/min averages it down to ≈ 0.05°.
    assert math.degrees(np.sqrt(np.mean(yaw_err ** 2))) < 0.08
    assert math.degrees(np.percentile(np.abs(yaw_err), 95)) < 0.15
    assert np.sqrt(np.mean(np.array([e[2] for e in errs]) ** 2)) < 0.005


def test_gating_rejects_a_false_id_20_degrees_off():
    d = Drive(4, 12.0, drift_rate=math.radians(3.0) / 60.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    d.run(f)
    before = f.x.copy()
    k = len(d.t) - 1
    # at the filter's own time (no prediction step), so a rejection must leave the state exactly as it was
    res = f.add_yaw(f.t, d.heading[k] + math.radians(20.0), SIGMA_YAW, d.odom_T_base[k], marker_id=99)
    assert res.status == "gated" and not res.accepted and res.chi2 > 1000
    assert f.stats.rejected_by_marker == {99: 1}
    np.testing.assert_allclose(f.x, before, atol=1e-12)
    good = f.add_yaw(d.t[k] + 0.02, d.heading[k], SIGMA_YAW, d.odom_T_base[k], marker_id=3)
    assert good.accepted


def test_coasting_follows_the_drift_rate_and_grows_the_covariance_then_recovers():
    p = FilterParams()
    plain = FilterParams(drift_rate_walk=0.0, initial_drift_rate_sigma=0.0)   # δψ a plain random walk
    d = Drive(6, 60.0, drift_rate=math.radians(3.0) / 60.0)
    f, r = MapOdomFilter(PRISM_IN_BASE, p), MapOdomFilter(PRISM_IN_BASE, plain)
    errs = d.run(f, yaw_gap=(30.0, 40.0))
    errs_plain = d.run(r, yaw_gap=(30.0, 40.0))
    var_before = f.P[0, 0]
    # the drift rate learnt in the 27 s before the gap carries map→odom through it: the plain random
    # walk freezes δψ, and 3°/min × 10 s = 0.5° by the end of the gap (less what the prism track tells)
    in_gap = np.array([abs(e[1]) for e in errs if 35.0 <= e[0] < 40.0])
    in_gap_plain = np.array([abs(e[1]) for e in errs_plain if 35.0 <= e[0] < 40.0])
    assert np.max(in_gap_plain) > math.radians(0.3)
    assert np.max(in_gap) < math.radians(0.2) and np.mean(in_gap) < 0.5 * np.mean(in_gap_plain)
    after = np.array([abs(e[1]) for e in errs if e[0] >= 45.0])
    assert np.max(after) < math.radians(0.3) and np.mean(after) < math.radians(0.1)
    assert f.stats.reinitialisations == 0                  # 10 s < reinit_after
    # Query while coasting: the yaw variance grows as the model says (hand-derived for δψ' = δψ + ω dt:
    # var + 2 dt cov(δψ, ω) + dt² var(ω) + q_a² dt + q_w² dt³/3; the prism adds little yaw information)
    g = MapOdomFilter(PRISM_IN_BASE, p)
    Drive(6, 10.0, drift_rate=math.radians(3.0) / 60.0).run(g)
    t0, _, P = g.state
    dt = 30.0 - t0
    _, P30 = g.map_T_odom(30.0)
    want = (P[0, 0] + 2 * dt * P[0, 4] + dt ** 2 * P[4, 4] + p.yaw_random_walk ** 2 * g.stats.noise_scale * dt
            + p.drift_rate_walk ** 2 * dt ** 3 / 3.0)
    assert P30[0, 0] == pytest.approx(want, rel=1e-9)
    assert var_before < P30[0, 0]


def test_late_measurements_policy():
    d = Drive(8, 8.0)
    f = MapOdomFilter(PRISM_IN_BASE, FilterParams(max_delay=0.5))
    d.run(f)
    k = len(d.t) - 1
    k_late = k - 6          # 0.3 s old: applied
    assert f.add_yaw(d.t[k_late], d.yaw(k_late), SIGMA_YAW, d.odom_T_base[k_late]).accepted
    assert f.t == d.t[k]    # the filter did not go back
    k_old = k - 20          # 1.0 s old: rejected
    res = f.add_prism(d.t[k_old], d.prism(k_old), SIGMA_PRISM, d.odom_T_base[k_old])
    assert res.status == "too_old" and f.stats.too_old == 1


def test_covariance_is_honest_over_monte_carlo_runs():
    """Truth drawn from the filter's own model (a drift rate from its prior, wandering at its rate
    walk; yaw and translation random walks): normalised final errors have std 1 ± 20 %."""
    # a prior of 3°/min: faster drift would move the odometry's yaw at rest beyond the standstill test
    p = FilterParams(yaw_random_walk=math.radians(0.1), translation_random_walk=0.01,
                     initial_drift_rate_sigma=math.radians(3.0) / 60.0)
    z = []
    for run in range(150):
        rng = np.random.default_rng(run)
        d = Drive(100 + run, 12.0, yaw_walk=p.yaw_random_walk, trans_walk=p.translation_random_walk,
                  dpsi0=float(rng.uniform(-math.pi, math.pi)),
                  drift_rate=float(rng.normal(0.0, p.initial_drift_rate_sigma)), rate_walk=p.drift_rate_walk)
        f = MapOdomFilter(PRISM_IN_BASE, p)
        d.run(f, yaw_every=4, marker_ids=(), errors_from=math.inf)
        err = np.concatenate([[wrap_angle(f.x[0] - d.dpsi[-1])], f.x[1:4] - d.map_t_odom[-1], [f.x[4] - d.rate[-1]]])
        z.append(err / np.sqrt(np.diag(f.P)))
    sd = np.std(np.array(z), axis=0)
    assert np.all((sd > 0.8) & (sd < 1.2)), sd


def test_a_restarted_filter_continues_from_its_snapshot_and_refuses_a_stale_one():
    """A node respawned while driving: the new filter starts from the old one's snapshot (a JSON round trip),
    its covariance grown over the gap, and tracks on; a snapshot older than max_age, or from the future (a
    bag replayed again), is refused with the reason."""
    import json

    d = Drive(11, 30.0, drift_rate=math.radians(3.0) / 60.0)
    f = MapOdomFilter(PRISM_IN_BASE)
    k_stop = int(np.searchsorted(d.t, 15.0))
    for k in range(k_stop):
        f.add_prism(d.t[k], d.prism(k), SIGMA_PRISM, d.odom_T_base[k])
        f.add_yaw(d.t[k], d.yaw(k), SIGMA_YAW, d.odom_T_base[k], marker_id=(3, 5)[k % 2])
    snap = json.loads(json.dumps(f.snapshot()))
    assert MapOdomFilter(PRISM_IN_BASE).snapshot() is None
    t_restart = d.t[k_stop - 1] + 2.0                      # 2 s later, still driving
    g = MapOdomFilter(PRISM_IN_BASE)
    assert g.restore(snap, t_restart, max_age=10.0) == ""
    assert g.initialised and g.stats.restored_age == pytest.approx(2.0)
    k = int(np.searchsorted(d.t, t_restart))
    T, P = g.map_T_odom(t_restart)
    assert abs(wrap_angle(math.atan2(T[1, 0], T[0, 0]) - d.dpsi[k])) < 3.0 * math.sqrt(P[0, 0])
    assert P[0, 0] > f.P[0, 0]                              # grown over the gap
    errs = d.run(g, errors_from=t_restart)                  # the drive goes on: it tracks, no lock-out
    assert max(abs(e[1]) for e in errs if e[0] > t_restart + 1.0) < math.radians(0.2)
    for t_now, why in ((snap["t"] + 11.0, "old"), (snap["t"] - 5.0, "old")):
        assert why in MapOdomFilter(PRISM_IN_BASE).restore(snap, t_now, max_age=10.0)
    assert "not a filter state" in MapOdomFilter(PRISM_IN_BASE).restore({"t": 1.0}, 1.0, 10.0)

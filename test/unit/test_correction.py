"""MapOdomFilter against a simulated drive with a known drifting odometry.

The truth is built here from transforms.py: a base_link trajectory in map (standstill, then a
curve with some tilt), a map→odom yaw offset δψ(t) (constant drift and/or random walk) and odom
position drift; the odometry is the truth seen through the drifting map→odom, so
``map_T_odom_true(t) · odom_T_base(t) = map_T_base_true(t)`` exactly. The prism and the marker
yaws are the truth plus known noise.
"""

import math

import numpy as np
import pytest

from aruco_abs_orient.correction import (
    CorrectionError,
    FilterParams,
    MapOdomFilter,
    NotInitialisedError,
)
from aruco_abs_orient.transforms import make_T, rot_z, rpy_to_matrix, wrap_angle

PRISM_IN_BASE = np.array([-0.2, 0.05, 1.3])
SIGMA_PRISM = 0.005          # m
SIGMA_YAW = math.radians(0.2)


class Drive:
    """Truth and odometry sampled every ``dt`` s: still for ``still`` s, then a curve at ``speed`` m/s."""

    def __init__(self, seed, duration, dt=0.05, still=3.0, speed=1.0, dpsi0=2.0, drift_rate=0.0,
                 yaw_walk=0.0, trans_walk=0.0, rate_walk=0.0):
        rng = np.random.default_rng(seed)
        self.rng = rng
        n = int(round(duration / dt)) + 1
        self.t = np.arange(n) * dt
        moving = np.clip(self.t - still, 0.0, None)
        self.heading = 0.7 + 0.4 * np.sin(0.3 * moving)
        self.roll = 0.01 + 0.02 * np.sin(moving)
        self.pitch = 0.015 * np.cos(0.7 * moving)
        vel = speed * (self.t > still)[:, None] * np.stack([np.cos(self.heading), np.sin(self.heading),
                                                             np.zeros(n)], axis=1)
        self.p = np.array([5.0, -3.0, 0.2]) + np.concatenate([[np.zeros(3)], np.cumsum(vel[1:] * dt, axis=0)])
        steps = rng.normal(size=n) * yaw_walk * math.sqrt(dt)
        steps[0] = 0.0
        self.rate = drift_rate + np.cumsum(rng.normal(size=n) * rate_walk * math.sqrt(dt))   # rad/s
        self.dpsi = dpsi0 + np.concatenate([[0.0], np.cumsum(self.rate[:-1] * dt)]) + np.cumsum(steps)
        self.p_odom = np.zeros((n, 3))
        for k in range(1, n):
            walk = rng.normal(size=3) * trans_walk * math.sqrt(dt) * (self.t[k] > still)   # VO drifts when moving
            self.p_odom[k] = self.p_odom[k - 1] + rot_z(-self.dpsi[k]) @ (self.p[k] - self.p[k - 1]) + walk
        self.R = rpy_to_matrix(self.roll, self.pitch, self.heading)
        self.odom_T_base = make_T(rpy_to_matrix(self.roll, self.pitch, self.heading - self.dpsi), self.p_odom)
        self.map_t_odom = self.p - np.einsum("nij,nj->ni", rot_z(self.dpsi), self.p_odom)

    def prism(self, k):
        return self.p[k] + self.R[k] @ PRISM_IN_BASE + SIGMA_PRISM * self.rng.normal(size=3)

    def yaw(self, k):
        return self.heading[k] + SIGMA_YAW * self.rng.normal()

    def run(self, f, yaw_every=2, yaw_gap=(), marker_ids=(3, 5, 8), errors_from=0.0):
        """Feed prism (every step) and yaws (every ``yaw_every`` steps, none inside ``yaw_gap`` (t0, t1));
        return per-step (time, yaw error rad, base position error m) once initialised after ``errors_from``."""
        out = []
        for k, tk in enumerate(self.t):
            f.add_prism(tk, self.prism(k), SIGMA_PRISM, self.odom_T_base[k])
            if k % yaw_every == 0 and not (yaw_gap and yaw_gap[0] <= tk < yaw_gap[1]):
                mid = marker_ids[(k // yaw_every) % len(marker_ids)] if marker_ids else None
                f.add_yaw(tk, self.yaw(k), SIGMA_YAW, self.odom_T_base[k], marker_id=mid)
            if f.initialised and tk >= errors_from:
                T, _ = f.map_T_odom(tk)
                base = T @ self.odom_T_base[k]
                out.append((tk, float(wrap_angle(f.x[0] - self.dpsi[k])), np.linalg.norm(base[:3, 3] - self.p[k])))
        return out


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

"""Absolute pose without a total station (issue 15): resection into the map→odom filter, the tilt sources,
prism dropouts, and a wrong marker id, on the generator's scenarios fed without rendering
(:mod:`synthetic.feed`: exact bearings + noise in place of detection).

Truth: the scenario's own base_link pose and tilt; the pipeline never sees them.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from aruco_abs_orient.correction import MapOdomFilter
from aruco_abs_orient.detection import MarkerObservation
from aruco_abs_orient.pipeline import AbsOrientPipeline, PipelineParams
from aruco_abs_orient.synthetic.feed import feed
from aruco_abs_orient.synthetic.scenario import Scenario, ScenarioConfig
from aruco_abs_orient.tilt import GRAVITY, TiltEstimator, tilt_from_imu
from aruco_abs_orient.transforms import make_T, matrix_to_quat, matrix_to_rpy, rot_z, rpy_to_matrix, wrap_angle, yaw_of

NOISE = math.radians(0.02)
HALL = ScenarioConfig(duration=15.0, fps=10.0, width=3840, standstill=0.0, accel_time=0.5, n_markers=10,
                      marker_size=0.19, marker_distance=(3.0, 10.0), boresight_deg=0.0)


def errors(cfg, params=None, perturb=None):
    """(relative times, heading errors rad, position errors m (NaN without a pose), results, pipeline)."""
    sc = Scenario(cfg)
    pipe = AbsOrientPipeline(sc.markers, sc.base_T_camera_nominal, sc.base_T_prism, params or PipelineParams())
    rel, eh, ep, results = [], [], [], []
    frames = feed(sc, pipe, None, NOISE, np.random.default_rng(cfg.seed)) if perturb is None else perturb(sc, pipe)
    for t, res in frames:
        T = sc.map_T_base(t)
        rel.append(t - sc.frame_times[0])
        ok = res.map_T_base is not None
        eh.append(float(wrap_angle(res.yaw - yaw_of(T[:3, :3]))) if ok else math.nan)
        ep.append(float(np.linalg.norm(res.map_T_base[:3, 3] - T[:3, 3])) if ok else math.nan)
        results.append(res)
    return np.array(rel), np.array(eh), np.array(ep), results, pipe


def rms(x):
    x = np.asarray(x)[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2)))


@pytest.mark.parametrize("seed", range(2))
def test_markers_only_gives_heading_and_position_from_the_markers_alone(seed):
    rel, eh, ep, results, pipe = errors(replace(HALL, seed=seed), PipelineParams(markers_only=True))
    assert all(r.prism_position is None for r in results)           # the prism was never used
    assert np.mean(np.isfinite(eh)) > 0.9, pipe.waiting_reason
    assert math.degrees(rms(eh)) < 0.05
    assert rms(ep) < 0.02
    assert pipe.filter.stats.pose_accepted > 0.5 * len(rel)
    # the frame's own resection, before the filter, is what the node publishes: checked against the truth too
    sc = Scenario(replace(HALL, seed=seed))
    own = [(r.stamp, r.marker_pose) for r in results if r.marker_pose_accepted and len(r.observations) >= 3]
    err = [np.linalg.norm(T[:3, 3] - sc.map_T_base(t)[:3, 3]) for t, T in own]
    assert len(own) > 30 and np.median(err) < 0.02


def test_markers_only_waits_and_says_why_with_one_marker():
    cfg = replace(HALL, seed=3, duration=5.0, n_markers=1, marker_distance=(3.0, 5.0))
    _, eh, _, _, pipe = errors(cfg, PipelineParams(markers_only=True))
    assert np.all(np.isnan(eh))
    assert "resection" in pipe.waiting_reason, pipe.waiting_reason


def test_a_wrong_marker_id_consistent_over_several_frames_does_not_pull_the_pose():
    """A second physical marker carrying the id of a map marker, 1.5 m from where the map has it, seen in 8
    consecutive frames (so it agrees with itself from frame to frame): neither the resection's robust fit
    nor the filter's gate let it move the pose."""
    cfg = replace(HALL, seed=1)

    def with_impostor(sc, pipe):
        times = sc.frame_times
        frame, ids, bearings = sc.marker_bearings(times, noise=NOISE, rng=np.random.default_rng(1))
        fake_id = int(sc.markers.ids[0])
        fake_at = sc.markers[fake_id].position + np.array([1.5, -0.8, 0.2])
        for i, t in enumerate(times):
            obs = [MarkerObservation(int(ids[k]), np.zeros((4, 3)), bearings[k], (0.0, 0.0), np.zeros((4, 2)), 0.0,
                                     NOISE, "full") for k in np.nonzero(frame == i)[0] if ids[k] != fake_id]
            if 80 <= i < 88:
                T = sc.map_T_camera(t)
                d = T[:3, :3].T @ (fake_at - T[:3, 3])
                obs.append(MarkerObservation(fake_id, np.zeros((4, 3)), d / np.linalg.norm(d), (0.0, 0.0),
                                             np.zeros((4, 2)), 0.0, NOISE, "full"))
            yield float(t), pipe.process_observations(float(t), obs, sc.odom_T_base(float(t)))

    rel, eh, ep, results, _ = errors(cfg, PipelineParams(markers_only=True), with_impostor)
    clean_rel, clean_eh, clean_ep, _, _ = errors(cfg, PipelineParams(markers_only=True))
    window = (rel >= 7.5) & (rel < 10.0)
    assert np.all(np.isfinite(eh[window]))
    assert math.degrees(np.max(np.abs(eh[window]))) < 0.08
    assert np.max(ep[window]) < 0.03
    impostor = [o for r in results[80:88] for o in r.observations if o.id == int(Scenario(cfg).markers.ids[0])]
    assert impostor and not any(o.accepted for o in impostor)
    # the same frames without the impostor: no worse than that by more than noise
    assert abs(math.degrees(rms(eh[window]) - rms(clean_eh[window]))) < 0.02


def test_markers_only_map_with_too_few_markers_is_refused_per_frame_with_the_reason():
    cfg = replace(HALL, seed=2, duration=3.0, n_markers=2, marker_distance=(3.0, 4.0))
    _, _, _, results, pipe = errors(cfg, PipelineParams(markers_only=True))
    one = [r for r in results if len(r.observations) == 1]
    assert all("resection needs" in r.observations[0].reason for r in one)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_prism_dropout_is_bridged_by_resection_instead_of_coasting(seed):
    """A 5 s prism dropout while the VO drifts 4°/min (0.33° over the dropout if it coasted): the frames' resections
    keep the heading within 1.5× of its error with the prism."""
    cfg = replace(HALL, seed=seed, duration=20.0, prism_outage=(10.0, 5.0), prism_gaps=0)
    rel, eh, _, results, pipe = errors(cfg)
    gap = (rel >= 10.2) & (rel < 15.0)
    assert all(r.prism_position is None for r, g in zip(results, gap) if g)
    assert sum(r.marker_pose_accepted for r, g in zip(results, gap) if g) > 20
    inside, outside = rms(eh[gap]), rms(eh[(~gap) & (rel > 2.0)])
    assert inside < 1.5 * outside, (math.degrees(inside), math.degrees(outside))


def test_filter_starts_from_poses_that_agree_and_gates_one_that_does_not():
    f = MapOdomFilter(np.zeros(3))
    truth_dpsi, truth_t = 0.4, np.array([2.0, -1.0, 0.1])
    C = np.diag([math.radians(0.05) ** 2, 1e-4, 1e-4, 1e-4])
    for k in range(3):
        q = np.array([0.3 * k, 0.1 * k, 0.0])
        odom = make_T(rot_z(0.05 * k), q)
        p = rot_z(truth_dpsi) @ q + truth_t
        res = f.add_pose(float(k) * 0.1, p, truth_dpsi + 0.05 * k, C, odom, sources=(1, 2, 3))
    assert res.status == "initialised"
    T, _ = f.map_T_odom(0.2)
    assert abs(wrap_angle(yaw_of(T[:3, :3]) - truth_dpsi)) < 1e-9
    np.testing.assert_allclose(T[:3, 3], truth_t, atol=1e-9)
    q = np.array([1.0, 0.5, 0.0])
    off = f.add_pose(0.3, rot_z(truth_dpsi) @ q + truth_t + [0.5, 0.0, 0.0], truth_dpsi, C, make_T(np.eye(3), q))
    assert off.status == "gated"
    assert f.add_pose(0.4, rot_z(truth_dpsi) @ q + truth_t, truth_dpsi, C, make_T(np.eye(3), q)).accepted


# ----------------------------------------------------------------------------- tilt


def _imu_at(roll, pitch, yaw=0.7):
    R = rpy_to_matrix(roll, pitch, yaw)
    return matrix_to_quat(R), R.T @ np.array([0.0, 0.0, GRAVITY])


def test_tilt_from_imu_orientation_acceleration_and_fallbacks():
    q, a = _imu_at(0.03, -0.02)
    cov = np.diag([1e-6, 1e-6, 1e-2]).ravel()
    (roll, pitch, sigma), _ = tilt_from_imu(q, cov, a + 0.5, np.eye(3).ravel() * 0.01, np.zeros(3))
    assert abs(roll - 0.03) < 1e-9 and abs(pitch + 0.02) < 1e-9 and sigma == pytest.approx(1e-3)
    # REP-145 orientation unknown: gravity from the acceleration at standstill
    unknown = np.r_[-1.0, np.zeros(8)]
    (roll, pitch, sigma), _ = tilt_from_imu(q, unknown, a, np.eye(3).ravel() * 1e-4, np.zeros(3))
    assert abs(roll - 0.03) < 1e-9 and abs(pitch + 0.02) < 1e-9
    assert sigma == pytest.approx(max(0.01 / GRAVITY, math.radians(0.02)))
    # NaN orientation, moving: nothing, with the reason
    out, why = tilt_from_imu([np.nan, 0, 0, 1], cov, a, np.eye(3).ravel() * 1e-4, np.array([0.0, 0.0, 0.3]))
    assert out is None and "not finite" in why and "standstill" in why
    # a mounting rotation of the IMU in base_link is taken out
    R_bi = rpy_to_matrix(0.0, 0.0, math.pi / 2)
    R_wb = rpy_to_matrix(0.03, -0.02, 0.7)
    (roll, pitch, _), _ = tilt_from_imu(matrix_to_quat(R_wb @ R_bi), cov, a, np.zeros(9), np.zeros(3), base_R_imu=R_bi)
    assert abs(roll - 0.03) < 1e-9 and abs(pitch + 0.02) < 1e-9


def test_tilt_estimator_prefers_a_fresh_imu_and_falls_back_to_the_corrected_odometry():
    est = TiltEstimator(None, math.radians(PipelineParams().tilt_sigma_deg))
    assert est.tilt(0.0, 0.01, 0.02).source == "odometry"
    est.add_imu(1.0, 0.05, 0.01, 1e-3)
    est.add_imu(1.1, 0.07, 0.01, 1e-3)
    t = est.tilt(1.05, 0.0, 0.0)
    assert t.source == "imu" and t.roll == pytest.approx(0.06)
    later = est.tilt(3.0, 0.0, 0.0)      # IMU stale: the odometry, corrected by what the IMU said
    assert later.source == "imu"
    assert later.roll == pytest.approx(0.06, abs=0.01)


@pytest.mark.parametrize("imu", [False, True])
def test_a_drifting_odometry_tilt_is_corrected_by_the_imu_or_the_markers(imu):
    """VO roll/pitch drifting 3°/min: with the prism, the markers' attitude (or the IMU) keep the tilt used for
    the yaws on the truth while the odometry's is degrees off."""
    cfg = replace(HALL, seed=4, duration=40.0, vo_tilt_drift_deg_per_min=3.0, imu_rate=50.0 if imu else 0.0)
    rel, eh, _, results, pipe = errors(cfg, PipelineParams(tilt_from_markers=True))
    sc = Scenario(cfg)
    t_end = sc.frame_times[-1]
    true_rp = np.array(matrix_to_rpy(sc.map_T_base(t_end)[:3, :3])[:2])
    odom_rpy = np.array(matrix_to_rpy(sc.odom_T_base(t_end)[:3, :3]))
    odom_rp = odom_rpy[:2]
    used = pipe.tilt.tilt(t_end, *odom_rpy)
    assert used.source == ("imu" if imu else "markers")
    assert math.degrees(np.max(np.abs(odom_rp - true_rp))) > 1.5
    assert math.degrees(np.max(np.abs(np.array([used.roll, used.pitch]) - true_rp))) < 0.1
    assert results[-1].tilt_source == used.source
    assert math.degrees(rms(eh[rel > 2.0])) < 0.03


@pytest.mark.parametrize("fps, drift, seed", [(30.0, 3.0, 5), (15.0, -2.0, 6)])
def test_the_markers_tilt_is_fitted_once_per_interval_and_still_follows_a_drifting_odometry(fps, drift, seed):
    """tilt_fit_interval (0.1 s): at 30 and 15 fps one roll and pitch fit per 0.1 s slot at most, most slots have
    one, and the tilt and heading stay as good as with a fit in every frame while the VO's tilt drifts."""
    cfg = replace(HALL, seed=seed, duration=20.0, fps=fps, vo_tilt_drift_deg_per_min=drift, prism_dropout=0.0,
                  prism_gaps=0)   # every frame with the prism: no resection's tilt in the count
    sc = Scenario(cfg)
    t_end = sc.frame_times[-1]
    true_rp = np.array(matrix_to_rpy(sc.map_T_base(t_end)[:3, :3])[:2])
    runs = {}
    for interval in (0.1, 0.0):
        rel, eh, _, results, pipe = errors(cfg, PipelineParams(tilt_from_markers=True, tilt_fit_interval=interval))
        used = pipe.tilt.tilt(t_end, *matrix_to_rpy(sc.odom_T_base(t_end)[:3, :3]))
        assert "no_prism" not in pipe.stats
        runs[interval] = (pipe.stats.get("tilt_from_markers", 0),
                          math.degrees(np.max(np.abs(np.array([used.roll, used.pitch]) - true_rp))),
                          math.degrees(rms(eh[rel > 2.0])))
    slots = cfg.duration / 0.1
    (fits, tilt_err, heading), (every_fits, every_tilt_err, every_heading) = runs[0.1], runs[0.0]
    assert 0.6 * slots <= fits <= slots + 1
    assert every_fits > 0.9 * fps * 0.1 * fits
    assert tilt_err < 0.1 and every_tilt_err < 0.1
    assert heading < max(1.2 * every_heading, 0.01)

"""synthetic/scenario.py: determinism, the standstill and the loop, the VO drift model, the prism
track (rate, jitter, dropouts, noise), lever arms and boresight, markers, the hidden-YAML round trip.
Checked against the config's numbers and geometry computed here, not the module's own helpers."""
import dataclasses
import math

import numpy as np
import pytest
import yaml

from aruco_abs_orient.camera import angle_between
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario, ScenarioError
from aruco_abs_orient.transforms import invert_T, matrix_to_rpy, transform_points, wrap_angle, yaw_of

CFG = dataclasses.replace(PRESETS["ci"], duration=30.0)


@pytest.fixture(scope="module")
def sc():
    return Scenario(CFG)


def test_deterministic_per_seed():
    a, b = Scenario(CFG), Scenario(CFG)
    t = a.frame_times
    np.testing.assert_array_equal(a.odom_T_base(t), b.odom_T_base(t))
    np.testing.assert_array_equal(a.prism.positions, b.prism.positions)
    np.testing.assert_array_equal(a.markers.positions(), b.markers.positions())
    c = Scenario(dataclasses.replace(CFG, seed=1))
    assert not np.allclose(a.markers.positions()[:2], c.markers.positions()[:2])
    assert not np.allclose(a.map_T_base(t[0]), c.map_T_base(t[0]))


def test_frames_and_clock_offset(sc):
    n = int(round(CFG.duration * CFG.fps))
    assert sc.frame_times.shape == (n,)
    np.testing.assert_allclose(np.diff(sc.frame_times), 1.0 / CFG.fps, atol=1e-6)
    assert sc.frame_times[0] == CFG.start_time
    np.testing.assert_allclose(sc.camera_stamps - sc.frame_times, CFG.camera_time_offset, atol=1e-6)


def test_standstill_then_driving_on_the_loop(sc):
    t = CFG.start_time + np.arange(0.0, CFG.duration, 0.05)
    T = sc.map_T_base(t)
    p = T[:, :3, 3]
    still = t - CFG.start_time <= CFG.standstill
    assert np.abs(p[still] - p[0]).max() < 1e-9
    assert np.abs(T[still, :3, :3] - T[0, :3, :3]).max() < 1e-9
    # cruise speed once accelerated
    cruise = t - CFG.start_time > CFG.standstill + CFG.accel_time + 0.1
    speed = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) / 0.05
    np.testing.assert_allclose(speed[cruise[:-1]], CFG.speed, rtol=0.01)
    # on the ellipse, heading along the motion, mostly level
    (cx, cy), (a, b) = CFG.track_center, CFG.track_radii
    np.testing.assert_allclose(((p[:, 0] - cx) / a) ** 2 + ((p[:, 1] - cy) / b) ** 2, 1.0, atol=1e-9)
    heading = np.arctan2(np.diff(p[:, 1]), np.diff(p[:, 0]))
    yaw_mid = yaw_of(sc.map_T_base(t[:-1] + 0.025)[:, :3, :3])
    assert np.degrees(np.abs(wrap_angle(heading - yaw_mid))[cruise[:-1]]).max() < 0.2
    roll, pitch, _ = matrix_to_rpy(T[:, :3, :3])
    assert np.degrees(np.abs(roll)).max() <= CFG.roll_pitch_deg + 1e-9
    assert np.degrees(np.abs(pitch)).max() <= CFG.roll_pitch_deg + 1e-9
    assert np.degrees(np.abs(roll)).max() > 0.3 * CFG.roll_pitch_deg  # not trivially flat


def test_drift_model_exact_without_noise():
    quiet = dataclasses.replace(CFG, vo_yaw_walk_deg_per_sqrt_s=0.0, vo_translation_noise=0.0, vo_scale_error=0.0)
    s = Scenario(quiet)
    t = s.frame_times
    M = s.map_T_odom(t)
    yaw = yaw_of(M[:, :3, :3])
    rate = math.radians(quiet.vo_yaw_drift_deg_per_min) / 60.0
    # map→odom yaw = ψ0 − drift: loses drift_rate·t
    np.testing.assert_allclose(wrap_angle(yaw - yaw[0]), -rate * (t - t[0]), atol=1e-9)
    # map→odom starts at the first base_link pose, levelled (a non-trivial offset)
    T0 = s.map_T_base(t[0])
    np.testing.assert_allclose(M[0, :3, 3], T0[:3, 3], atol=1e-12)
    assert yaw[0] == pytest.approx(float(yaw_of(T0[:3, :3])))
    assert np.linalg.norm(M[0, :3, 3]) > 1.0
    np.testing.assert_allclose(matrix_to_rpy(M[:, :3, :3])[0], 0.0, atol=1e-12)  # odom stays level
    # with zero drift rate too, map→odom is constant: VO = truth seen from odom
    still = Scenario(dataclasses.replace(quiet, vo_yaw_drift_deg_per_min=0.0))
    np.testing.assert_allclose(still.map_T_odom(t), np.broadcast_to(still.map_T_odom(t[0]), (t.size, 4, 4)),
                               atol=1e-6)


def test_drift_random_walk_scale_and_jitter():
    long = dataclasses.replace(CFG, duration=300.0, vo_yaw_walk_deg_per_sqrt_s=0.05)
    s = Scenario(long)
    t = long.start_time + np.arange(0.0, 300.0, 1.0)
    rate = math.radians(long.vo_yaw_drift_deg_per_min) / 60.0
    walk = s.vo_yaw_error(t) - rate * (t - t[0])
    steps = np.diff(walk)  # 1 s increments of a random walk: σ = 0.05°
    assert np.degrees(steps.std()) == pytest.approx(0.05, rel=0.25)
    assert abs(np.degrees(steps.mean())) < 0.02
    # jitter: same seed with and without translation noise differ by ~σ per axis at the 50 Hz grid
    noiseless = Scenario(dataclasses.replace(long, vo_translation_noise=0.0))
    tg = long.start_time + np.arange(1.0, 299.0, 0.02)
    d = s.odom_T_base(tg)[:, :3, 3] - noiseless.odom_T_base(tg)[:, :3, 3]
    assert d.std(axis=0) == pytest.approx([long.vo_translation_noise] * 3, rel=0.1)
    # scale error: VO path length / true path length
    quiet = Scenario(dataclasses.replace(long, vo_translation_noise=0.0))
    tt = long.start_time + np.arange(0.0, 300.0, 0.1)
    true_len = np.linalg.norm(np.diff(quiet.map_T_base(tt)[:, :3, 3], axis=0), axis=1).sum()
    vo_len = np.linalg.norm(np.diff(quiet.odom_T_base(tt)[:, :3, 3], axis=0), axis=1).sum()
    assert vo_len / true_len == pytest.approx(1.0 + long.vo_scale_error, abs=2e-4)


def test_drift_at_least_3_deg_per_minute_in_demo():
    s = Scenario(PRESETS["demo"])
    t = s.frame_times
    M = s.map_T_odom(t)
    assert abs(math.degrees(float(wrap_angle(yaw_of(M[-1, :3, :3]) - yaw_of(M[0, :3, :3]))))) >= 2.5
    assert PRESETS["demo"].vo_yaw_drift_deg_per_min >= 3.0


def test_prism_rate_jitter_dropouts_noise(sc):
    ts, pos = sc.prism.stamps, sc.prism.positions
    period = 1.0 / CFG.prism_rate
    assert np.all(np.diff(ts) > 0)
    # each stamp within the jitter of a nominal 19 Hz tick
    k = np.round((ts - ts[0]) / period)
    offsets = (ts - ts[0]) - k * period
    assert np.abs(offsets).max() <= 2 * CFG.prism_jitter + 1e-9
    assert offsets.std() > 0.3 * CFG.prism_jitter  # really jittered
    # dropouts and gaps: fewer samples than ticks, and at least one ≥ 0.5 s hole
    ticks = int(k[-1]) + 1
    assert 0.85 * ticks < ts.size < ticks
    assert np.diff(ts).max() > 0.5
    assert np.median(np.diff(ts)) == pytest.approx(period, abs=0.002)
    # covers the camera's time span
    assert ts[0] < sc.frame_times[0] and ts[-1] > sc.frame_times[-1]
    # mm noise about the lever-arm point of the true pose
    T = sc.map_T_base(ts)
    truth = (T[:, :3, :3] @ np.asarray(CFG.prism_lever_arm)) + T[:, :3, 3]
    err = pos - truth
    assert err.std(axis=0) == pytest.approx([CFG.prism_noise] * 3, rel=0.2)
    assert np.abs(err.mean(axis=0)).max() < 0.5e-3


def test_lever_arms_and_boresight(sc):
    np.testing.assert_allclose(sc.base_T_prism[:3, 3], CFG.prism_lever_arm)
    np.testing.assert_allclose(sc.base_T_prism[:3, :3], np.eye(3))
    np.testing.assert_allclose(sc.base_T_camera_nominal[:3, 3], CFG.camera_lever_arm)
    np.testing.assert_allclose(sc.base_T_camera_true[:3, 3], CFG.camera_lever_arm)
    np.testing.assert_allclose(sc.base_T_camera_nominal[:3, :3], np.eye(3))
    R = sc.base_T_camera_true[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    angle = math.degrees(math.acos((np.trace(R) - 1.0) / 2.0))
    assert angle == pytest.approx(CFG.boresight_deg, abs=1e-9)
    s5 = Scenario(dataclasses.replace(CFG, boresight_deg=0.5))
    R5 = s5.base_T_camera_true[:3, :3]
    assert math.degrees(math.acos((np.trace(R5) - 1.0) / 2.0)) == pytest.approx(0.5, abs=1e-9)


def test_placed_markers_are_seen_through_the_true_camera(sc):
    t = float(sc.frame_times[40])
    map_T_cam = sc.map_T_base(t) @ sc.base_T_camera_true
    placed = {m.id: m for m in sc.placed_markers(t)}
    assert sorted(placed) == sc.markers.ids
    for m in sc.markers:
        np.testing.assert_allclose(transform_points(map_T_cam, placed[m.id].center), m.position, atol=1e-9)
        normal_map = map_T_cam[:3, :3] @ placed[m.id].normal
        np.testing.assert_allclose(normal_map, sc.marker_normals[m.id], atol=1e-9)
    # through the nominal camera (the published tf) a point is rotated by the boresight error
    cam_nominal = invert_T(sc.map_T_base(t) @ sc.base_T_camera_nominal)
    R_err = sc.base_T_camera_nominal[:3, :3].T @ sc.base_T_camera_true[:3, :3]
    offs = []
    for m in sc.markers:
        seen_nominal = transform_points(cam_nominal, m.position)
        np.testing.assert_allclose(seen_nominal, R_err @ placed[m.id].center, atol=1e-9)
        offs.append(math.degrees(float(angle_between(seen_nominal, placed[m.id].center))))
    assert max(offs) <= CFG.boresight_deg + 1e-9
    assert max(offs) > 0.0


@pytest.mark.parametrize("preset", ["tiny", "ci", "easy", "demo", "realistic"])
def test_markers_around_the_track(preset):
    cfg = PRESETS[preset]
    s = Scenario(cfg)
    assert len(s.markers) >= 5
    ids = s.markers.ids
    assert len(set(ids)) == len(ids) and all(0 <= i < 50 for i in ids)
    (cx, cy), (a, b) = cfg.track_center, cfg.track_radii
    th = np.linspace(-math.pi, math.pi, 3600)
    loop = np.stack([cx + a * np.cos(th), cy + b * np.sin(th)], axis=1)
    start = s.map_T_base(cfg.start_time)[:3, 3]
    near_start = 0
    for m in s.markers:
        d = np.linalg.norm(loop - m.position[:2], axis=1)
        assert cfg.marker_distance[0] - 0.01 <= d.min() <= cfg.marker_distance[1] + 0.01
        assert cfg.marker_height[0] <= m.position[2] <= cfg.marker_height[1]
        assert m.size == cfg.marker_size
        n = s.marker_normals[m.id]
        assert np.linalg.norm(n) == pytest.approx(1.0)
        # facing the track: some of the loop lies within 60° of the face normal
        to_loop = np.c_[loop - m.position[:2], np.zeros(len(loop))]
        cos = (to_loop @ n) / np.linalg.norm(to_loop, axis=1)
        assert cos.max() > 0.5
        near_start += np.linalg.norm(m.position[:2] - start[:2]) <= max(cfg.marker_distance[0] + 1.0,
                                                                         0.6 * cfg.marker_distance[1]) + 0.01
    assert near_start >= 2  # visible during the standstill


def test_from_hidden_round_trip(sc, tmp_path):
    path = str(tmp_path / "hidden.yaml")
    sc.save_hidden(path)
    with open(path) as f:
        data = yaml.safe_load(f)
    assert data["config"]["seed"] == CFG.seed
    assert data["camera_time_offset"] == CFG.camera_time_offset
    assert data["boresight"]["angle_deg"] == CFG.boresight_deg
    assert data["vo_drift"]["yaw_drift_deg_per_min"] == CFG.vo_yaw_drift_deg_per_min
    back = Scenario.from_hidden(path)
    assert back.config == CFG
    t = sc.frame_times
    np.testing.assert_array_equal(back.odom_T_base(t), sc.odom_T_base(t))
    np.testing.assert_array_equal(back.prism.stamps, sc.prism.stamps)
    np.testing.assert_array_equal(back.base_T_camera_true, sc.base_T_camera_true)


def test_from_hidden_errors(sc, tmp_path):
    with pytest.raises(ScenarioError, match="cannot read"):
        Scenario.from_hidden(str(tmp_path / "missing.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("config: [1, 2\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        Scenario.from_hidden(str(bad))
    bad.write_text("markers: []\n")
    with pytest.raises(ScenarioError, match="config"):
        Scenario.from_hidden(str(bad))
    good = tmp_path / "h.yaml"
    sc.save_hidden(str(good))
    data = yaml.safe_load(good.read_text())
    data["config"]["warp_drive"] = 1
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="warp_drive"):
        Scenario.from_hidden(str(bad))
    data = yaml.safe_load(good.read_text())
    data["config"]["fps"] = -3.0
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="fps"):
        Scenario.from_hidden(str(bad))
    data = yaml.safe_load(good.read_text())
    first = next(iter(data["marker_normals"]))
    data["marker_normals"][first] = [0.0, 0.0, 1.0]
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="marker_normals"):
        Scenario.from_hidden(str(bad))


def test_calibration_spin_in_place():
    """A spin turns base_link once about its vertical in place, during the standstill, at its peak rate, and
    the platform then drives off forwards; the VO sees the turn; the rest of the world is the seed's."""
    cfg = dataclasses.replace(CFG, standstill=11.0, spin_deg=360.0, spin_rate_deg_per_s=60.0, spin_markers=4)
    sc, plain = Scenario(cfg), Scenario(dataclasses.replace(CFG, standstill=11.0))
    assert cfg.spin_time == pytest.approx(9.0)  # 1.5 · 360° / 60°/s: a smoothstep's peak is 1.5 × its mean
    dt = 0.01
    t = cfg.start_time + np.arange(0.0, cfg.standstill + 6.0, dt)
    T = sc.map_T_base(t)
    still = t - cfg.start_time <= cfg.standstill
    assert np.abs(T[still, :3, 3] - T[0, :3, 3]).max() < 1e-9  # in place
    yaw = np.unwrap(yaw_of(T[:, :3, :3]))
    rate = np.degrees(np.diff(yaw)) / dt
    assert rate.max() == pytest.approx(60.0, rel=0.01) and rate.min() > -0.5
    assert np.degrees(yaw[still][-1] - yaw[0]) == pytest.approx(360.0, abs=1e-6)
    spinning = (t[:-1] - cfg.start_time > cfg.spin_start + 0.1) & (t[:-1] - cfg.start_time < cfg.spin_start + 0.2)
    assert np.all(rate[spinning] > 0.0)
    assert np.all(rate[t[:-1] - cfg.start_time < cfg.spin_start] == 0.0)
    # after the spin: the very poses of the plain scenario (same loop, same heading, same roll and pitch)
    after = t - cfg.start_time > cfg.standstill
    np.testing.assert_allclose(T[after], plain.map_T_base(t[after]), atol=1e-9)
    # the VO turns with it, up to its yaw drift
    vo = np.unwrap(yaw_of(sc.odom_T_base(t)[:, :3, :3]))
    np.testing.assert_allclose(vo - vo[0] - (yaw - yaw[0]), sc.vo_yaw_error(t) - sc.vo_yaw_error(t[0]), atol=1e-6)
    # the map's markers are the plain scenario's, and 4 more around the start, 2 low and 2 high
    ids = set(sc.markers.ids) - set(plain.markers.ids)
    assert set(plain.markers.ids) < set(sc.markers.ids) and len(ids) == 4
    for i in plain.markers.ids:
        np.testing.assert_array_equal(sc.markers[i].position, plain.markers[i].position)
    eye = T[0, :3, 3] + np.array([0.0, 0.0, cfg.camera_lever_arm[2]])
    elevation = sorted(math.degrees(math.atan2(sc.markers[i].position[2] - eye[2],
                                               np.linalg.norm(sc.markers[i].position[:2] - eye[:2]))) for i in ids)
    assert elevation[0] < -12.0 and elevation[1] < -12.0 and elevation[2] > 35.0 and elevation[3] > 35.0
    for i in ids:  # each faces the camera at the start, 1.8-2.6 m away, off the track ahead
        to_eye = eye - sc.markers[i].position
        assert 1.8 <= np.linalg.norm(to_eye[:2]) <= 2.6
        off_track = wrap_angle(math.atan2(-to_eye[1], -to_eye[0]) - yaw[0])
        assert 40.0 <= abs(math.degrees(off_track)) <= 140.0
        assert float(np.dot(sc.marker_normals[i], to_eye / np.linalg.norm(to_eye))) == pytest.approx(1.0)
    # the calibration spin needs the standstill to hold it, in whole turns
    with pytest.raises(ScenarioError, match="spin_deg.*standstill of at least 10.0 s"):
        Scenario(dataclasses.replace(cfg, standstill=5.0))
    with pytest.raises(ScenarioError, match="spin_deg.*whole turns"):
        Scenario(dataclasses.replace(cfg, spin_deg=90.0))
    with pytest.raises(ScenarioError, match="spin_markers"):
        Scenario(dataclasses.replace(cfg, spin_markers=9))


@pytest.mark.parametrize("crab_deg, seed", [(2.0, 0), (-3.0, 5)])
def test_a_crabbing_platform_heads_off_its_direction_of_travel(crab_deg, seed):
    """``crab_deg``: base_link's heading is off its direction of travel by 0.4-1.0 × crab_deg (finite differences
    of the true track), the VO's yaw carries it too, and the prism track follows base_link as before."""
    cfg = dataclasses.replace(PRESETS["ci"], seed=seed, crab_deg=crab_deg)
    sc = Scenario(cfg)
    plain = Scenario(dataclasses.replace(cfg, crab_deg=0.0))
    t = cfg.start_time + np.linspace(cfg.standstill + cfg.accel_time, cfg.duration - 1.0, 40)
    h = 1e-3
    v = sc.map_T_base(t + h)[:, :2, 3] - sc.map_T_base(t - h)[:, :2, 3]
    crab = np.degrees(wrap_angle(yaw_of(sc.map_T_base(t)[:, :3, :3]) - np.arctan2(v[:, 1], v[:, 0])))
    assert np.all(np.abs(crab) >= 0.4 * abs(crab_deg) - 1e-6) and np.all(np.abs(crab) <= abs(crab_deg) + 1e-6)
    assert np.all(np.sign(crab) == np.sign(crab_deg)) and np.ptp(crab) > 0.1 * abs(crab_deg)
    np.testing.assert_allclose(sc.map_T_base(t)[:, :3, 3], plain.map_T_base(t)[:, :3, 3], atol=1e-12)
    vo_turn = np.degrees(wrap_angle(yaw_of(sc.odom_T_base(t)[:, :3, :3]) - yaw_of(plain.odom_T_base(t)[:, :3, :3])))
    np.testing.assert_allclose(vo_turn - vo_turn[0], crab - crab[0], atol=1e-6)


def test_the_written_map_is_the_survey():
    """``survey_noise``: the map written (``surveyed_markers``) is off the rendered truth by about that σ per
    axis, with that σ; without it the two are the same."""
    cfg = dataclasses.replace(PRESETS["ci"], n_markers=30, survey_noise=0.003)
    sc = Scenario(cfg)
    diff = np.array([sc.surveyed_markers[m.id].position - m.position for m in sc.markers])
    assert 0.002 < float(np.std(diff)) < 0.004 and np.abs(diff).max() < 0.015
    assert all(sc.surveyed_markers[m.id].sigma == 0.003 for m in sc.markers)
    exact = Scenario(dataclasses.replace(cfg, survey_noise=0.0))
    assert all(np.array_equal(exact.surveyed_markers[m.id].position, m.position) for m in exact.markers)

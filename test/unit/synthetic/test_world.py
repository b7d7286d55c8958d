"""synthetic/world.py and the realistic scenario options: the hall, the rolling shutter, the two lenses,
the camera clock, the wandering platform and the VO's tilt drift, each checked on rendered frames or
motion against geometry computed independently here (plain cv2.aruco, finite differences)."""
import dataclasses
import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.camera import Equirect
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario, ScenarioError
from aruco_abs_orient.synthetic.world import render_frame
from aruco_abs_orient.transforms import invert_T, transform_points

_PARAMS = cv2.aruco.DetectorParameters()
_PARAMS.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
DETECTOR = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), _PARAMS)

# a fast turn: 3 m/s on the tiny loop (yaw rate up to ~1.2 rad/s), markers high above the camera
FAST = dataclasses.replace(PRESETS["tiny"], width=1920, speed=3.0, profile="clean", marker_height=(2.6, 3.6),
                           marker_distance=(2.0, 4.0), seed=4)


def detect(image):
    corners, ids, _ = DETECTOR.detectMarkers(image)
    return {} if ids is None else {int(i): c.reshape(4, 2).mean(axis=0) for i, c in zip(ids.ravel(), corners)}


def projected(scenario, marker_id, t, eq):
    """Pixel (u, v) of a marker's centre seen by the true camera at true time t."""
    p = transform_points(invert_T(scenario.map_T_camera(t)), scenario.markers[marker_id].position)
    return np.array(eq.bearing_to_pixel(p), dtype=float)


def test_rolling_shutter_shifts_each_marker_by_its_rows_capture_time():
    """40 ms readout while turning fast: each marker moves (against the global-shutter frame) by what the
    camera turned between the frame's stamp and the capture time of the marker's row,
    t + (v/H − ½)·readout — a few pixels for markers far above the middle row."""
    readout = 0.040
    global_sc = Scenario(FAST)
    rolling_sc = Scenario(dataclasses.replace(FAST, rolling_shutter_readout=readout))
    eq = Equirect(FAST.width, FAST.width // 2)
    checked = []
    for index in (52, 55, 58, 61):
        t = float(global_sc.frame_times[index])
        seen_g = detect(render_frame(global_sc, index))
        seen_r = detect(render_frame(rolling_sc, index))
        for mid in set(seen_g) & set(seen_r):
            u0, v0 = projected(global_sc, mid, t, eq)
            t_row = t + (v0 / eq.height - 0.5) * readout
            u1, _ = projected(global_sc, mid, t_row, eq)
            expected = (u1 - u0 + eq.width / 2) % eq.width - eq.width / 2
            measured = (seen_r[mid][0] - seen_g[mid][0] + eq.width / 2) % eq.width - eq.width / 2
            checked.append((expected, measured))
    checked = np.array(checked)
    assert len(checked) >= 4, checked
    assert np.abs(checked[:, 0]).max() > 2.0, checked  # the effect is visible at all
    np.testing.assert_allclose(checked[:, 1], checked[:, 0], atol=0.35)


def test_row_times_convention():
    """The middle row is captured at the frame's time; row v at t + (v/H − ½)·readout."""
    sc = Scenario(dataclasses.replace(FAST, rolling_shutter_readout=0.03))
    rows = sc.row_times(100.0, 960)
    assert rows[480] == pytest.approx(100.0)
    assert rows[0] == pytest.approx(100.0 - 0.015)
    assert rows[-1] - rows[0] == pytest.approx(0.03 * 959 / 960)
    hidden = sc.hidden()["realism"]["rolling_shutter"]
    assert hidden["readout_s"] == 0.03 and "(v / H - 1/2)" in hidden["convention"]


def test_two_lenses_rendered_where_the_lens_model_puts_them():
    """Two lenses 3 cm off centre, the back one turned 0.3° against the front, stitched at 2 m: the markers
    detected in the rendered frames (the package's whole-frame search, nothing of the model) sit where
    ``DualFisheye.project`` puts them, and visibly off where a single centre would (0.1-0.9°)."""
    from aruco_abs_orient.synthetic.feed import marker_observations
    from aruco_abs_orient.tracking import MarkerTracker

    base = dataclasses.replace(PRESETS["tiny"], width=1920, profile="clean", seed=2, marker_distance=(1.0, 3.0))
    dual = Scenario(dataclasses.replace(base, lens_offset=0.03, lens_rotation_deg=0.3, stitch_distance=2.0))
    single = Scenario(base)
    tracker = MarkerTracker(dual.markers)
    frames = list(range(0, len(dual.frame_times), 8))
    seen = marker_observations(dual, dual.frame_times[frames])
    one = marker_observations(single, single.frame_times[frames])
    errors, parallax = [], []
    for k, index in enumerate(frames):
        for o in tracker.process(render_frame(dual, index), None).observations:
            pick = (seen.frame == k) & (seen.ids == o.id)
            if pick.any():
                errors.append(math.degrees(float(np.arccos(np.clip(o.centre @ seen.bearings[pick][0], -1, 1)))))
                parallax.append(math.degrees(float(np.arccos(np.clip(seen.bearings[pick][0] @ one.bearings[
                    (one.frame == k) & (one.ids == o.id)][0], -1, 1)))))
    errors, parallax = np.array(errors), np.array(parallax)
    assert len(errors) >= 20, len(errors)
    assert np.median(errors) < 0.03 and np.percentile(errors, 90) < 0.08, np.round(np.sort(errors), 3)
    assert np.median(parallax) > 0.1 and np.median(parallax) > 5 * np.median(errors), np.round(parallax, 3)


def test_a_marker_across_the_seam_is_where_its_corners_put_it():
    """Two lenses 3 cm off centre, stitched at infinity: a marker across a seam between the lenses is imaged
    corner by corner through both, so its detected centre is not either lens's image of the centre point
    (off by 0.5-1.4° at 1-3 m) but where ``DualFisheye.project_marker`` puts it from the four corners (the
    rendered frames: the package's whole-frame search, nothing of the model), and the ray back from its
    detected corners passes through it."""
    from aruco_abs_orient.markers import square_corners
    from aruco_abs_orient.tracking import MarkerTracker

    centre_model, corner_model, lens_ray, marker_ray = [], [], [], []

    def off_ray(origins, directions, point):     # degrees between a ray and the direction to the point from its origin
        v = point - origins[0]
        return math.degrees(float(np.arccos(np.clip(v @ directions[0] / np.linalg.norm(v), -1, 1))))

    for seed in (2, 3, 5):
        cfg = dataclasses.replace(PRESETS["tiny"], width=1920, profile="clean", seed=seed, marker_distance=(1.0, 3.0),
                                  lens_offset=0.03)
        sc = Scenario(cfg)
        tracker = MarkerTracker(sc.markers)
        for index in range(0, len(sc.frame_times), 2):
            camera_T_map = invert_T(sc.map_T_camera(sc.frame_times[index]))
            for o in tracker.process(render_frame(sc, index), None).observations:
                m = next(m for m in sc.markers if m.id == o.id)
                centre = transform_points(camera_T_map, m.position)
                corners = transform_points(camera_T_map, m.position + square_corners(m.size, sc.marker_normals[m.id]))
                weights = sc.lenses.front_weight(sc.lenses.project(corners))
                if weights.min() < 0.5 < weights.max():          # the corners on both sides of a seam
                    centre_model.append(math.degrees(float(np.arccos(np.clip(o.centre @ sc.lenses.project(centre),
                                                                             -1, 1)))))
                    corner_model.append(math.degrees(float(np.arccos(np.clip(
                        o.centre @ sc.lenses.project_marker(centre, corners), -1, 1)))))
                    lens_ray.append(off_ray(*sc.lenses.rays(o.centre[None]), centre))
                    marker_ray.append(off_ray(*sc.lenses.marker_rays(o.centre[None], o.corners[None]), centre))
    assert len(corner_model) >= 8, len(corner_model)
    assert np.median(centre_model) > 0.3, np.round(centre_model, 3)
    assert np.median(corner_model) < 0.05 and max(corner_model) < 0.2, np.round(corner_model, 3)
    # and back: the ray the solvers take for such a marker (DualFisheye.marker_rays, from its detected corners)
    # passes through it, where the ray of the lens that dominates at its centre does not
    assert np.median(lens_ray) > 0.3 and np.median(marker_ray) < 0.08, (np.round(lens_ray, 3), np.round(marker_ray, 3))


def test_camera_clock_rate_error():
    """A camera clock 500 ppm fast: frames every 1/fps of its clock, so in true time every 1/(fps·1.0005);
    the stamp runs ahead of true time by offset + 500e-6 · elapsed."""
    cfg = dataclasses.replace(PRESETS["tiny"], clock_rate_error_ppm=500.0)
    sc = Scenario(cfg)
    np.testing.assert_allclose(np.diff(sc.camera_stamps), 1.0 / cfg.fps, rtol=2e-5)  # stamps ~1.7e9 s
    np.testing.assert_allclose(np.diff(sc.frame_times), 1.0 / cfg.fps / 1.0005, rtol=2e-5)
    lead = sc.camera_stamps - sc.frame_times
    assert lead[-1] - lead[0] == pytest.approx(500e-6 * (sc.frame_times[-1] - sc.frame_times[0]), rel=1e-4)
    np.testing.assert_allclose(sc.true_time(sc.camera_stamps), sc.frame_times, rtol=0, atol=1e-6)


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 500), st.floats(5.0, 60.0))
def test_wander_and_non_holonomic_heading(seed, when):
    """Off the loop by at most ±lateral_wander, and heading along the path's direction of travel."""
    cfg = dataclasses.replace(PRESETS["realistic"], seed=seed, duration=60.0)
    sc = Scenario(cfg)
    t = cfg.start_time + when
    T = sc.map_T_base(np.array([t - 1e-3, t, t + 1e-3]))
    v = T[2, :2, 3] - T[0, :2, 3]
    heading = math.atan2(T[1, 1, 0], T[1, 0, 0])
    assert abs((math.atan2(v[1], v[0]) - heading + math.pi) % (2 * math.pi) - math.pi) < 2e-4
    on_loop = sc._track_point(sc._theta_at(t))
    assert np.linalg.norm(T[1, :2, 3] - on_loop[:2]) <= cfg.lateral_wander + 1e-9


def test_vo_tilt_drift_grows_at_its_rate():
    cfg = dataclasses.replace(PRESETS["realistic"], vo_tilt_drift_deg_per_min=2.0, duration=60.0, odom_levelled=True)
    sc = Scenario(cfg)
    for dt in (0.0, 30.0, 60.0):
        t = cfg.start_time + dt
        R_vo = sc.odom_T_base(t)[:3, :3]
        R_true = sc.map_T_base(t)[:3, :3]
        up = (R_vo @ R_true.T)[2, 2]  # odom's vertical seen from map: the VO's yaw error cannot tilt it
        tilt = math.degrees(math.acos(np.clip(up, -1, 1)))
        assert tilt == pytest.approx(2.0 * dt / 60.0, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 3])
def test_an_unlevelled_odom_starts_at_base_link_and_stays_tilted(seed):
    """``odom_levelled=False`` (a VO without gravity): odom is base_link's starting pose, its roll and pitch
    included, so odom stays tilted against map by base_link's starting tilt; base_link's attitude in odom and
    the true one differ by that tilt (plus the VO's yaw error), not by the platform's own tilt later on."""
    cfg = dataclasses.replace(PRESETS["ci"], seed=seed, roll_pitch_deg=1.5, odom_levelled=False)
    sc = Scenario(cfg)
    t0 = cfg.start_time
    assert np.allclose(sc.odom_T_base(t0)[:3, :3], np.eye(3), atol=1e-12)
    start_tilt = math.degrees(math.acos(sc.map_T_base(t0)[2, 2]))
    assert start_tilt > 0.05
    for t in t0 + np.array([5.0, 12.0, 19.0]):
        map_R_odom = sc.map_T_base(t)[:3, :3] @ sc.odom_T_base(t)[:3, :3].T
        assert math.degrees(math.acos(np.clip(map_R_odom[2, 2], -1, 1))) == pytest.approx(start_tilt, abs=1e-9)


def test_hall_frame_markers_where_they_are_and_no_false_ids():
    """A hall frame (posters, checkers, lights, pillars, exposure changes, blur, noise; 1920 px, 45 cm markers):
    plain OpenCV finds only map ids, each at the projection of that marker's centre, and at least two."""
    cfg = dataclasses.replace(PRESETS["realistic"], width=1920, marker_size=0.45, marker_distance=(2.0, 6.0),
                              duration=8.0, fps=10.0)
    sc = Scenario(cfg)
    eq = Equirect(1920, 960)
    found = 0
    for index in (5, 40, 70):
        seen = detect(render_frame(sc, index))
        for mid, centre in seen.items():
            assert mid in sc.markers.ids, (index, mid)
            u, v = projected(sc, mid, float(sc.frame_times[index]), eq)
            assert math.hypot((centre[0] - u + 960) % 1920 - 960, centre[1] - v) < 2.0, (index, mid)
        found += len(seen)
    assert found >= 2


def test_hall_pillars_drawn_where_they_stand():
    """The frame with the hall's pillars differs from the same frame without them at the nearest pillar's
    axis (camera height) and not three radii beside it."""
    cfg = dataclasses.replace(PRESETS["realistic"], width=1920, duration=8.0, fps=10.0)
    sc = Scenario(cfg)
    eq = Equirect(1920, 960)
    t = float(sc.frame_times[0])
    with_pillars = render_frame(sc, 0).astype(float)
    pillars = sc.world.pillars.copy()
    sc.world.pillars = pillars[:0]
    without = render_frame(sc, 0).astype(float)
    camera_T_map = invert_T(sc.map_T_camera(t))
    eye = sc.map_T_camera(t)[:3, 3]
    px, py, r = pillars[np.argmin(np.hypot(pillars[:, 0] - eye[0], pillars[:, 1] - eye[1]))]
    side = np.array([-(py - eye[1]), px - eye[0], 0.0]) / math.hypot(px - eye[0], py - eye[1])
    for point, drawn in ((np.array([px, py, eye[2]]), True), (np.array([px, py, eye[2]]) + 3 * r * side, False)):
        u, v = (int(round(float(x))) for x in eq.bearing_to_pixel(transform_points(camera_T_map, point)))
        diff = np.abs(with_pillars[v - 2:v + 3, (u + np.arange(-2, 3)) % 1920]
                      - without[v - 2:v + 3, (u + np.arange(-2, 3)) % 1920]).max()
        assert (diff > 3.0) == drawn, (point, diff)


def test_hidden_yaml_rebuilds_the_realistic_scenario(tmp_path):
    sc = Scenario(dataclasses.replace(PRESETS["realistic-rs"], duration=4.0))
    path = str(tmp_path / "hidden.yaml")
    sc.save_hidden(path)
    again = Scenario.from_hidden(path)
    assert again.config == sc.config
    np.testing.assert_allclose(again.world.pillars, sc.world.pillars)
    import yaml

    with open(path) as f:
        realism = yaml.safe_load(f)["realism"]
    assert realism["rolling_shutter"]["readout_s"] == 0.03
    assert realism["camera_clock"]["rate_error_ppm"] == 20.0
    assert len(realism["hall"]["pillars_x_y_radius_m"]) == len(sc.world.pillars) > 0
    assert realism["camera_lenses"]["lens_offset_m"] == 0.01 and realism["exposure"]["time_s"] > 0
    assert len(realism["camera_lenses"]["back_lens_rotation_deg"]) == 3


@pytest.mark.parametrize("field, value", [("world", "cave"), ("rolling_shutter_readout", 0.05),
                                          ("lateral_wander", -0.01), ("jpeg_quality", 101)])
def test_bad_realism_parameters_named(field, value):
    with pytest.raises(ScenarioError, match=field):
        dataclasses.replace(PRESETS["realistic"], **{field: value}).validate()

"""pipeline.py and framesolve.py against hand-checked numbers: each gate of a frame (no prism, range, elevation,
tracking, fusion), ``update_params`` and ``reset``.

The world is built here: base_link at map (1, 2, 0) with yaw 0.3 rad, level; the camera 0.5 m and the
prism 1.0 m above base_link; markers at known map positions. Bearings are exact (the camera frame's
direction to each marker), so every accepted yaw is 0.3 rad to rounding, and a marker the test moved
in the map is one whose disagreement the test knows.
"""
import math

import numpy as np
import pytest

from aruco_abs_orient.detection import DetectionError, MarkerObservation
from aruco_abs_orient.markers import Marker, MarkerMap
from aruco_abs_orient.pipeline import AbsOrientPipeline, PipelineError, PipelineParams
from aruco_abs_orient.tracking import TrackingParams
from aruco_abs_orient.transforms import make_T, rpy_to_matrix

YAW = 0.3
BASE = np.array([1.0, 2.0, 0.0])
BASE_T_CAMERA = make_T(np.eye(3), [0.0, 0.0, 0.5])
BASE_T_PRISM = make_T(np.eye(3), [0.0, 0.0, 1.0])
MAP_T_BASE = make_T(rpy_to_matrix(0.0, 0.0, YAW), BASE)
ODOM_T_BASE = make_T(rpy_to_matrix(0.0, 0.0, -0.2), [5.0, -1.0, 0.0])  # odometry's own yaw and origin
PRISM = BASE + np.array([0.0, 0.0, 1.0])
#: id → map position: four markers around the base at 3–5 m and different heights
MARKERS = {0: [4.0, 2.0, 1.2], 1: [1.0, 6.0, 0.8], 2: [-2.0, 1.0, 1.5], 3: [1.5, -2.0, 0.3]}


# --------------------------------------------------------------------------- frames and gates

def bearing_to(position) -> np.ndarray:
    """The exact camera-frame unit bearing of a map point seen from the world's camera."""
    map_T_camera = MAP_T_BASE @ BASE_T_CAMERA
    d = map_T_camera[:3, :3].T @ (np.asarray(position, dtype=float) - map_T_camera[:3, 3])
    return d / np.linalg.norm(d)


def observation(marker_id: int, seen_at=None, sigma: float = 1e-4) -> MarkerObservation:
    """Marker ``marker_id`` seen where it is (or at map point ``seen_at``: a marker moved since the survey)."""
    b = bearing_to(MARKERS[marker_id] if seen_at is None else seen_at)
    return MarkerObservation(marker_id, np.zeros((4, 3)), b, (0.0, 0.0), np.zeros((4, 2)), 0.1, sigma, "full")


def pipeline(**params) -> AbsOrientPipeline:
    mm = MarkerMap([Marker(i, np.array(p, dtype=float), 0.19, 0.002) for i, p in MARKERS.items()])
    pipe = AbsOrientPipeline(mm, BASE_T_CAMERA, BASE_T_PRISM, PipelineParams(**params))
    for t in np.arange(0.0, 3.01, 0.1):  # the prism holds still at its place
        pipe.add_prism(float(t), PRISM)
    return pipe


def reasons(res):
    return {r.id: r.reason for r in res.observations}


def test_consistent_markers_give_the_true_yaw_and_initialise_the_filter():
    pipe = pipeline()
    for t in (1.0, 1.1, 1.2):
        res = pipe.process_observations(t, [observation(i) for i in MARKERS], ODOM_T_BASE)
        assert all(r.reason == "" or r.reason.startswith("filter:") for r in res.observations)
        assert [r.yaw for r in res.observations] == pytest.approx([YAW] * 4, abs=1e-9)
        assert [r.range for r in res.observations] == pytest.approx(
            [np.linalg.norm(np.array(MARKERS[i]) - BASE - [0, 0, 0.5]) for i in MARKERS])
        assert res.fused_yaw == pytest.approx(YAW, abs=1e-9)
    assert res.initialised and res.yaw == pytest.approx(YAW, abs=1e-6)
    assert np.allclose(res.map_T_base[:3, 3], BASE, atol=1e-9)  # the prism minus the lever arm
    assert all(r.accepted for r in res.observations)
    # map_T_odom takes odometry's pose onto the truth
    assert np.allclose(res.map_T_odom @ ODOM_T_BASE, MAP_T_BASE, atol=1e-6)


def test_no_prism_position_means_no_yaw():
    pipe = pipeline()
    res = pipe.process_observations(10.0, [observation(0)], ODOM_T_BASE)  # 7 s after the last prism sample
    assert list(reasons(res)) == [0] and reasons(res)[0].startswith("no prism position, and a resection needs")
    assert pipe.stats["no_prism"] == 1
    assert res.fused_yaw is None


def test_a_marker_nearer_than_min_range_is_a_geometry_rejection():
    pipe = pipeline(min_range=3.2)  # marker 0 is 3.08 m from the camera, the others 3.32–4.04 m
    res = pipe.process_observations(1.0, [observation(i) for i in MARKERS], ODOM_T_BASE)
    assert reasons(res)[0].startswith("geometry:") and pipe.stats["degenerate"] == 1
    assert all(reasons(res)[i] == "" or reasons(res)[i].startswith("filter:") for i in (1, 2, 3))


def test_elevation_gate_rejects_a_marker_moved_up_and_update_params_opens_it():
    moved = np.array(MARKERS[1]) + [0.0, 0.0, 0.5]  # 0.5 m higher at 4 m: ~7° of elevation
    pipe = pipeline()
    res = pipe.process_observations(1.0, [observation(0), observation(1, seen_at=moved)], ODOM_T_BASE)
    assert reasons(res)[1] == "elevation disagrees with the map (wrong id or moved marker)"
    assert pipe.stats["rejected_elevation"] == 1
    pipe.update_params(elevation_gate=100.0)   # the widest
    res = pipe.process_observations(1.1, [observation(0), observation(1, seen_at=moved)], ODOM_T_BASE)
    assert "elevation" not in reasons(res)[1] and pipe.stats["rejected_elevation"] == 1


def test_fusion_gate_leaves_out_the_marker_that_disagrees_with_the_others():
    # marker 2 seen 5° off in azimuth around the camera (same range and height): its yaw is 5° off
    cam = BASE + [0.0, 0.0, 0.5]
    rel = np.array(MARKERS[2]) - cam
    turned = cam + rpy_to_matrix(0.0, 0.0, math.radians(5.0)) @ rel
    pipe = pipeline()
    res = pipe.process_observations(1.0, [observation(0), observation(1), observation(3),
                                          observation(2, seen_at=turned)], ODOM_T_BASE)
    yaws = {r.id: r.yaw for r in res.observations}
    assert yaws[2] == pytest.approx(YAW - math.radians(5.0), abs=1e-6)
    assert reasons(res)[2] == "disagrees with the other markers of the frame"
    assert pipe.stats["rejected_fusion"] == 1
    assert res.fused_yaw == pytest.approx(YAW, abs=1e-9)
    # two markers (no consensus step): the gate drops one of them; the widest gate (100 σ) keeps both, and the
    # fused yaw lies between theirs
    pair = [observation(0), observation(2, seen_at=turned)]
    res = pipeline().process_observations(1.0, pair, ODOM_T_BASE)
    assert sum(r.reason == "disagrees with the other markers of the frame" for r in res.observations) == 1
    pipe = pipeline()
    pipe.update_params(fusion_gate=100.0)   # the widest
    res = pipe.process_observations(1.0, pair, ODOM_T_BASE)
    assert all(r.reason != "disagrees with the other markers of the frame" for r in res.observations)
    assert YAW - math.radians(5.0) + 1e-3 < res.fused_yaw < YAW - 1e-3


def test_tracking_gate_reports_the_yaw_but_does_not_use_it():
    pipe = pipeline()
    res = pipe.process_observations(1.0, [observation(0)], ODOM_T_BASE, gated=[observation(1)])
    r = {o.id: o for o in res.observations}
    assert r[1].reason.startswith("tracking gate") and r[1].yaw == pytest.approx(YAW, abs=1e-9)
    assert not r[1].accepted and res.fused_yaw == pytest.approx(YAW, abs=1e-9)


def test_init_search_interval_searches_every_nth_frame_before_the_filter_starts():
    pipe = pipeline(init_search_interval=3)
    blank = np.zeros((32, 64), np.uint8)  # a valid 2:1 frame without markers
    for k in range(7):
        pipe.process_image(1.0 + 0.01 * k, blank, ODOM_T_BASE)
    assert pipe.stats["frames"] == 7 and pipe.stats["skipped_before_init"] == 4  # frames 1, 4, 7 searched


# --------------------------------------------------------------------------- update_params and reset

def test_update_params_routes_each_name_to_its_group_and_validates():
    pipe = pipeline()
    tracker = pipe.tracker
    pipe.update_params(prism_sigma=0.01, gate_deg=2.5, gate_chi2_yaw=20.0)
    assert pipe.params.prism_sigma == 0.01
    assert pipe.tracking_params.gate_deg == 2.5 and pipe.tracker is not tracker  # a tracker with the new params
    assert pipe.tracker.params.gate_deg == 2.5
    pipe.update_params(pole_band_deg=60.0)  # a detection knob: the tracker's detector gets it, tracking kept
    assert pipe.tracker.detector.params.pole_band_deg == 60.0 and pipe.tracker.params.gate_deg == 2.5
    with pytest.raises(DetectionError, match="pole_band_deg"):
        pipe.update_params(pole_band_deg=95.0, gate_deg=3.0)
    assert pipe.tracking_params.gate_deg == 2.5  # a refused detection change leaves tracking alone too
    assert pipe.filter_params.gate_chi2_yaw == 20.0 and pipe.filter.params.gate_chi2_yaw == 20.0
    with pytest.raises(PipelineError, match="'no_such_knob'"):
        pipe.update_params(no_such_knob=1.0)
    with pytest.raises(PipelineError, match="prism_max_gap"):
        pipe.update_params(prism_max_gap=-1.0)
    assert pipe.params.prism_max_gap == PipelineParams().prism_max_gap  # a refused change changes nothing
    assert TrackingParams().gate_deg != 2.5  # the defaults are untouched


def test_reset_forgets_the_filter_the_tracker_and_the_prism():
    pipe = pipeline()
    for t in (1.0, 1.1, 1.2):
        res = pipe.process_observations(t, [observation(i) for i in MARKERS], ODOM_T_BASE)
    assert res.initialised
    tracker = pipe.tracker
    pipe.reset()
    assert not pipe.filter.initialised and pipe.tracker is not tracker and pipe.stats["resets"] == 1
    assert pipe.prism.at(1.0, 1.0, 1.0) is None
    res = pipe.process_observations(1.3, [observation(0)], ODOM_T_BASE)
    assert list(reasons(res)) == [0] and reasons(res)[0].startswith("no prism position")


def test_a_prism_position_with_the_instruments_covariance_is_used_with_it():
    """A position given with its covariance (the driver's ms60/prism_with_covariance) is weighed with it, not with
    prism_sigma: base_link's position covariance is the larger of the two samples around the frame; a bad
    covariance is refused and counted; samples without one fall back to prism_sigma."""
    far = np.diag([0.0005, 0.003, 0.0005]) ** 2      # 100 m north of the instrument: 3 mm along, 0.5 mm across
    pipe = AbsOrientPipeline(MarkerMap([Marker(i, np.array(p, dtype=float), 0.19, 0.002) for i, p in MARKERS.items()]),
                             BASE_T_CAMERA, BASE_T_PRISM, PipelineParams())
    for t in np.arange(0.0, 3.01, 0.1):
        pipe.add_prism(float(t), PRISM, far)
    pipe.add_prism(3.05, PRISM, np.full((3, 3), np.nan))
    assert pipe.stats["bad_prism"] == 1
    for t in (1.0, 1.1, 1.2):
        res = pipe.process_observations(t, [observation(i) for i in MARKERS], ODOM_T_BASE)
    assert res.initialised and np.array_equal(res.base_position_cov, far) and np.array_equal(res.prism_cov, far)
    res = pipeline().process_observations(1.0, [observation(i) for i in MARKERS], ODOM_T_BASE)
    assert np.allclose(res.prism_cov, np.eye(3) * PipelineParams().prism_sigma ** 2)

"""Rolling shutter (issue 17): each observation at its row's capture time, stamp + (v/H − ½)·readout.

Truth: the generator's scenario (``synthetic.feed`` solves each marker's bearing at its own row time
from the true camera poses); the pipeline sees only the bearings, the odometry at the frame stamps and
the prism track.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.camera import Equirect
from aruco_abs_orient.pipeline import AbsOrientPipeline, PipelineError, row_fraction
from aruco_abs_orient.synthetic.feed import feed, marker_observations
from aruco_abs_orient.synthetic.scenario import Scenario, ScenarioConfig
from aruco_abs_orient.transforms import wrap_angle, yaw_of

# a tight loop (up to ~20°/s of yaw) with markers above and below the camera
TURNING = ScenarioConfig(duration=20.0, fps=30.0, width=3840, standstill=1.0, accel_time=1.0, n_markers=10,
                         marker_size=0.19, marker_distance=(1.5, 6.0), marker_height=(0.0, 2.5),
                         track_radii=(4.0, 2.5), boresight_deg=0.0, prism_noise=0.0, prism_jitter=0.0,
                         vo_yaw_walk_deg_per_sqrt_s=0.0)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 3839.0), st.floats(0.0, 1919.0), st.sampled_from([960, 1920]))
def test_row_fraction_is_the_pixel_row(u, v, height):
    """Bearing of pixel (u, v) → (v/H − ½) of that very row, through camera.Equirect's model."""
    u = u * height / 1920
    v = v * height / 1920
    b = Equirect(2 * height, height).pixel_to_bearing(u, v)
    assert row_fraction(b, height) == pytest.approx(v / height - 0.5, abs=1e-9)


def test_row_fraction_hand_checked():
    """The horizon is row H/2 − ½ (just above the middle), straight up the top edge, down the bottom."""
    H = 1920
    f = row_fraction(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), H)
    assert f == pytest.approx([-0.5 / H, -0.5 - 0.5 / H, 0.5 - 0.5 / H])
    with pytest.raises(PipelineError, match="height"):
        row_fraction(np.array([1.0, 0.0, 0.0]), 0)


def test_feed_bearings_are_at_their_row_times():
    """feed's bearing of each marker is the scenario's exact bearing at stamp + row·readout."""
    sc = Scenario(TURNING)
    times = sc.frame_times[60:90]
    ob = marker_observations(sc, times, readout=0.03)
    t_row = times[ob.frame] + ob.rows * 0.03
    k, ids, u = sc.marker_bearings(t_row)
    same = ids == ob.ids[k]
    assert same.sum() >= 0.95 * len(ob.ids)
    assert np.max(np.linalg.norm(u[same] - ob.bearings[k[same]], axis=1)) < 1e-7
    # and not at the frame stamp: the shutter moved them
    k0, ids0, u0 = sc.marker_bearings(times[ob.frame])
    moved = np.linalg.norm(u0[ids0 == ob.ids[k0]] - ob.bearings[k0[ids0 == ob.ids[k0]]], axis=1)
    assert np.max(moved) > 1e-4


def _yaw_errors(readout_camera: float, readout_pipeline: float) -> np.ndarray:
    sc = Scenario(TURNING)
    pipe = AbsOrientPipeline(sc.markers, sc.base_T_camera_nominal, sc.base_T_prism, readout=readout_pipeline)
    errs = []
    for t, res in feed(sc, pipe, noise=0.0, readout=readout_camera):
        if res.prism_position is None:  # a prism gap: the frame's resection (global-shutter geometry) gave its yaws
            continue
        truth = yaw_of(sc.map_T_base(t)[:3, :3])
        for r in res.observations:
            if math.isfinite(r.yaw) and t > sc.frame_times[0] + 3.0:
                errs.append(float(wrap_angle(r.yaw - truth)))
    return np.abs(np.array(errs))


def test_pipeline_removes_the_rolling_shutter_error():
    """A 30 ms readout in a tight loop: the per-marker yaws (referred to the frame stamp) are wrong by up to
    a few hundredths of a degree when the pipeline ignores it, and back to the global-shutter level
    with the readout given."""
    ignored = _yaw_errors(0.03, 0.0)
    corrected = _yaw_errors(0.03, 0.03)
    level = _yaw_errors(0.0, 0.0)
    assert np.percentile(ignored, 95) > 3 * np.percentile(level, 95)
    assert np.percentile(corrected, 95) < 1.5 * np.percentile(level, 95) + math.radians(0.002)


def test_readout_needs_the_image_height_and_is_validated():
    sc = Scenario(replace(TURNING, duration=2.0))
    with pytest.raises(PipelineError, match="readout"):
        AbsOrientPipeline(sc.markers, sc.base_T_camera_nominal, sc.base_T_prism, readout=-0.01)
    pipe = AbsOrientPipeline(sc.markers, sc.base_T_camera_nominal, sc.base_T_prism, readout=0.03)
    with pytest.raises(PipelineError, match="image_height"):
        pipe.process_observations(float(sc.frame_times[0]), [], sc.odom_T_base(float(sc.frame_times[0])))

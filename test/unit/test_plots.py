"""plots: each picture's title is its answer, computed from hand-made inputs whose answer is known; the files
are real PNGs of the documented size, read back (size from the IHDR chunk, the title from the Title chunk).

A fraction of a second per plot (matplotlib's Agg); matplotlib 3.1's API (test_noetic runs this file there)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from aruco_abs_orient.calibration import Calibration
from aruco_abs_orient.camera import DualFisheye, azel_to_bearing
from aruco_abs_orient.evaluation import error_by_frame_position, marker_agreement, pairwise_differences, yaw_ape
from aruco_abs_orient.plots import (
    WIDTH,
    HeadingCurve,
    Span,
    calibration_answer,
    mounting_turn,
    plot_calibration,
    plot_frame_position,
    plot_heading_error,
    plot_marker_agreement,
    plot_time_offset,
    png_title,
)
from aruco_abs_orient.timesync import OffsetEstimate
from aruco_abs_orient.transforms import rot_z

rad = math.radians


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def estimate(offset, sigma, method="coherence"):
    taus = np.linspace(offset - 1.0, offset + 1.0, 201)
    return OffsetEstimate(offset=offset, sigma=sigma, confidence=0.5, coherence=0.999, taus=taus,
                          curve=1.0 - 0.01 * (taus - offset) ** 2, method=method, n_samples=900, overlap=20.0)


def test_the_time_offset_title_says_whether_the_offset_in_use_is_right(tmp_path):
    coarse, refined = estimate(0.333, 0.013), estimate(0.3677, 0.0002, "marker bearings")
    offsets = refined.offset + np.linspace(-0.06, 0.06, 13)
    cost = (offsets, rad(0.02) + rad(3.0) * (offsets - refined.offset) ** 2)
    path = str(tmp_path / "sync.png")
    plot_time_offset(path, coarse, refined, cost, baseline=estimate(0.367, 0.0167, "xcorr"))
    assert png_title(path) == "time offset 367.7 ± 0.2 ms: the marker bearings agree best there"
    assert png_size(path) == (WIDTH, 680)
    plot_time_offset(path, coarse, refined, cost, in_use=0.3177)
    assert png_title(path) == ("time offset in use 317.7 ms is -50.0 ms off: the marker bearings agree best at "
                               "367.7 ± 0.2 ms")
    plot_time_offset(path, coarse, refined, cost, in_use=0.3679)             # within 3σ (and 0.5 ms)
    assert png_title(path) == "time offset in use 367.9 ms: the marker bearings agree best there (367.7 ± 0.2 ms)"
    plot_time_offset(path, coarse)                                           # no marker bearings: the coarse one
    assert png_title(path).startswith("time offset 333.0 ± 13.0 ms: where the VO heading follows the prism track best")
    assert "timesync --markers" in png_title(path)


def test_the_markers_title_names_the_marker_that_disagrees(tmp_path):
    t = np.repeat(np.arange(30.0), 3)
    ids = np.tile([4, 9, 17], 30)
    dev = np.radians(np.where(ids == 9, -0.8, 0.0) + np.tile([0.03, -0.03], 45))
    accepted = ids != 9
    reasons = np.where(accepted, "", "tracking gate: far from its predicted bearing (moved marker, or the filter "
                                     "is off)")
    series = {m: (t[ids == m], np.radians(np.where(ids == m, dev, 0.0)[ids == m])) for m in (4, 9, 17)}
    path = str(tmp_path / "markers.png")
    plot_marker_agreement(path, marker_agreement(t, ids, dev, accepted, reasons), pairwise_differences(series))
    assert png_title(path) == ("marker 9 disagrees with the others by -0.800° (their typical spread 0.044°): moved, or "
                               "surveyed wrong")
    assert png_size(path)[0] == WIDTH
    good = np.radians(np.tile([0.03, -0.03], 45))
    plot_marker_agreement(path, marker_agreement(t, ids, good, np.ones(len(t), dtype=bool)))
    assert png_title(path) == ("the markers agree: every marker's median within 0.000° of the consensus, typical "
                               "spread 0.044°")


def test_the_heading_title_has_the_error_and_the_share_within_the_filters_own_sigma(tmp_path):
    t = np.arange(0.0, 10.0, 0.1)
    error = np.where(t < 5.0, rad(0.01), rad(0.1))            # half the time within 2σ = 0.06°, half beyond
    ape = yaw_ape(t, error, t, np.zeros_like(t))
    sigma = np.full(len(t), rad(0.03))
    ekf = yaw_ape(t, -2 * error, t, np.zeros_like(t))
    path = str(tmp_path / "heading.png")
    plot_heading_error(path, [HeadingCurve("processed", ape, sigma), HeadingCurve("EKF", ekf, 3 * sigma)],
                       spans=[Span(3.0, 4.5, "no marker seen")], rejected=[(2.0, "filter: gated")], t0=0.0)
    rmse = math.sqrt(0.5 * (0.01 ** 2 + 0.1 ** 2))
    p95 = np.percentile(np.where(t < 5.0, 0.01, 0.1), 95)
    assert png_title(path) == (f"heading error RMSE {rmse:.3f}°, p95 {p95:.3f}°, 50 % within the filter's own ±2σ; "
                               f"EKF RMSE {2 * rmse:.3f}°, p95 {2 * p95:.3f}°, 50 % within its own ±2σ")
    assert png_size(path) == (WIDTH, 600)


def test_the_frame_position_title_has_the_largest_bin(tmp_path):
    az = np.linspace(-3.0, 3.0, 400)
    el = np.where(np.arange(400) % 2, 0.3, -0.3)
    bias = error_by_frame_position(az, el, np.where(el > 0, rad(0.12), rad(-0.04)), az_bins=4, el_bins=2)
    path = plot_frame_position(str(tmp_path / "frame.png"), bias)
    assert png_title(path).startswith("yaw error by position in the frame: the largest bin mean is 0.120°")


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0])
def test_the_mounting_turn_of_a_rolled_camera_follows_the_azimuth(yaw_deg):
    """A boresight roll r (about base_link x) turns a horizon bearing by arccos(cos²a + sin²a cos r), a the angle
    of the bearing from base_link x: |sin az| for a camera looking along x, |cos az| for one turned by 90°."""
    r = rad(0.3)
    az = np.radians(np.arange(-180.0, 180.0, 15.0))
    b = azel_to_bearing(az, np.zeros_like(az))
    turn = mounting_turn((r, 0.0, 0.0), b, rot_z(rad(yaw_deg)))
    a = az + rad(yaw_deg)
    assert turn == pytest.approx(np.arccos(np.cos(a) ** 2 + np.sin(a) ** 2 * math.cos(r)), abs=1e-6)


def calibration(rpy_deg, sigma_deg, before, after, used):
    n = len(before)
    rpy, sd = np.radians(rpy_deg), np.radians(sigma_deg)
    return Calibration(boresight_rpy=rpy, boresight_sigma=sd, lever_arm_delta=np.zeros(3),
                       lever_arm_sigma=np.full(3, np.nan), lever_arm_estimated=False, cov=np.diag(sd ** 2),
                       residual_rms_before=float(np.sqrt(np.mean(before[used] ** 2))),
                       residual_rms_after=float(np.sqrt(np.mean(after[used] ** 2))),
                       residual_median_before=float(np.median(before[used])),
                       residual_median_after=float(np.median(after[used])), heading_rms=0.0, variance_factors={},
                       n_observations=n, n_used=int(used.sum()), n_markers=5, n_heading=100, moving_time=20.0,
                       iterations=5, used=used, residuals_before=before, residuals_after=after,
                       lenses=DualFisheye(lens_offset=0.01))


def test_the_calibration_title_says_how_far_the_mounting_was_off(tmp_path):
    """Observations all around the horizon, before = the turn of a camera rolled by 0.3° (+ noise), after =
    noise: the title gives the fitted turn and the residuals; a turn within 2σ of none says so. (The noise: |N(0,
    0.01°)|, RMS 0.010°.)"""
    rng = np.random.default_rng(3)
    az = rng.uniform(-math.pi, math.pi, 600)
    el = rng.uniform(-0.3, 0.3, 600)
    b = azel_to_bearing(az, el)
    noise = np.abs(rng.normal(0.0, rad(0.01), 600))
    before = mounting_turn((rad(0.3), 0.0, 0.0), b, np.eye(3)) + noise
    used = rng.random(600) > 0.05
    before[~used] = np.nan
    tilted = calibration([0.3, 0.0, 0.0], [0.01, 0.01, 0.02], before, noise, used)
    path = plot_calibration(str(tmp_path / "calibration.png"), tilted, b)
    rms_before = math.degrees(tilted.residual_rms_before)
    assert png_title(path) == (f"camera mounting off by 0.30° (roll +0.30° ± 0.01°, pitch +0.00° ± 0.01°, yaw "
                               f"+0.00° ± 0.02°): bearing residuals {rms_before:.3f}° → 0.010° RMS after calibrating")
    assert png_size(path) == (WIDTH, 720)
    right = calibration([0.01, -0.015, 0.0], [0.01, 0.01, 0.02], noise, noise, used)
    assert calibration_answer(right) == ("camera mounted as the lever arms say: no turn beyond 2σ (roll +0.01° ± "
                                         "0.01°, pitch -0.01° ± 0.01°, yaw +0.00° ± 0.02°); bearing residuals "
                                         "0.010° → 0.010° RMS")

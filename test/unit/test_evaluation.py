"""Yaw evaluation against hand-checked numbers; reports are real files checked byte-wise (the plots: test_plots)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.evaluation import (
    EvaluationError,
    Report,
    error_by_frame_position,
    error_stats,
    fmt_angle,
    gaps,
    interp_yaw,
    marker_agreement,
    normalised_residuals,
    pairwise_differences,
    per_marker_series,
    write_report,
    yaw_ape,
    yaw_rpe,
)
from aruco_abs_orient.plots import HeadingCurve, plot_heading_error
from aruco_abs_orient.timesync import OffsetEstimate

rad = math.radians


def test_interp_yaw_across_the_wrap():
    t = np.array([0.0, 1.0, 3.0, 3.5, 3.75])
    yaw = np.array([rad(179.0), rad(-179.0), rad(-170.0), rad(-169.0), rad(-168.0)])
    q, ok = interp_yaw([0.5, 0.25, 1.0, 2.0, 4.0, -1.0], t, yaw, max_gap=1.5)
    assert ok.tolist() == [True, True, True, False, False, False]  # 1→3 s gap is 2 s > 1.5 s
    assert abs(math.degrees(q[0])) == pytest.approx(180.0, abs=1e-9)
    assert math.degrees(q[1]) == pytest.approx(179.5, abs=1e-3)
    assert math.degrees(q[2]) == pytest.approx(-179.0, abs=1e-12)
    assert np.isnan(q[3:]).all()
    # max_gap 0: only samples at the very same stamps
    q, ok = interp_yaw([1.0 + 1e-7, 0.5], t, yaw, max_gap=0.0)
    assert ok.tolist() == [True, False] and math.degrees(q[0]) == pytest.approx(-179.0)


@settings(max_examples=30, deadline=None)
@given(interval=st.floats(0.02, 2.0), jitter=st.floats(0.0, 1e-3), dropout=st.integers(3, 6),
       seed=st.integers(0, 2**16))
def test_a_reference_sampled_slowly_is_compared_everywhere_but_across_its_dropouts(interval, jitter, dropout, seed):
    # a reference written at its own rate (one line per image at 5 fps: 0.2 s apart, with the stamps' float
    # jitter) is compared between all its samples; where `dropout` of them are missing, nowhere in the hole
    # unless the hole is within max_gap
    rng = np.random.default_rng(seed)
    t = np.arange(40) * interval + rng.uniform(-jitter, jitter, 40) * interval
    t = np.delete(t, np.arange(20, 20 + dropout - 1))                 # a hole of `dropout` intervals
    yaw = np.linspace(0.0, 1.0, len(t))
    tq = (t[:-1] + t[1:]) / 2
    _, ok = interp_yaw(tq, t, yaw, max_gap=0.2)
    hole = np.diff(t) > 2.5 * interval
    assert hole.sum() == 1 and ok[~hole].all()
    assert ok[hole].all() == (np.diff(t)[hole] <= 0.2).all()


def test_wrap_179_vs_minus_179_is_2_degrees():
    e = yaw_ape([0.0, 1.0], [rad(179.0), rad(179.0)], [0.0, 1.0], [rad(-179.0), rad(-179.0)])
    assert np.degrees(e.error) == pytest.approx([-2.0, -2.0])
    assert math.degrees(e.stats.rmse) == pytest.approx(2.0)
    assert math.degrees(e.stats.bias) == pytest.approx(-2.0)


@settings(max_examples=20, deadline=None)
@given(offset_deg=st.floats(-20.0, 20.0), start_deg=st.floats(-180.0, 180.0))
def test_constant_offset_gives_known_stats_anywhere_on_the_circle(offset_deg, start_deg):
    t_ref = np.arange(0.0, 20.0, 0.1)
    yaw_ref = wrap(rad(start_deg) + 0.8 * t_ref)  # crosses ±180° several times
    t_est = np.arange(0.05, 19.9, 1.0 / 30.0)  # other stamps: the reference is interpolated
    yaw_est = wrap(rad(start_deg) + 0.8 * t_est + rad(offset_deg))
    s = yaw_ape(t_est, yaw_est, t_ref, yaw_ref).stats
    assert math.degrees(s.rmse) == pytest.approx(abs(offset_deg), abs=0.02)
    assert math.degrees(s.mean) == pytest.approx(abs(offset_deg), abs=0.02)
    assert math.degrees(s.bias) == pytest.approx(offset_deg, abs=0.02)
    assert math.degrees(s.std) < 0.02
    assert s.coverage == 1.0
    # RPE does not see a constant offset
    r = yaw_rpe(t_est, yaw_est, t_ref, yaw_ref, delta=1.0).stats
    assert math.degrees(r.max) < 0.02


def wrap(a):
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def test_error_stats_hand_checked():
    s = error_stats(np.radians([0.0, -1.0, 2.0, -3.0, 4.0]), thresholds=np.radians([0.5, 1.5, 2.5]))
    assert math.degrees(s.rmse) == pytest.approx(math.sqrt(6.0))  # (0+1+4+9+16)/5 = 6
    assert math.degrees(s.mean) == pytest.approx(2.0)
    assert math.degrees(s.median) == pytest.approx(2.0)
    assert math.degrees(s.std) == pytest.approx(math.sqrt(2.0))  # of |e| = 0..4
    assert math.degrees(s.p95) == pytest.approx(3.8)  # linear between 3 and 4
    assert math.degrees(s.max) == pytest.approx(4.0)
    assert math.degrees(s.bias) == pytest.approx(0.4)
    assert s.share_under == pytest.approx((0.2, 0.4, 0.6))  # < 0.5°, < 1.5°, < 2.5°
    d = s.report_dict()
    assert d["rmse_deg"] == pytest.approx(math.sqrt(6.0)) and d["share_under_2.5_deg"] == pytest.approx(0.6)
    with pytest.raises(EvaluationError, match="no samples"):
        error_stats([], n_total=3)


def test_ape_coverage_and_rpe_drift():
    t_ref = np.arange(0.0, 4.75, 0.5)  # reference only for the first half
    t_est = np.arange(0.0, 10.0, 0.5)
    drift = rad(1.0)  # estimate drifts 1°/s away from the reference
    e = yaw_ape(t_est, 0.3 + drift * t_est, t_ref, np.full(len(t_ref), 0.3))
    assert e.stats.coverage == pytest.approx(10 / 20)
    assert math.degrees(e.stats.max) == pytest.approx(4.5)
    r = yaw_rpe(t_est, 0.3 + drift * t_est, t_est, np.full(len(t_est), 0.3), delta=2.0)
    assert np.degrees(r.error) == pytest.approx(np.full(len(r.error), 2.0))
    assert len(r.error) == 16  # stamps 0 … 7.5 s have t + 2 s inside
    with pytest.raises(EvaluationError, match="delta"):
        yaw_rpe(t_est, t_est, t_est, t_est, delta=0.0)
    with pytest.raises(EvaluationError, match="2 stamps but 3"):
        yaw_ape([0, 1], [0, 1, 2], t_ref, t_ref)


def test_per_marker_series_and_pairwise_statistics_hand_checked():
    t = np.arange(0.0, 5.0, 0.1)
    base = wrap(rad(179.8) + 0.01 * t)  # near the wrap: marker 2 crosses it
    records_t = np.concatenate([t, t, t, [7.0]])
    ids = np.concatenate([np.full(len(t), 1), np.full(len(t), 2), np.full(len(t), 3), [4]])
    yaws = np.concatenate([base, wrap(base + rad(1.2)), wrap(base - rad(0.4)), [0.0]])
    order = np.random.default_rng(1).permutation(len(records_t))  # records arrive unordered
    series = per_marker_series(records_t[order], ids[order], yaws[order])
    assert sorted(series) == [1, 2, 3, 4]
    assert np.all(np.diff(series[1][0]) > 0)
    pw = pairwise_differences(series)
    assert sorted(pw.pairs) == [(1, 2), (1, 3), (2, 3)]  # marker 4 never seen with another
    assert np.degrees(pw.pairs[(1, 2)][1]) == pytest.approx(np.full(len(t), -1.2))
    assert np.degrees(pw.pairs[(2, 3)][1]) == pytest.approx(np.full(len(t), 1.6))
    s = pw.stats  # |d| = 1.2, 0.4, 1.6 (each 50 times)
    assert math.degrees(s.median) == pytest.approx(1.2)
    assert math.degrees(s.mean) == pytest.approx(3.2 / 3)
    assert math.degrees(s.std) == pytest.approx(math.sqrt(0.746667 / 3), abs=1e-5)
    assert s.share_under == pytest.approx((1 / 3, 1 / 3, 1.0))
    assert set(pw.report_dict()) == {"all_pairs", "1-2", "1-3", "2-3"}


def test_pairwise_needs_common_times_unless_interpolating():
    series = {1: (np.array([0.0, 1.0, 2.0]), np.zeros(3)), 2: (np.array([0.5, 1.5]), np.full(2, rad(0.3)))}
    with pytest.raises(EvaluationError, match="common times"):
        pairwise_differences(series)
    pw = pairwise_differences(series, max_gap=1.0)
    assert np.degrees(pw.pairs[(1, 2)][1]) == pytest.approx([-0.3])  # marker 1 at 1.0 s vs 2 between


def test_error_by_frame_position_finds_an_elevation_bias():
    rng = np.random.default_rng(4)
    n = 4000
    az = rng.uniform(-math.pi, math.pi, n)
    el = np.where(rng.random(n) < 0.5, -0.5, 0.5) + rng.uniform(-0.1, 0.1, n)
    err = np.where(el > 0, rad(0.2), rad(-0.2))  # a bias that depends on elevation only
    b = error_by_frame_position(az, el, err, az_bins=8, el_bins=2, el_range=(-0.7, 0.7))
    assert np.degrees(b.by_elevation) == pytest.approx([-0.2, 0.2])
    assert math.degrees(b.max_abs_bias) == pytest.approx(0.2)
    assert b.count.sum() == n and b.count.shape == (2, 8)
    # a lone outlier in an otherwise empty bin does not count as a bias (min_count)
    b2 = error_by_frame_position(np.append(az, 0.0), np.append(el, 0.1), np.append(err, rad(5.0)),
                                 az_bins=8, el_bins=4, el_range=(-0.7, 0.7), min_count=5)
    assert math.degrees(b2.max_abs_bias) == pytest.approx(0.2)
    with pytest.raises(EvaluationError, match="no marker observations"):
        error_by_frame_position([], [], [])


def make_estimate():
    taus = np.linspace(-1.0, 1.0, 101)
    return OffsetEstimate(offset=0.367, sigma=0.002, confidence=0.9, coherence=0.999, taus=taus,
                          curve=1.0 - 0.01 * (taus - 0.367) ** 2, method="coherence", n_samples=1800, overlap=60.0)


def test_report_has_a_headline_page_then_tables_and_json(tmp_path):
    t = np.arange(0.0, 10.0, 0.1)
    ape = yaw_ape(t, np.full(len(t), rad(1.5)), t, np.zeros_like(t))
    plot = plot_heading_error(str(tmp_path / "plots_ape.png"), [HeadingCurve("ours", ape)])
    bias = error_by_frame_position([0.1, 0.2], [0.0, 0.1], [0.0, 0.0], el_bins=2, min_count=5)  # no full bin
    rep = Report(title="report of run1", intro="one line about the run",
                 headline=[("heading vs reference", f"RMSE {fmt_angle(ape.stats.rmse)}", "–", "[x](t.md#a)")],
                 notes=["observations disagree with a time offset: ..."], plots={"heading error": plot},
                 tables=[("Per marker", ["marker", "n"], [[1, 200], [7, 3.14159]])],
                 data={"ape": ape, "timesync": make_estimate(), "frame_position": bias})
    md, js = write_report(str(tmp_path / "out"), rep)
    with open(js) as f:
        data = json.load(f)
    assert data["ape"]["rmse_deg"] == pytest.approx(1.5)
    assert data["ape"]["share_under_2_deg"] == 1.0
    assert data["timesync"]["offset_ms"] == pytest.approx(367.0)
    assert data["frame_position"]["max_abs_bias_deg"] is None  # NaN → null, never a made-up number
    assert data["plots"] == {"heading error": "../plots_ape.png"}
    assert data["plot_titles"] == {"../plots_ape.png": "heading error RMSE 1.500°, p95 1.500°"}  # each plot's answer
    assert data["headline"][0][1] == "RMSE 1.50°"
    text = Path(md).read_text()
    lines = text.splitlines()
    # the page a person reads first: title, the intro, the headline table, the checks, the plots; then details
    assert lines[0] == "# report of run1" and lines[2] == "one line about the run"
    assert "| heading vs reference | RMSE 1.50° | – | [x](t.md#a) |" in text
    assert text.index("RMSE 1.50°") < text.index("**Checks:**") < text.index("![heading error](../plots_ape.png)") \
        < text.index("## Details") < text.index("### Per marker")
    assert "| 7 | 3.142 |" in text  # 4 significant digits
    assert sorted(os.listdir(tmp_path / "out")) == ["report.json", "report.md"]


def test_fmt_angle_rounds_for_a_person():
    assert [fmt_angle(rad(x)) for x in (0.0173, -0.66, 1.174, 23.456)] == ["0.017°", "-0.660°", "1.17°", "23.5°"]
    assert fmt_angle(None) == fmt_angle(float("nan")) == "–"


def test_normalised_residuals_and_gaps():
    rng = np.random.default_rng(1)
    sigma = np.full(20000, rad(0.1))
    z = normalised_residuals(rng.normal(0, rad(0.1), 20000), sigma)
    assert z["rms"] == pytest.approx(1.0, abs=0.03) and z["share_within_2_sigma"] == pytest.approx(0.954, abs=0.01)
    assert normalised_residuals(rng.normal(0, rad(0.3), 20000), sigma)["rms"] == pytest.approx(3.0, abs=0.1)
    with pytest.raises(EvaluationError):
        normalised_residuals([0.1], [0.0])
    t = np.concatenate([np.arange(1.0, 5.0, 0.1), np.arange(7.0, 9.0, 0.1)])
    assert gaps(t, 0.5, start=0.0, end=10.0) == [pytest.approx((4.9, 7.0)), pytest.approx((8.9, 10.0)),
                                                 pytest.approx((0.0, 1.0))]


def test_marker_agreement_flags_the_marker_off_the_consensus_hand_checked():
    """Three markers: 11 and 12 scatter ±0.02° around the consensus, 13 sits 0.5° off; rejected rows are counted
    by reason; a marker seen fewer than min_count times is never flagged."""
    t = np.repeat(np.arange(20.0), 3)
    ids = np.tile([11, 12, 13], 20)
    scatter = np.tile([0.02, -0.02], 30)
    dev = np.radians(np.where(ids == 13, 0.5, 0.0) + scatter)
    accepted = ids != 13
    reasons = np.where(ids == 13, "tracking gate: far from its predicted bearing", "")
    a = marker_agreement(t, ids, dev, accepted, reasons)
    assert a.markers == (11, 12, 13) and list(a.n) == [20, 20, 20]
    assert np.degrees(a.median) == pytest.approx([0.0, 0.0, 0.5], abs=0.02 + 1e-9)
    assert math.degrees(a.typical_spread) == pytest.approx(1.4826 * 0.02, abs=1e-9)
    assert a.flagged == (13,)
    assert a.rejected == {13: {"tracking gate: far from its predicted bearing": 20}}
    few = marker_agreement(t[:6], ids[:6], dev[:6], accepted[:6], reasons[:6])      # 2 observations each
    assert few.flagged == ()
    d = a.report_dict()
    assert d["flagged"] == [13] and d["markers"]["13"]["median_deg"] == pytest.approx(0.5, abs=0.021)


@settings(max_examples=25, deadline=None)
@given(off_deg=st.floats(0.2, 3.0), sign=st.sampled_from([-1.0, 1.0]), n_markers=st.integers(3, 8),
       seed=st.integers(0, 10_000))
def test_a_moved_marker_is_flagged_and_no_good_one(off_deg, sign, n_markers, seed):
    """Markers whose deviations scatter with σ 0.03° (normal noise); one of them off by ≥ 0.2°: it alone is
    flagged, wherever it is among the ids."""
    rng = np.random.default_rng(seed)
    ids = np.repeat(np.arange(n_markers) * 7 + 3, 60)
    moved = int(rng.integers(n_markers)) * 7 + 3
    dev = rng.normal(0.0, math.radians(0.03), len(ids)) + np.where(ids == moved, sign * math.radians(off_deg), 0.0)
    a = marker_agreement(np.arange(len(ids)) * 0.1, ids, dev, np.ones(len(ids), dtype=bool))
    assert a.flagged == (moved,)
    clean = marker_agreement(np.arange(len(ids)) * 0.1, ids, np.where(ids == moved, 0.0, dev),
                             np.ones(len(ids), dtype=bool))
    assert clean.flagged == ()

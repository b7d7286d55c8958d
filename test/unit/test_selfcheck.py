"""Self-checks (issue 20): a run that disagrees with itself says why and what fixes it.

Two levels of truth:
- observation arrays built here from an exact geometry (a prism track, surveyed markers, a known time
  offset error and camera tilt applied through the bearing-rate and tilt formulas, VO drift, noise): the
  estimates must come back;
- the generator's rendered ``ci`` scenario processed by ``process`` like a user's recording: with the
  right offset no time-offset warning, with a forgotten offset (0 instead of 0.367 s) the warning with a
  suggestion near the hidden offset, its unpublished 0.3° camera roll found as a tilt, and a marker moved
  in the map by 0.3 m named.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.nodestate import live_offset_to_apply
from aruco_abs_orient.offline.process import RunSetup, process_bag
from aruco_abs_orient.selfcheck import RollingSelfCheck, RunContext, YawObservation, bearing_rate, check_run
from aruco_abs_orient.timesync.online import OnlineOffsetEstimator

DEG = math.pi / 180


def _world(rng, n_markers=6, duration=60.0):
    """A prism driving a figure of varying curvature at ~1 m/s, markers around it at 2-10 m."""
    pt = np.arange(0.0, duration, 0.05)
    heading = 0.6 * np.sin(2 * np.pi * pt / 23.0) + 0.004 * pt ** 1.5
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * 0.05, axis=0)
    prism = np.column_stack([xy, np.full(len(pt), 1.0)])
    markers = {}
    for i in range(n_markers):
        j = rng.integers(len(pt))
        ang = rng.uniform(-np.pi, np.pi)
        r = rng.uniform(2.0, 10.0)
        markers[i] = np.array([xy[j, 0] + r * np.cos(ang), xy[j, 1] + r * np.sin(ang), rng.uniform(0.5, 2.5)])
    return pt, prism, heading, markers


def _observations(rng, pt, prism, heading, markers, eps, tilt, moved=None, noise=0.02 * DEG):
    """Marker yaws as a run sees them: truth + ε·k (prism looked up ε s off) + the tilt's azimuth error
    + a moved marker's offset + noise; the odometry yaw drifts (what the map→odom yaw absorbs)."""
    rows = []
    for t in np.arange(2.0, pt[-1] - 2.0, 1 / 15):
        p = np.array([np.interp(t, pt, prism[:, k]) for k in range(3)])
        psi = float(np.interp(t, pt, heading))
        for mid, m in markers.items():
            d = m - p
            dist = math.hypot(d[0], d[1])
            if dist > 12 or rng.random() < 0.5:
                continue
            az = math.atan2(d[1], d[0]) - psi          # bearing in the (level) camera frame
            el = math.atan2(d[2] - 0.2, dist)
            k = float(bearing_rate([t], [m], pt, prism)[0])
            err = eps * k - math.tan(el) * (tilt[0] * math.cos(az) + tilt[1] * math.sin(az))
            if moved is not None and mid == moved[0]:
                err += moved[1]
            odom = psi - (0.002 * t + 0.01 * math.sin(t / 7))  # VO drift
            rows.append((t, mid, az, el, 0.03 * DEG, err + rng.normal(0, noise), True, psi + err, odom))
    cols = list(zip(*rows))
    return {k: np.asarray(v) for k, v in zip(("time", "id", "azimuth", "elevation", "yaw_sigma", "residual",
                                              "accepted", "yaw", "odom_yaw"), cols)}


@settings(max_examples=20)
@given(eps=st.floats(-0.5, 0.5), roll=st.floats(-1.0, 1.0), pitch=st.floats(-1.0, 1.0),
       seed=st.integers(0, 2 ** 16))
def test_time_offset_and_tilt_come_back(eps, roll, pitch, seed):
    rng = np.random.default_rng(seed)
    pt, prism, heading, markers = _world(rng)
    obs = _observations(rng, pt, prism, heading, markers, eps, (roll * DEG, pitch * DEG))
    r = check_run(obs, (pt, prism), markers, run=RunContext(time_offset=0.1))
    assert r["time_offset"]["suggested_s"] == pytest.approx(0.1 + eps, abs=0.01)
    # within 0.05°, or 5 σ where the world's geometry is poor (σ > 0.01°): the reported σ is optimistic,
    # errors reach 4 σ over 40 seeds (seed 18000: roll 0.058°, σ 0.015°)
    tol = max(0.05, 5 * r["camera_tilt_deg"]["sigma"])
    assert r["camera_tilt_deg"]["roll"] == pytest.approx(roll, abs=tol)
    assert r["camera_tilt_deg"]["pitch"] == pytest.approx(pitch, abs=tol)
    kinds = {f["kind"] for f in r["findings"]}
    assert ("time_offset" in kinds) == (abs(eps) > 0.03) or 0.015 < abs(eps) < 0.03
    if abs(eps) < 0.015 and math.hypot(roll, pitch) > 0.2:
        assert "camera_tilt" in kinds


def test_a_consistent_run_has_no_finding_and_a_moved_marker_is_named():
    rng = np.random.default_rng(3)
    pt, prism, heading, markers = _world(rng)
    clean = _observations(rng, pt, prism, heading, markers, 0.0, (0.0, 0.0))
    assert check_run(clean, (pt, prism), markers)["findings"] == []
    moved = _observations(rng, pt, prism, heading, markers, 0.0, (0.0, 0.0), moved=(2, 1.5 * DEG))
    findings = check_run(moved, (pt, prism), markers)["findings"]
    assert findings[0]["kind"] == "marker" and findings[0]["message"].startswith("marker 2: ")
    assert findings[0]["value"] == pytest.approx(1.5, abs=0.1)
    # its yaws also make the residuals inconsistent with their σ: the likely cause is named
    assert [f["kind"] for f in findings[1:]] == ["sigma"] and findings[1]["message"].endswith("likely cause: marker")


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 16), start=st.floats(15.0, 35.0), gap=st.floats(6.0, 15.0),
       moved=st.sampled_from([None, 0, 3]))
def test_markers_seen_only_in_stretches_apart_are_not_reported_off_each_other(seed, start, gap, moved):
    """Markers 0, 2, 4 seen only before a stretch with no marker in view and 1, 3, 5 only after it (a corridor
    without markers, longer than the self-check's knots): the two groups are compared only through the filter's
    drift across the gap; none is off the others (it was: 10⁵ degrees, the fit singular), while a marker moved
    by 2° within its group is still named."""
    rng = np.random.default_rng(seed)
    pt, prism, heading, markers = _world(rng, n_markers=6)
    obs = _observations(rng, pt, prism, heading, markers, 0.0, (0.0, 0.0),
                        moved=None if moved is None else (moved, 2.0 * DEG))
    before, after = obs["time"] < start, obs["time"] > start + gap
    keep = (before & (obs["id"] % 2 == 0)) | (after & (obs["id"] % 2 == 1))
    obs = {k: v[keep] for k, v in obs.items()}
    r = check_run(obs, (pt, prism), markers)
    named = [f["message"].split(":")[0] for f in r["findings"] if f["kind"] == "marker"]
    assert named in ([], [f"marker {moved}"]), r["findings"]
    assert all(abs(v) < 10.0 for v in r.get("marker_offset_deg", {}).values()), r["marker_offset_deg"]
    if moved is not None:   # named when two others were seen all along with it (a majority against it)
        t = {m: obs["time"][obs["id"] == m] for m in markers if np.sum(obs["id"] == m) >= 20}
        if moved in t and sum(1 for m in t if m != moved and m % 2 == moved % 2
                              and t[m].min() <= t[moved].min() + 1 and t[m].max() >= t[moved].max() - 1) >= 2:
            assert named == [f"marker {moved}"], r["findings"]


def _rolling(rng, eps, in_use, window=60.0):
    """A node's rolling self-check fed 60 s whose marker yaws are ``eps`` s off the offset ``in_use``, checked
    once (``diagnostics``, returned with it) over the last ``window`` s; and how many yaws it was fed."""
    pt, prism, heading, markers = _world(rng)
    obs = _observations(rng, pt, prism, heading, markers, eps, (0.0, 0.0))
    live = RollingSelfCheck(markers, time_offset=in_use, window=window)
    for t, p in zip(pt, prism):
        live.add_prism(float(t), p)
    for i in range(len(obs["time"])):
        live.add_observation(YawObservation(*(obs[k][i] for k in YawObservation._fields if k in obs)))
    return live, live.diagnostics(), len(obs["time"])


def test_rolling_window_for_the_node():
    live, (level, message, values), fed = _rolling(np.random.default_rng(5), 0.3, 0.0, window=30.0)
    assert len(live._obs) < fed  # bounded: the last 30 s only
    assert level == "warn" and "observations disagree with a time offset" in message
    assert values["self-check suggested time offset [s]"] == pytest.approx(0.3, abs=0.03)
    # what the node asks before it applies a live time-offset estimate: the true offset is supported, the one
    # in use (0) and one 50 ms off are not
    assert live.supports(0.3) and not live.supports(0.0) and not live.supports(0.35)
    empty = RollingSelfCheck(live.marker_xyz)
    assert not empty.supports(0.0)  # no check yet: no verdict either way
    assert empty.diagnostics()[0] == "ok"


def test_the_marker_yaws_veto_a_live_offset_estimate_that_contradicts_a_good_offset():
    """The node's rule (nodestate.live_offset_to_apply) with a real estimator's suggestion: a biased live
    estimate (0.317 ± 0.0095 s, as on the realistic demo) does not replace a good offset (0.367 s) the marker
    yaws support; it does replace a forgotten one (0 s) they contradict, and it does before any check."""
    estimator = OnlineOffsetEstimator()
    estimator.applied, estimator.applied_sigma = 0.317, 0.0095
    good = _rolling(np.random.default_rng(7), 0.0, 0.367)[0]
    assert live_offset_to_apply(0.367, estimator, good) == (None, True)
    forgotten = _rolling(np.random.default_rng(7), 0.367, 0.0)[0]
    estimator.applied, estimator.applied_sigma = 0.367, 0.0095
    assert live_offset_to_apply(0.0, estimator, forgotten) == (0.367, False)
    assert live_offset_to_apply(0.0, estimator, RollingSelfCheck(good.marker_xyz)) == (0.367, False)
    estimator.applied = 0.37  # agrees with the offset in use: nothing to switch to
    assert live_offset_to_apply(0.367, estimator, good) == (None, False)


# ----------------------------------------------------------------------------- rendered scenario


@pytest.fixture(scope="module")
def ci(scenario_factory):
    scen = scenario_factory("ci")
    return scen, yaml.safe_load(Path(scen.hidden).read_text())


def _run(scen, out, offset, markers=None):
    res = process_bag(scen.bag, MarkerMap.load(markers or scen.markers), str(out), RunSetup(offset, progress=False))
    summary = json.loads(Path(res.summary_path).read_text())
    return summary["selfcheck"], summary


def test_right_offset_no_offset_warning_and_the_unpublished_camera_roll_found(ci, tmp_path):
    """The ci scenario's camera is turned 0.29° in roll (rendered, not in the bag's tf): calibrate's own model on
    the run's bearings finds it within 3 σ and says so with the command; the right time offset is not flagged."""
    scen, hidden = ci
    check, summary = _run(scen, tmp_path, hidden["camera_time_offset"])
    kinds = [f["kind"] for f in check["findings"]]
    assert "time_offset" not in kinds and "marker" not in kinds, check["findings"]
    assert check["time_offset"]["suggested_s"] == pytest.approx(hidden["camera_time_offset"], abs=0.015)
    found = np.array(check["model_check"]["boresight_correction_deg"])
    sigma = np.array(check["model_check"]["boresight_sigma_deg"])
    assert np.all(np.abs(found - np.array(hidden["boresight"]["rpy_deg"])) < 3 * sigma), (found, sigma)
    assert "camera_tilt" in kinds and any("aruco-abs-orient calibrate" in w for w in summary["warnings"])


def test_after_calibrating_the_self_check_finds_nothing(ci, tmp_path):
    """The loop a user walks: the self-check finds the camera's roll and names calibrate; calibrate; process with
    the calibration: no time-offset, tilt or yaw finding (the check is calibrate's own model)."""
    from aruco_abs_orient.calibration import load_calibration
    from aruco_abs_orient.offline.cli import main as cli_main

    scen, hidden = ci
    cal = tmp_path / "calibration.yaml"
    assert cli_main(["calibrate", scen.bag, "--markers", scen.markers, "--time-offset",
                     str(hidden["camera_time_offset"]), "--out", str(cal), "--quiet"]) == 0
    res = process_bag(scen.bag, MarkerMap.load(scen.markers), str(tmp_path / "run"),
                      RunSetup(hidden["camera_time_offset"], calibration=load_calibration(str(cal)), progress=False))
    check = json.loads(Path(res.summary_path).read_text())["selfcheck"]
    kinds = {f["kind"] for f in check["findings"]}
    assert not kinds & {"time_offset", "camera_tilt", "boresight_yaw"}, check["findings"]


def test_forgotten_offset_is_warned_with_the_fix(ci, tmp_path):
    scen, hidden = ci
    check, summary = _run(scen, tmp_path, 0.0)
    found = [f for f in check["findings"] if f["kind"] == "time_offset"]
    assert found, check
    assert found[0]["value"] == pytest.approx(hidden["camera_time_offset"], abs=0.1)
    assert "the marker bearings fit a time offset of +0.3" in found[0]["message"]
    assert f"aruco-abs-orient timesync {scen.bag} --markers {scen.markers}" in found[0]["message"]
    assert found[0]["message"] in summary["warnings"]


def test_a_marker_moved_after_the_survey_is_named(ci, tmp_path):
    scen, hidden = ci
    data = yaml.safe_load(Path(scen.markers).read_text())
    for m in data["markers"]:
        if m["id"] == 31:
            m["position"][0] += 0.3  # 0.3 m east in the map: the real one did not move
    moved = tmp_path / "markers.yaml"
    moved.write_text(yaml.safe_dump(data))
    check, _ = _run(scen, tmp_path / "out", hidden["camera_time_offset"], str(moved))
    named = [f for f in check["findings"] if f["kind"] == "marker"]
    assert [f["message"].split(":")[0] for f in named] == ["marker 31"], check["findings"]


@pytest.mark.parametrize("boresight_yaw_deg", [0.0, 0.3, -0.5])
def test_heading_against_the_direction_of_travel_on_straights(boresight_yaw_deg):
    """Straight stretches joined by turns: a heading off the prism track's direction by the camera's
    mounting yaw is found (and none when there is none); turns and standstill are left out."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 60.0, 0.05)
    heading = np.where(t < 20, 0.0, np.where(t < 25, (t - 20) * np.pi / 10, np.where(t < 45, np.pi / 2,
                       np.pi / 2 + (t - 45) * np.pi / 10)))
    speed = np.where(t < 2, 0.0, 1.0)
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * (speed * 0.05)[:, None], axis=0)
    prism = np.column_stack([xy + rng.normal(0, 0.003, xy.shape), np.ones(len(t))])
    pose_t = t[::2]
    pose_yaw = np.interp(pose_t, t, heading) + math.radians(boresight_yaw_deg) + rng.normal(0, 0.0005, len(pose_t))
    r = check_run({}, (t, prism), {}, (pose_t, pose_yaw))
    assert r["heading_minus_travel_deg"]["median"] == pytest.approx(boresight_yaw_deg, abs=0.05)
    found = [f for f in r["findings"] if f["kind"] == "boresight_yaw"]
    assert bool(found) == (boresight_yaw_deg != 0.0), r["findings"]


def test_no_heading_finding_on_the_realistic_worlds_loop_with_the_prism_lever_arm():
    """Issue 17: the realistic demo's loop has no straights; the moments that pass as straight (slow
    turning while it speeds up) are in a curve, where the prism 0.25 m behind base_link swings outwards: its
    track was 0.6° off the true heading there and the calibrated demo was told to calibrate its mounting yaw.
    With the prism's lever arm the track's direction is base_link's: no finding on the true headings, and a
    0.3° mounting yaw still found."""
    import dataclasses

    from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
    from aruco_abs_orient.transforms import yaw_of

    sc = Scenario(dataclasses.replace(PRESETS["demo"], seed=0))   # the demo's track
    pose_t = np.arange(sc.prism.stamps[0] + 0.3, sc.prism.stamps[-1] - 0.3, 1 / 30)
    pose_yaw = yaw_of(sc.map_T_base(pose_t)[:, :3, :3])
    lever = sc.base_T_prism[:3, 3]
    prism = (sc.prism.stamps, sc.prism.positions)
    swung = check_run({}, prism, {}, (pose_t, pose_yaw))
    assert abs(swung["heading_minus_travel_deg"]["median"]) > 0.3   # the bias the lever arm makes
    r = check_run({}, prism, {}, (pose_t, pose_yaw), RunContext(prism_lever=lever))
    assert abs(r["heading_minus_travel_deg"]["median"]) < 0.12, r["heading_minus_travel_deg"]
    assert not [f for f in r["findings"] if f["kind"] == "boresight_yaw"], r["findings"]
    r = check_run({}, prism, {}, (pose_t, pose_yaw + math.radians(0.3)), RunContext(prism_lever=lever))
    assert [f for f in r["findings"] if f["kind"] == "boresight_yaw"], r


def test_the_node_s_rolling_check_runs_calibrate_s_model():
    """The node's rolling self-check with calibrate's model (a ModelContext): fed 70 s of the generator's world
    (exact bearings, its VO, its prism track) with a time offset 40 ms off and a camera turned 0.3° in roll that the
    mounting in use does not know, it finds both with calibrate's own model after a window's worth of data, and
    keeps them between model checks; with the true offset and mounting it finds none of them."""
    import dataclasses

    from aruco_abs_orient.camera import bearing_to_azel
    from aruco_abs_orient.selfcheck import ModelContext, SelfCheckParams
    from aruco_abs_orient.synthetic.feed import marker_observations
    from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario
    from aruco_abs_orient.transforms import make_T, rot_x
    from aruco_abs_orient.tum import Trajectory

    sc = Scenario(dataclasses.replace(PRESETS["ci"], seed=4, duration=70.0, fps=5.0, boresight_deg=0.0))
    frames = sc.frame_times
    ob = marker_observations(sc, frames, noise=0.02 * DEG, rng=np.random.default_rng(4))
    az, el = bearing_to_azel(ob.bearings)
    kinds = {}
    for name, error, turn in (("wrong", 0.04, 0.3), ("right", 0.0, 0.0)):
        mounting = sc.base_T_camera_true @ make_T(rot_x(math.radians(turn)))   # what the run believes
        model = ModelContext(sc.surveyed_markers, Trajectory(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4))),
                             mounting, sc.base_T_prism)
        live = RollingSelfCheck({m.id: m.position for m in sc.markers}, window=65.0, model=model,
                                params=SelfCheckParams(model_observations=600))
        for t, p in zip(sc.prism.stamps, sc.prism.positions):
            live.add_prism(float(t), p)
        reports = []
        for k, t in enumerate(frames):
            live.add_odometry(float(t) + error, sc.odom_T_base(t))     # stamped on a clock 40 ms off
            for i in np.flatnonzero(ob.frame == k):
                live.add_observation(YawObservation(float(t) + error, int(ob.ids[i]), float(az[i]), float(el[i]),
                                                    0.1 * DEG, math.nan, True, bearing_sigma=0.02 * DEG))
            if k % 50 == 49:
                reports.append(live.check())
        assert "model_check" not in reports[0] and "model_check" in reports[-1], [r.keys() for r in reports]
        kinds[name] = {f["kind"] for f in reports[-1]["findings"]}
    assert {"time_offset", "camera_tilt"} <= kinds["wrong"], kinds
    assert not kinds["right"] & {"time_offset", "camera_tilt", "boresight_yaw"}, kinds


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_a_wrong_time_offset_sign_names_the_offset_not_a_moved_marker(seed):
    """A time offset given with the wrong sign (−0.367 s for +0.367 s: 0.734 s off) looks the prism up 0.73 m
    along its track: each marker's yaw is off by the change of its bearing from there (exactly, not linearised),
    which a per-marker offset partly absorbs. The offset is the finding, not a moved marker."""
    rng = np.random.default_rng(seed)
    pt, prism, heading, markers = _world(rng)
    obs = _observations(rng, pt, prism, heading, markers, 0.0, (0.0, 0.0))
    err = 0.734
    for k, (t, mid) in enumerate(zip(obs["time"], obs["id"])):
        m = markers[int(mid)]
        here, there = ([np.interp(s, pt, prism[:, j]) for j in range(2)] for s in (t, t + err))
        shift = math.atan2(m[1] - there[1], m[0] - there[0]) - math.atan2(m[1] - here[1], m[0] - here[0])
        obs["yaw"][k] += (shift + math.pi) % (2 * math.pi) - math.pi
    kinds = [f["kind"] for f in check_run(obs, (pt, prism), markers, run=RunContext(time_offset=-0.367))["findings"]]
    assert "time_offset" in kinds and "marker" not in kinds, kinds

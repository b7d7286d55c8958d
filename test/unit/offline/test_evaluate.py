"""offline/evaluate.py's ``evaluate --params``: the evaluation section of a params file changes what the report
computes, on a run directory written here by hand (a trajectory with a known hole, a reference with a known
gap, a known heading error), so every figure is checked against hand-made truth; a bad key is one line."""

import json
import math

import numpy as np
import pytest

from aruco_abs_orient.offline.cli import main as cli_main
from aruco_abs_orient.transforms import make_T, rot_z
from aruco_abs_orient.tum import Trajectory, write_tum

ERROR_DEG = 0.5   # the run's heading is off by this everywhere but in the reference's gap


def trajectory(stamps, yaw_deg):
    """Poses along x (1 m/s) with the given headings (degrees)."""
    return Trajectory.from_transforms(stamps, [make_T(rot_z(math.radians(y)), [t, 0.0, 0.0])
                                               for t, y in zip(stamps, yaw_deg)])


@pytest.fixture
def run(tmp_path):
    """10 s at 10 Hz from t = 100 s with a 0.3 s hole (4.0–4.3 s); the reference at 10 Hz, with a 0.35 s gap
    (6.0–6.35 s) over which the truth (the run's heading minus 0.5°) turns by 90°: interpolated across the gap,
    the run's poses inside it would show large errors."""
    t0 = 100.0
    est_t = t0 + np.round(np.concatenate([np.arange(0.0, 4.0 + 1e-9, 0.1), np.arange(4.3, 9.95, 0.1)]), 3)
    ref_t = t0 + np.round(np.concatenate([np.arange(0.0, 6.0 + 1e-9, 0.1), np.arange(6.35, 10.0, 0.1)]), 3)
    truth = lambda t: np.where(t - t0 > 6.1, 90.0, 0.0)  # noqa: E731  (the heading, degrees: the test repeats it)
    d = tmp_path / "run"
    d.mkdir()
    write_tum(str(d / "trajectory.tum"), trajectory(est_t, truth(est_t) + ERROR_DEG))
    write_tum(str(tmp_path / "truth.tum"), trajectory(ref_t, truth(ref_t)))
    (d / "summary.json").write_text(json.dumps({"frames": 100, "frames_with_pose": len(est_t), "bag_duration_s": 10.0,
                                                "recording_start_s": t0, "time_offset_s": 0.0, "bag": "hand.bag"}))
    return d, tmp_path / "truth.tum", est_t


def evaluate(run_dir, reference, out, *extra):
    assert cli_main(["evaluate", str(run_dir), "--reference", str(reference), "--out", str(out), *extra]) == 0
    return json.loads((out / "report.json").read_text())


def test_the_evaluation_section_changes_the_gaps_listed_and_compared(run, tmp_path, capsys):
    run_dir, truth, est_t = run
    default = evaluate(run_dir, truth, tmp_path / "default")
    assert default["coverage"]["gaps_s"] == []                                 # 0.3 s < min_gap 0.5 s
    inside = np.sum((est_t > 106.0) & (est_t < 106.35))                        # poses in the reference's gap
    assert default["heading_ape"]["rmse_deg"] == pytest.approx(ERROR_DEG, abs=1e-6)  # 0.35 s > max_gap 0.2 s
    assert default["heading_ape"]["n"] == len(est_t) - inside

    params = tmp_path / "eval.yaml"
    params.write_text("evaluation:\n  min_gap: 0.25\n  max_gap: 0.4\n")
    changed = evaluate(run_dir, truth, tmp_path / "changed", "--params", str(params))
    assert changed["coverage"]["gaps_s"] == [pytest.approx([4.0, 4.3])]      # now listed, seconds since start
    assert changed["heading_ape"]["n"] == len(est_t)                          # compared across the gap too
    # ... where the reference turns by 90° over its 0.35 s gap: interpolated there between its unit heading
    # vectors (0° and 90°), as evaluation.interp_yaw does ("linearly on the unit circle")
    gap = est_t[(est_t > 106.0) & (est_t < 106.35)]
    a = (gap - 106.0) / 0.35
    err = np.where(gap - 100.0 > 6.1, 90.0, 0.0) + ERROR_DEG - np.degrees(np.arctan2(a, 1.0 - a))
    expected = math.sqrt((np.sum(err ** 2) + (len(est_t) - len(gap)) * ERROR_DEG ** 2) / len(est_t))
    assert changed["heading_ape"]["rmse_deg"] == pytest.approx(expected, rel=1e-6)
    assert "no gap over 0.5 s" in (tmp_path / "default" / "report.md").read_text()
    capsys.readouterr()


def test_a_bad_key_is_one_line_naming_it(run, tmp_path, capsys):
    run_dir, truth, _ = run
    bad = tmp_path / "bad.yaml"
    bad.write_text("evaluation:\n  min_gaps: 0.2\n")
    code = cli_main(["evaluate", str(run_dir), "--reference", str(truth), "--out", str(tmp_path / "o"),
                     "--params", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "bad.yaml: evaluation.min_gaps: unknown parameter; did you mean 'min_gap'" in err[0]
    assert not (tmp_path / "o" / "report.json").exists()


def test_the_stretches_without_an_absolute_update_say_why():
    """Accepted marker yaws every 0.1 s over 0-2 s and 5-6 s; in between, rejected ones (tracking gate, and one
    gated by the filter) up to 3.5 s, then nothing; the run ends at 8 s: two stretches, each with its reason."""
    from aruco_abs_orient.offline.evaluate import no_update_spans

    acc_t = np.round(np.concatenate([np.arange(0.0, 2.05, 0.1), np.arange(5.0, 6.05, 0.1)]), 3)
    rej_t = np.round(np.arange(2.5, 3.55, 0.1), 3)
    gate = "tracking gate: far from its predicted bearing (moved marker, or the filter is off)"
    reasons = [""] * len(acc_t) + [gate] * (len(rej_t) - 1) + ["filter: gated"]
    obs = {"time": np.concatenate([acc_t, rej_t]), "accepted": np.array([True] * len(acc_t) + [False] * len(rej_t)),
           "reason": np.array(reasons)}
    spans = no_update_spans(obs, 0.0, 8.0, min_gap=0.5)
    assert [(round(s.start, 3), round(s.end, 3), s.reason) for s in spans] == [
        (2.0, 5.0, "tracking gate: far from its predicted bearing"), (6.0, 8.0, "no marker seen")]
    assert no_update_spans(obs, 0.0, 8.0, min_gap=3.5) == []


def test_frames_without_a_per_marker_sigma_are_judged_on_the_rest(run, tmp_path):
    """A frame's yaw from a resection (no prism at that time) is written without a per-marker σ: the σ
    consistency is computed from the rows that have one (hand-made: residual 0.02° against σ 0.04° → RMS 0.5),
    the residuals from all accepted rows, and a marker seen only in such frames has no σ column of its own."""
    run_dir, truth, est_t = run
    head = ("time,id,method,azimuth_deg,elevation_deg,pixel_u,pixel_v,angular_size_deg,bearing_sigma_deg,range_m,"
            "yaw_deg,yaw_sigma_deg,residual_deg,accepted,reason\n")
    rows = [f"{t:.3f},{mid},tracked,10,0,1,1,2,0.01,{rng},0.5,{sigma},{res},1,\n"
            for t in est_t[:20] for mid, rng, sigma, res in ((3, "5.0", "0.04", "0.02"), (7, "", "", "0.06"))]
    (run_dir / "observations.csv").write_text(head + "".join(rows))
    report = evaluate(run_dir, truth, tmp_path / "out")
    z = report["normalised_residuals"]
    assert z["n"] == 20 and z["rms"] == pytest.approx(0.5, rel=1e-6)
    assert report["residuals"]["rmse_deg"] == pytest.approx(math.sqrt((0.02 ** 2 + 0.06 ** 2) / 2), rel=1e-6)

#!/usr/bin/env python3
"""Boresight calibration benchmark: a 0.5° boresight error, recovered and removed.

Renders one synthetic scenario twice with the same seed (same track, markers, VO drift, prism noise):
once with a ``--boresight-deg`` camera rotation error (rendered, not published) and once without.
Then, in one run:

1. ``timesync`` (VO-heading coherence) then ``calibrate`` with the time offset refined beside the
   boresight (as ``make demo`` does, nothing hidden is used) on the erroneous recording → boresight
   error vs the hidden truth (deg, per axis and as one rotation angle) with the estimator's σ, and the
   time offset's error;
2. ``process`` (the offline pipeline) three times: the erroneous recording with the nominal transform
   and the coherence offset (naive), with the calibrated transform and the refined offset (ours), and
   the error-free recording with the true offset (the no-error level);
   for each the heading (yaw) RMSE of base_link against truth.tum and the position-in-frame bias of the
   per-marker yaws (evaluation.error_by_frame_position: max |mean| over azimuth×elevation bins with
   ≥ ``--min-count`` samples, and the mean per elevation band).

    PYTHONPATH=src .venv/bin/python bench/calibration.py [--preset easy] [--duration 60] [--every 3]
        [--work /tmp/aruco_calib_bench] [--boresight-deg 0.5]

Scenarios are cached in ``--work`` (re-rendered only with ``--force``).

``--honesty`` runs another section instead: over ``--seeds`` seeds of each of the generator's worlds
(``WORLDS``: easy, ci, ci with the odometry tilted as it started, ci-realistic and realistic, crabbing and not,
with and without the VO's tilt drift; ``--world`` to choose, ``--fps``/``--width`` to change the camera), the
user's CLI workflow with calibrate's defaults (bench/_workflow.py; the camera's rolling-shutter readout given as
known), per run the error/σ of roll, pitch, yaw, the time offset, the lens offset and the lenses' relative rotation
(roll, pitch, yaw of the back lens against the front one), the heading model chosen, the calibrated heading RMSE
beside the one with the true calibration, and the self-check's findings; then the share within 3 σ. A refusal is
counted and its reason printed.

Measured (demo preset, 60 s, 30 fps, 3840×1920, seed 3, every 3rd image, 2 cores): boresight error
0.0070° (−0.0017, −0.0022, −0.0064 rpy; σ 0.0007, 0.0008, 0.0081); time offset 396.4 ms from the VO
heading, refined to 366.86 ± 0.35 ms (truth 367.0); heading RMSE naive 0.756°, calibrated 0.0203°,
no-error recording 0.0180° (the difference is the +0.005° left of the boresight yaw, within its σ);
frame-position bias 0.986° → 0.013° (no-error 0.008°).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import os
import sys
import time

import numpy as np
import yaml

from aruco_abs_orient.calibration import Unknowns
from aruco_abs_orient.evaluation import error_by_frame_position, interp_yaw, yaw_ape
from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.offline.bagio import read_bag_data
from aruco_abs_orient.offline.calibrate import calibrate_bag, collect_observations
from aruco_abs_orient.offline.process import RunSetup, process_bag
from aruco_abs_orient.offline.sync import estimate_bag_offset
from aruco_abs_orient.synthetic.bag import generate
from aruco_abs_orient.synthetic.scenario import PRESETS
from aruco_abs_orient.transforms import matrix_to_rpy, yaw_of
from aruco_abs_orient.tum import read_tum


def scenario(work: str, name: str, config, force: bool) -> str:
    out = os.path.join(work, name)
    if force or not os.path.exists(os.path.join(out, "hidden.yaml")):
        t0 = time.perf_counter()
        generate(config, out, progress=True, force=True)
        print(f"rendered {name} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return out


def evaluate(out_dir: str, truth_path: str, min_count: int):
    """Heading RMSE (deg) of the processed trajectory and the frame-position bias of per-marker yaws."""
    truth = read_tum(truth_path)
    truth_yaw = yaw_of(truth.rotations)
    est = read_tum(os.path.join(out_dir, "trajectory.tum"))
    ape = yaw_ape(est.stamps, yaw_of(est.rotations), truth.stamps, truth_yaw)
    rmse = math.degrees(math.sqrt(float(np.mean(ape.error ** 2))))
    t, az, el, yaw = [], [], [], []
    with open(os.path.join(out_dir, "observations.csv")) as f:
        for row in csv.DictReader(f):
            if row["yaw_deg"] and row["accepted"] == "1":
                t.append(float(row["time"]))
                az.append(math.radians(float(row["azimuth_deg"])))
                el.append(math.radians(float(row["elevation_deg"])))
                yaw.append(math.radians(float(row["yaw_deg"])))
    ref, ok = interp_yaw(np.array(t), truth.stamps, truth_yaw, max_gap=0.2)
    err = np.array(yaw)[ok] - ref[ok]
    bias = error_by_frame_position(np.array(az)[ok], np.array(el)[ok], err, min_count=min_count)
    mean_bias = math.degrees(float(np.mean((err + math.pi) % (2 * math.pi) - math.pi)))
    return rmse, bias, mean_bias, int(ok.sum())


#: the worlds of the honesty table: (name, preset, changes, duration s); --duration overrides the durations
WORLDS = (
    ("easy", "easy", {}, 30.0),
    ("ci", "ci", {}, 20.0),
    ("ci, odometry tilted as it started", "ci", {"odom_levelled": False, "roll_pitch_deg": 2.0}, 20.0),
    ("ci-realistic", "ci-realistic", {}, 20.0),
    ("ci-realistic, crabbing 2°", "ci-realistic", {"crab_deg": 2.0}, 20.0),
    ("realistic", "realistic", {}, 20.0),
    ("realistic, crabbing 2°", "realistic", {"crab_deg": 2.0}, 20.0),
    ("realistic, no VO tilt drift", "realistic", {"vo_tilt_drift_deg_per_min": 0.0}, 20.0),
)


def _honesty_run(a, preset: str, changes: dict, duration: float, seed: int):
    """One world and seed through the CLI workflow: (run dict, scenario dir); the camera's rolling-shutter readout
    given to calibrate as known (a camera's datasheet figure), not estimated."""
    import _workflow

    from aruco_abs_orient.synthetic.scenario import ScenarioConfig

    base = dict(PRESETS[preset].to_dict(), seed=seed, duration=a.duration or duration, **changes)
    base.update({k: v for k, v in (("width", a.width), ("fps", a.fps)) if v})
    config = ScenarioConfig.from_dict(base)
    scen = _workflow.scenario_dir(config, "calibration", a.workers)
    readout = ["--readout-ms", 1e3 * config.rolling_shutter_readout] if config.rolling_shutter_readout else []
    run = _workflow.workflow(scen, os.path.join(scen, "runs", "honesty"), readout)
    if "refused" not in run:
        run["rmse_true"] = _workflow.true_calibration_rmse(scen, os.path.join(scen, "runs", "true_calibration"))
    return run


def _z_scores(run) -> list:
    """error/σ of roll, pitch, yaw, the time offset and (when estimated) the lens offset and the three components
    of the back lens's rotation against the front one (NaN where not estimated)."""
    rep, hidden = run["report"], run["hidden"]
    err = np.subtract(rep["boresight_rpy_deg"], hidden["boresight"]["rpy_deg"])
    z = list(err / np.array(rep["boresight_sigma_deg"]))
    z.append(run["offset_err_ms"] / rep["time_offset_sigma_ms"])
    lens_err = rep.get("lens_offset_mm", 0.0) - 1e3 * hidden["realism"]["camera_lenses"]["lens_offset_m"]
    z.append(lens_err / rep["lens_offset_sigma_mm"] if rep.get("lens_offset_sigma_mm") else float("nan"))
    rot_err = np.subtract(rep.get("lens_rotation_deg", [math.nan] * 3),
                          hidden["realism"]["camera_lenses"]["back_lens_rotation_deg"])
    z += list(rot_err / np.array(rep.get("lens_rotation_sigma_deg", [math.nan] * 3)))
    return z


def honesty(a) -> int:
    """Are calibrate's σ honest, with its defaults, on recordings of every world the generator has? Per world and
    seed: the CLI workflow (bench/_workflow.py: timesync, the calibrate line it suggests with the lenses estimated
    and the heading model chosen by the data, process with the calibration, evaluate), the error over σ of roll,
    pitch, yaw, the time offset, the lens offset and the lenses' relative rotation, the model chosen, the calibrated
    heading RMSE beside the RMSE with the true calibration (the recording's floor), and what the self-check of the
    processed run found."""
    names = [w[0] for w in WORLDS]
    unknown = [w for w in a.world or () if w not in names]
    if unknown:
        print(f"--world: unknown {unknown}; the worlds: {names}", file=sys.stderr)
        return 2
    print(f"# bench/calibration.py --honesty: seeds {a.seed}..{a.seed + a.seeds - 1}, width {a.width or 'preset'}, "
          f"fps {a.fps or 'preset'}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    zs, rmse, findings, refused, models = [], {}, [], [], {}
    print(f"{'world':36s} {'seed':>4s} {'model':>8s} {'roll z':>7s} {'pitch z':>7s} {'yaw z':>6s} {'τ z':>6s} "
          f"{'lens z':>6s} {'rotation z (r, p, y)':>20s} {'RMSE deg':>9s} {'true cal':>9s} {'ratio':>6s} {'findings'}")
    for name, preset, changes, duration in WORLDS:
        if a.world and name not in a.world:
            continue
        for seed in range(a.seed, a.seed + a.seeds):
            run = _honesty_run(a, preset, changes, duration, seed)
            if "refused" in run:
                refused.append((name, seed))
                print(f"{name:36s} {seed:4d} refused: {run['refused']}", flush=True)
                continue
            z = _z_scores(run)
            zs += [x for x in z if math.isfinite(x)]
            model = run["report"]["heading_model"]
            models[model] = models.get(model, 0) + 1
            rmse.setdefault(name, []).append((run["rmse"], run["rmse_true"]))
            findings += [k for k in run["findings"] if k in ("camera_tilt", "boresight_yaw", "time_offset")]
            print(f"{name:36s} {seed:4d} {model:>8s} {z[0]:+7.2f} {z[1]:+7.2f} {z[2]:+6.2f} {z[3]:+6.2f} "
                  f"{z[4]:+6.2f} {' '.join(f'{x:+6.2f}' for x in z[5:8]):>20s} {run['rmse']:9.4f} "
                  f"{run['rmse_true']:9.4f} {run['rmse'] / run['rmse_true']:6.2f} "
                  f"{', '.join(run['findings']) or '—'}", flush=True)
    z = np.abs(np.array(zs))
    if not len(z):
        print("no world calibrated: nothing to judge", file=sys.stderr)
        return 1
    print(f"\n|error|/σ ≤ 3 in {100 * np.mean(z <= 3):.1f} % of {len(z)} estimates (target ≥ 95 %), beyond 5: "
          f"{int(np.sum(z > 5))} (target 0); heading models: {models}; refused: {refused or 'none'}")
    for name, values in rmse.items():
        ours, true = np.array(values).T
        print(f"calibrated heading RMSE, {name}: mean {np.mean(ours):.4f}° (true calibration {np.mean(true):.4f}°, "
              f"ratio {np.mean(ours) / np.mean(true):.2f}), worst {np.max(ours):.4f}°")
    print(f"self-check findings after calibrating (time offset, tilt, yaw): {len(findings)} (target 0)")
    return 0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", choices=sorted(PRESETS),
                    help="scenario preset (default: easy; realistic for --honesty)")
    ap.add_argument("--duration", type=float,
                    help="seconds of images (default: the preset's; 20 s for --honesty, which bounds its time)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--boresight-deg", type=float, default=0.5)
    ap.add_argument("--every", type=int, default=3, help="calibrate on every N-th image (default 3)")
    ap.add_argument("--min-count", type=int, default=30, help="samples per bin for the frame-position bias")
    ap.add_argument("--work", default="/tmp/aruco_calib_bench")
    ap.add_argument("--force", action="store_true", help="re-render the scenarios")
    g = ap.add_argument_group("honesty of calibrate's σ across the generator's worlds (rendered, the CLI workflow)")
    g.add_argument("--honesty", action="store_true", help="run this section instead of the one above")
    g.add_argument("--seeds", type=int, default=3, help="seeds per world, from --seed (default 3)")
    g.add_argument("--world", action="append", metavar="NAME",
                   help=f"only this world (repeatable; quote it): {'; '.join(w[0] for w in WORLDS)}")
    g.add_argument("--width", type=int, help="image width, px (default: each preset's)")
    g.add_argument("--fps", type=float, help="images per second (default: each preset's)")
    g.add_argument("--workers", type=int, default=2, help="render processes")
    return ap


def _calibrated(a, cfg, bag: str, markers: MarkerMap, offset: float, true_T: np.ndarray):
    """Calibrate ``bag`` (the coherence offset refined) and print how close it came to the truth; returns
    (the bag's data, the calibrated base_T_camera, the coherence offset, the refined one)."""
    t0 = time.perf_counter()
    coarse = estimate_bag_offset(bag)["timesync"].offset
    obs = collect_observations(bag, markers, every=a.every)
    cal = calibrate_bag(bag, markers, coarse, observations=obs, unknowns=Unknowns(time_offset=True))
    refined = coarse + cal.time_offset_delta
    t_cal = time.perf_counter() - t0
    data = read_bag_data(bag)
    calibrated = cal.apply(data.base_T_camera)
    truth_rpy = np.degrees(matrix_to_rpy(true_T[:3, :3] @ data.base_T_camera[:3, :3].T))
    est_rpy = np.degrees(cal.boresight_rpy)
    dR = calibrated[:3, :3].T @ true_T[:3, :3]
    angle = math.degrees(math.acos(min(1.0, (float(np.trace(dR)) - 1.0) / 2.0)))

    print(f"\nboresight calibration: preset {a.preset}, {cfg.duration:g} s at {cfg.fps:g} fps, "
          f"{cfg.width}x{cfg.width // 2}, seed {a.seed}, calibrated on every {a.every}. image")
    print(f"  observations {cal.n_used}/{cal.n_observations} of {cal.n_markers} markers from {obs.frames} images; "
          f"driving {cal.moving_time:.0f} s ({cal.n_heading} track headings, "
          f"RMS {math.degrees(cal.heading_rms):.3f}°); "
          f"{t_cal:.0f} s (detection + estimate)")
    print(f"  truth rpy (deg)     {truth_rpy[0]:+.4f} {truth_rpy[1]:+.4f} {truth_rpy[2]:+.4f}")
    print(f"  estimate rpy (deg)  {est_rpy[0]:+.4f} {est_rpy[1]:+.4f} {est_rpy[2]:+.4f}   "
          f"σ {' '.join(f'{x:.4f}' for x in np.degrees(cal.boresight_sigma))}")
    print(f"  error (deg)         {' '.join(f'{x:+.4f}' for x in est_rpy - truth_rpy)}   "
          f"rotation angle {angle:.4f}° (target ≤ 0.03°)")
    print(f"  bearing residual RMS {math.degrees(cal.residual_rms_before):.4f}° before, "
          f"{math.degrees(cal.residual_rms_after):.4f}° after")
    print(f"  time offset: true {1e3 * offset:.1f} ms, coherence {1e3 * coarse:.1f} ms, refined {1e3 * refined:.2f} ms "
          f"± {1e3 * cal.time_offset_sigma:.2f} (error {1e3 * (refined - offset):+.2f} ms)", flush=True)
    return data, calibrated, coarse, refined


def _print_runs(runs: dict) -> None:
    """The table of the processed runs: heading RMSE, mean yaw error, frame-position bias; the ratios."""
    print(f"\n  {'run':38s} {'heading RMSE':>13s} {'mean yaw err':>13s} {'frame-pos bias':>15s}  per-marker yaws")
    for name, (rmse, bias, mean_bias, n) in runs.items():
        print(f"  {name:38s} {rmse:12.4f}° {mean_bias:+12.4f}° {math.degrees(bias.max_abs_bias):14.4f}°  {n}")
    naive, ours, level = (runs[k][0] for k in runs)
    print(f"\n  heading RMSE: ours/no-error {ours / level:.3f}, naive/ours {naive / ours:.2f}")
    for name, (_, bias, _, _) in runs.items():
        by_el = ", ".join("—" if not np.isfinite(x) else f"{math.degrees(x):+.3f}" for x in bias.by_elevation)
        print(f"  mean yaw error by elevation band ({name}): {by_el} deg")


def main(argv=None) -> int:
    a = _parser().parse_args(argv)
    if a.honesty:
        return honesty(a)
    a.preset = a.preset or "easy"

    base = PRESETS[a.preset]
    changes = {"seed": a.seed, "boresight_deg": a.boresight_deg}
    if a.duration:
        changes["duration"] = a.duration
    cfg = dataclasses.replace(base, **changes)
    tag = f"{a.preset}_s{a.seed}_d{cfg.duration:g}"
    err_dir = scenario(a.work, f"{tag}_b{a.boresight_deg:g}", cfg, a.force)
    ok_dir = scenario(a.work, f"{tag}_b0", dataclasses.replace(cfg, boresight_deg=0.0), a.force)
    with open(os.path.join(err_dir, "hidden.yaml")) as f:
        hidden = yaml.safe_load(f)
    offset = float(hidden["camera_time_offset"])
    markers = MarkerMap.load(os.path.join(err_dir, "markers.yaml"))
    bag = os.path.join(err_dir, "scenario.bag")
    true_T = np.array(hidden["base_T_camera_true"])
    data, calibrated, coarse, refined = _calibrated(a, cfg, bag, markers, offset, true_T)

    runs = {}
    for name, d, T, tau in (("naive (nominal tf, coherence offset)", err_dir, data.base_T_camera, coarse),
                            ("ours (calibrated tf, refined offset)", err_dir, calibrated, refined),
                            ("no-error level (true offset)", ok_dir, None, offset)):
        out = os.path.join(a.work, f"{tag}_process_{len(runs)}")
        bd = read_bag_data(os.path.join(d, "scenario.bag"))
        if T is not None:
            bd = dataclasses.replace(bd, base_T_camera=T)
        process_bag(os.path.join(d, "scenario.bag"), markers, out, RunSetup(tau, progress=False), data=bd)
        runs[name] = evaluate(out, os.path.join(d, "truth.tum"), a.min_count)
    _print_runs(runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())

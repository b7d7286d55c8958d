#!/usr/bin/env python3
"""Issue 17 figures on the realistic world (the hall: pillars, posters, lights, exposure changes, blur,
JPEG 85, a wandering platform, a VO drifting in yaw and tilt, a stitch seam, a camera clock 20 ppm fast),
3840 px at 30 fps, on seeds the generator was not tuned on. One table across seeds:

  per seed    the user's workflow through the CLI, as tools/demo.sh runs it: timesync, calibrate
              (--refine-time-offset; the VO's track heading, its default), process with the calibration,
              evaluate against truth.tum:
              calibrated heading RMSE, p95 and coverage; the boresight yaw error against hidden.yaml
              and the σ calibrate reported; the offline throughput (frames/s and × real time)
  rolling     the same with a 30 ms rolling shutter (preset realistic-rs), without correction (calibrate
              without --readout: the pipeline assumes a global shutter), then with `calibrate --readout`
              (the readout estimated and used by process; its error against the truth printed)
  spin        the same drive processed with the calibration of a calibration run of its seed (preset
              calibration-rs: the same world, camera and clocks, a 360° spin in place at up to 60°/s beside 4
              more markers 0.2 and 2.6 m high, 2 m away, then 19 s of the drive): timesync and
              `calibrate --readout` on that run, its boresight, readout and time offset used by process
  columns     also the tilt error of the processed trajectory (RMS angle between the true and estimated
              base_link z axes), the boresight roll/pitch/yaw errors, the readout and its error
  detection   detection rate by range on frames of the first seed (every --every-nth frame, the bag's
              JPEGs re-rendered): this package's full-frame search vs plain OpenCV on the same frames
              (the package's backend call that bench/detection.py's plain comparison makes). A marker
              counts as expected when within 75° of facing the camera, at most 14 m away, and not
              hidden by a pillar (2-D line of sight against the hall's pillars).

Scenarios are cached in .cache/bench/realism/ (keyed by a digest of their whole configuration). The
default run is bounded (20 s scenarios, 3 seeds); --duration 60 for the full demo length. A drive of this world
hardly determines the readout (its markers are all within ~20° of the horizon; 20 s, seed 101: σ 9.5 ms,
calibrate refuses, the table prints why): the spin pass's calibration run does (its scenarios are 30 s whatever
--duration). Measured (--seeds 101 102 103 104 105 106 107 108 109 110, 20 s, load 3-5 on 2 cores):
global shutter RMSE 0.0181° mean, 0.0311° worst, p95 0.0313° mean, 0.0562° worst, coverage 99.7 %, boresight
yaw within 2.5 σ in 10 of 10 (at most 1.54 σ), offset error -0.6 to +1.2 ms; 30 ms rolling shutter uncorrected
0.0246° / 0.0396° mean, 0.0627° / 0.1012° worst; with --readout 6 of 10 refused (σ 7.8-20 ms), the 4 taken
5-9 ms low; seed 101 before issue 17's calibration fixes 0.170° and 0.192°. Detection by range on seed 101
(30 frames): 9-11 m 73 % vs plain OpenCV 54 %, 11-14 m 38 % vs 19 %. Spin pass (--passes spin, same seeds,
load 2-3): readout 29.7-30.6 ms (error <= 0.6 ms, none refused); the drives processed with it RMSE 0.0233° mean,
0.0517° worst, p95 0.0369° / 0.0659°, coverage 99.7 %; boresight yaw within 2.5 σ in 9 of 10 (seed 101: 3.54 σ).
The EKF figure needs the ROS replay (make demo) and is not here.

Usage: bench/realism.py [--seeds 101 102 103] [--duration 20] [--width 3840] [--no-rolling]
                        [--passes global rolling readout spin detection] [--every-nth 20] [--workers 2]
"""
import argparse
import dataclasses
import hashlib
import json
import math
import os
import re
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from aruco_abs_orient.camera import angle_between  # noqa: E402
from aruco_abs_orient.detection import DetectorParams, MarkerDetector  # noqa: E402
from aruco_abs_orient.synthetic.bag import generate  # noqa: E402
from aruco_abs_orient.synthetic.render import decode_jpeg, encode_jpeg  # noqa: E402
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario  # noqa: E402
from aruco_abs_orient.synthetic.world import render_frame  # noqa: E402
from aruco_abs_orient.transforms import quat_to_matrix  # noqa: E402
from aruco_abs_orient.tum import read_tum  # noqa: E402

CLI = [sys.executable, "-m", "aruco_abs_orient.offline.cli"]
RANGE_BINS = [(0, 3), (3, 5), (5, 7), (7, 9), (9, 11), (11, 14)]


def scenario_dir(config) -> str:
    digest = hashlib.sha1(json.dumps(config.to_dict(), sort_keys=True).encode()).hexdigest()[:10]
    key = f"{config.world}_s{config.seed}_{config.duration:g}s_rs{config.rolling_shutter_readout * 1e3:g}_{digest}"
    out = os.path.join(ROOT, ".cache", "bench", "realism", key)
    if not os.path.exists(os.path.join(out, "scenario.bag")):
        print(f"rendering {out}", file=sys.stderr, flush=True)
        generate(config, out, progress=False, force=True, workers=ARGS.workers)
    return out


def cli(*args) -> str:
    proc = subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True)
    if proc.returncode:
        raise RuntimeError(f"{' '.join(map(str, args[:2]))} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return proc.stdout


def offset_from(text: str):
    found = re.findall(r"--time-offset ([-0-9.]+)", text)
    return float(found[-1]) if found else None


def tilt_rmse_deg(run: str, truth_path: str) -> float:
    """RMS (deg) of the angle between the processed and the true base_link z axes (the tilt error: roll and
    pitch together), the trajectory on the total-station clock against truth.tum."""
    est, truth = read_tum(os.path.join(run, "trajectory.tum")), read_tum(truth_path)
    _, q, ok = truth.interpolate(est.stamps)
    z_est, z_true = est.rotations[ok][:, 2, :], quat_to_matrix(q[ok])[:, 2, :]   # map z in base_link
    return math.degrees(math.sqrt(float(np.mean(np.square(angle_between(z_est, z_true))))))


def workflow(scen: str, run: str, readout: bool = False, calib_scen: str = None) -> dict:
    """timesync → calibrate → process → evaluate on one scenario, as tools/demo.sh does (``readout``:
    calibrate estimates the rolling-shutter readout). With ``calib_scen`` timesync and calibrate run on that
    calibration run instead, and the scenario is processed with its calibration file and time offset (the
    same camera, mounting and clocks: its seed's boresight and offset)."""
    import yaml

    os.makedirs(run, exist_ok=True)
    cal_dir = calib_scen or scen
    cal_bag, cal_markers = os.path.join(cal_dir, "scenario.bag"), os.path.join(cal_dir, "markers.yaml")
    with open(os.path.join(scen, "hidden.yaml")) as f:
        hidden = yaml.safe_load(f)
    try:
        offset = offset_from(cli("timesync", cal_bag))
    except RuntimeError:
        offset = None
    offset = hidden["camera_time_offset"] if offset is None else offset
    cal = os.path.join(run, "calibration.yaml")
    extra = ["--readout"] if readout else []
    try:
        text = cli("calibrate", cal_bag, "--markers", cal_markers, "--time-offset", offset, "--refine-time-offset",
                   "--every", 3, "--out", cal, "--json", *extra)
    except RuntimeError as e:   # refused: the reason is the figure
        return {"refused": str(e).strip().splitlines()[-1][-300:]}
    report = json.loads(next(line for line in text.splitlines() if line.startswith("{")))
    offset = offset_from(text) or offset
    bag, markers = os.path.join(scen, "scenario.bag"), os.path.join(scen, "markers.yaml")
    t0 = time.perf_counter()
    cli("process", bag, "--markers", markers, "--out", run, "--time-offset", offset, "--calibration", cal, "--quiet")
    wall = time.perf_counter() - t0
    cli("evaluate", run, "--reference", os.path.join(scen, "truth.tum"))
    with open(os.path.join(run, "report.json")) as f:
        ev = json.load(f)
    with open(os.path.join(run, "summary.json")) as f:
        summary = json.load(f)
    err = np.subtract(report["boresight_rpy_deg"], hidden["boresight"]["rpy_deg"])
    true_readout = 1e3 * hidden["config"].get("rolling_shutter_readout", 0.0)
    return {"rmse": ev["heading_ape"]["rmse_deg"], "p95": ev["heading_ape"]["p95_deg"],
            "coverage": ev["coverage"]["share"], "roll_err": err[0], "pitch_err": err[1], "yaw_err": err[2],
            "yaw_sigma": report["boresight_sigma_deg"][2],
            "offset_err_ms": (offset - hidden["camera_time_offset"]) * 1e3,
            "readout_ms": summary.get("readout_ms", 0.0),
            "readout_err_ms": summary.get("readout_ms", 0.0) - true_readout,
            "tilt_rmse": tilt_rmse_deg(run, os.path.join(scen, "truth.tum")),
            "fps": summary["frames"] / wall, "rtf": summary["bag_duration_s"] / wall}


def occluded(hall, eye, target) -> bool:
    """Whether the horizontal line of sight eye → target passes through one of the hall's pillars."""
    for px, py, r in hall.pillars:
        d = target[:2] - eye[:2]
        s = np.clip(np.dot([px, py] - eye[:2], d) / np.dot(d, d), 0.0, 1.0)
        if math.hypot(*(eye[:2] + s * d - [px, py])) < r:
            return True
    return False


def detection_by_range(config, every: int):
    sc = Scenario(config)
    det = MarkerDetector(config.dictionary, DetectorParams())
    quality = config.jpeg_quality or 85
    counts = {b: [0, 0, 0, 0] for b in RANGE_BINS}  # expected, ours, plain OpenCV, hidden by a pillar
    frames = range(0, sc.frame_times.size, every)
    for index in frames:
        t = float(sc.frame_times[index])
        img = decode_jpeg(encode_jpeg(render_frame(sc, index), quality))
        k, ids, bearings = sc.marker_bearings(np.array([t]), max_range=14.0, max_incidence_deg=75.0)
        eye = sc.map_T_camera(t)[:3, 3]
        ours = {o.id: o.centre for o in det.detect(img)}
        plain = set(det.backend.detect(img, det.params.min_marker_perimeter_px)[0])
        for mid, b in zip(ids.tolist(), bearings):
            pos = sc.markers[mid].position
            rng_m = float(np.linalg.norm(pos - eye))
            key = next((lo, hi) for lo, hi in RANGE_BINS if lo <= rng_m < hi)
            if occluded(sc.world, eye, pos):
                counts[key][3] += 1
                continue
            counts[key][0] += 1
            counts[key][1] += mid in ours and float(angle_between(ours[mid], b)) < math.radians(0.5)
            counts[key][2] += mid in plain
    return len(frames), counts


#: the tables: title, the scenario preset processed, calibrate --readout, the preset calibrate runs on
#: (None: the processed scenario itself)
PASSES = {
    "global": ("global shutter", "realistic", False, None),
    "rolling": ("30 ms rolling shutter, uncorrected (calibrate without --readout)", "realistic-rs", False, None),
    "readout": ("30 ms rolling shutter, calibrate --readout on the same drive", "realistic-rs", True, None),
    "spin": ("30 ms rolling shutter, calibrate --readout on a calibration run (preset calibration-rs: a 360° "
             "spin in place beside markers high and low, then 19 s of the drive), the drive processed with it",
             "realistic-rs", True, "calibration-rs"),
    "detection": ("detection rate by range",),
}


def main(argv=None) -> int:
    global ARGS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--width", type=int, default=3840)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-rolling", action="store_true", help="skip the 30 ms rolling shutter passes")
    ap.add_argument("--passes", nargs="+", choices=PASSES, default=list(PASSES),
                    help="which tables (default all): " + "; ".join(f"{k}: {v[0]}" for k, v in PASSES.items()))
    ap.add_argument("--every-nth", type=int, default=20, help="frames for the detection-by-range table")
    ARGS = ap.parse_args(argv)
    print(f"# bench/realism.py: realistic world, {ARGS.width}x{ARGS.width // 2}, 30 fps, {ARGS.duration:g} s, "
          f"seeds {ARGS.seeds}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    passes = [PASSES[k] for k in ARGS.passes if k != "detection" and not (ARGS.no_rolling and k != "global")]
    header = f"{'seed':>5} {'RMSE deg':>9} {'p95 deg':>8} {'coverage':>9} {'tilt RMS':>9} {'roll err':>9} " \
             f"{'pitch err':>9} {'yaw err deg':>12} {'yaw σ deg':>10} {'|err|/σ':>8} {'offset err ms':>14} " \
             f"{'readout ms':>11} {'ro err ms':>10} {'frames/s':>9} {'x real time':>12}"
    for title, preset, readout, calib_preset in passes:
        rows = []
        for seed in ARGS.seeds:
            config = dataclasses.replace(PRESETS[preset], seed=seed, duration=ARGS.duration, width=ARGS.width)
            scen = scenario_dir(config)
            calib = calib_preset and scenario_dir(dataclasses.replace(PRESETS[calib_preset], seed=seed,
                                                                      width=ARGS.width))
            tag = preset + ("_readout" if readout else "") + (f"_{calib_preset}" if calib_preset else "")
            rows.append((seed, workflow(scen, os.path.join(scen, "runs", tag), readout, calib)))
        print(f"\n## {title} ({preset})\n{header}")
        for seed, r in rows:
            if "refused" in r:
                print(f"{seed:>5} calibrate refused: {r['refused']}")
                continue
            print(f"{seed:>5} {r['rmse']:>9.4f} {r['p95']:>8.4f} {100 * r['coverage']:>8.1f}% {r['tilt_rmse']:>9.4f} "
                  f"{r['roll_err']:>+9.4f} {r['pitch_err']:>+9.4f} {r['yaw_err']:>+12.4f} {r['yaw_sigma']:>10.4f} "
                  f"{abs(r['yaw_err']) / r['yaw_sigma']:>8.2f} {r['offset_err_ms']:>+14.2f} {r['readout_ms']:>11.1f} "
                  f"{r['readout_err_ms']:>+10.1f} {r['fps']:>9.1f} {r['rtf']:>12.2f}")
        done = [r for _, r in rows if "refused" not in r]
        if done:
            within = np.mean([abs(r["yaw_err"]) <= 2.5 * r["yaw_sigma"] for r in done])
            mean = {k: np.mean([r[k] for r in done]) for k in ("rmse", "p95", "coverage", "tilt_rmse")}
            print(f"{'mean':>5} {mean['rmse']:>9.4f} {mean['p95']:>8.4f} {100 * mean['coverage']:>8.1f}% "
                  f"{mean['tilt_rmse']:>9.4f}")
            print(f"{'worst':>5} {max(r['rmse'] for r in done):>9.4f} {max(r['p95'] for r in done):>8.4f} "
                  f"{100 * min(r['coverage'] for r in done):>8.1f}%; boresight yaw within 2.5 σ in "
                  f"{100 * within:.0f} % of {len(done)}; "
                  f"|readout err| ≤ {max(abs(r['readout_err_ms']) for r in done):.1f} ms; "
                  f"{len(rows) - len(done)} refused  (targets: RMSE ≤ 0.04°, p95 ≤ 0.08°, coverage ≥ 95 %)",
                  flush=True)
    if "detection" not in ARGS.passes:
        return 0
    config = dataclasses.replace(PRESETS["realistic"], seed=ARGS.seeds[0], duration=ARGS.duration, width=ARGS.width)
    n, counts = detection_by_range(config, ARGS.every_nth)
    print(f"\n## detection rate by range, seed {config.seed}, {n} frames (every {ARGS.every_nth}th)")
    print(f"{'range m':>8} {'expected':>9} {'ours':>7} {'plain OpenCV':>13} {'behind a pillar':>16}")
    for (lo, hi), (exp, ours, plain, hid) in counts.items():
        if exp + hid:
            print(f"{lo:>3}-{hi:<4} {exp:>9} {100 * ours / max(exp, 1):>6.0f}% {100 * plain / max(exp, 1):>12.0f}% "
                  f"{hid:>16}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

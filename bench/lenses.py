#!/usr/bin/env python3
"""The two-lens camera: what its parallax costs with a single-centre model, and what the lens calibration gives back.

On the realistic world with a 30 ms rolling shutter (preset realistic-rs; the readout known, --readout-ms: a
calibration spin determines it, bench/realism.py --passes spin), per seed, rendered three ways from the same
seed: a camera of one centre, and two lenses 1 cm off centre with the back one turned 0.05° stitched at
infinity and at 2 m. Each recording goes through the CLI workflow (bench/_workflow.py: timesync, calibrate
--refine-time-offset, process with the calibration, evaluate against truth.tum) with

  single centre   calibrate --no-lenses, the pipeline's lenses a single centre (what the package did before)
  nominal         calibrate --no-lenses, the pipeline's lenses 1 cm at the known stitching distance (a camera's
                  table value, not calibrated)
  calibrated      calibrate's default: the lens offset and relative rotation estimated (from the nominal 0, the
                  stitching distance known)
  true camera     no calibration: processed with the rendering's true mounting, readout, lenses and time offset
                  (bench/_workflow.true_calibration), the floor a perfect calibration reaches on that rendering

With --calibration-run each rendering is calibrated, as a user calibrates a camera, on its seed's calibration run
(preset calibration-rs rendered with the same camera: the same world, mounting and clocks, a 360° spin in place
beside 4 markers 0.2 and 2.6 m high, 2 m away, then the drive) and the drive processed with that calibration; a
spin shows every marker to both lenses at one range, which a 20 s drive does for few.

The table prints the heading RMSE, p95, the markers' pairwise agreement (median), the lens offset's and
rotation's errors with their σ; the summary compares each with the single-centre rendering of its seed and
with its own true camera, and counts the seeds whose calibrated lens offset is within 2 mm and relative rotation
within 0.02°, and within 2.5 σ.

Usage: bench/lenses.py [--seeds 101 102 103] [--duration 20] [--width 3840] [--workers 2] [--calibration-run]
"""
import argparse
import dataclasses
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _workflow

from aruco_abs_orient.synthetic.scenario import PRESETS

#: the renderings of a seed: (name, scenario changes)
CAMERAS = (("one centre", {"lens_offset": 0.0, "lens_rotation_deg": 0.0}),
           ("two lenses, stitched at infinity", {"stitch_distance": math.inf}),
           ("two lenses, stitched at 2 m", {"stitch_distance": 2.0}))


def _models(config):
    """(name, calibrate's extra arguments, the params file's lines) of the three models for a rendering."""
    stitch = 0.0 if math.isinf(config.stitch_distance) else config.stitch_distance
    nominal = PRESETS["realistic-rs"].lens_offset
    return (("single centre", ["--no-lenses"], f"pipeline: {{stitch_distance: {stitch:g}}}"),
            ("nominal", ["--no-lenses"], f"pipeline: {{lens_offset: {nominal:g}, stitch_distance: {stitch:g}}}"),
            ("calibrated", [], f"pipeline: {{stitch_distance: {stitch:g}}}"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--width", type=int, default=3840)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--calibration-run", action="store_true",
                    help="calibrate on each seed's calibration run (preset calibration-rs, the same camera), not on "
                         "the drive")
    a = ap.parse_args(argv)
    where = "on each seed's calibration run (calibration-rs)" if a.calibration_run else "on the drive itself"
    print(f"# bench/lenses.py: realistic-rs, {a.width}x{a.width // 2}, {a.duration:g} s, seeds {a.seeds}, calibrated "
          f"{where}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    print(f"{'seed':>4} {'rendered':34s} {'model':14s} {'RMSE deg':>9} {'p95 deg':>8} {'agree med':>9} "
          f"{'lens err mm':>11} {'σ mm':>6} {'rot err deg (x, y, z)':>24} {'findings'}")
    table = {}
    for seed in a.seeds:
        for cam, changes in CAMERAS:
            config = dataclasses.replace(PRESETS["realistic-rs"], seed=seed, duration=a.duration, width=a.width,
                                         **changes)
            scen = _workflow.scenario_dir(config, "lenses", a.workers)
            calib_scen = None
            if a.calibration_run:
                calib_scen = _workflow.scenario_dir(dataclasses.replace(PRESETS["calibration-rs"], seed=seed,
                                                                        width=a.width, **changes), "lenses", a.workers)
            truth_rot = None
            for model, args, params in _models(config):
                if cam == "one centre" and model != "calibrated":
                    continue
                run_dir = os.path.join(scen, "runs", model.replace(" ", "_") + ("_spin" if a.calibration_run else ""))
                os.makedirs(run_dir, exist_ok=True)
                params_file = os.path.join(run_dir, "params.yaml")
                with open(params_file, "w") as f:
                    f.write(params + "\n")
                readout = ["--readout-ms", 1e3 * config.rolling_shutter_readout]
                r = _workflow.workflow(scen, run_dir, args + readout + ["--params", params_file], calib_scen,
                                       process_args=["--params", params_file])
                if "refused" in r:
                    print(f"{seed:4d} {cam:34s} {model:14s} refused: {r['refused']}", flush=True)
                    continue
                rep = r["report"]
                lenses = r["hidden"]["realism"]["camera_lenses"]
                truth_rot = np.array(lenses["back_lens_rotation_deg"])
                lens = rot = ""
                if "lens_offset_mm" in rep:
                    miss = rep["lens_offset_mm"] - 1e3 * lenses["lens_offset_m"]
                    lens = f"{miss:+11.2f} {rep['lens_offset_sigma_mm']:6.2f}"
                    err = np.array(rep["lens_rotation_deg"]) - truth_rot
                    rot = " ".join(f"{e:+.3f}" for e in err) + " ±" + "/".join(
                        f"{s:.3f}" for s in rep["lens_rotation_sigma_deg"])
                    r["lens_error"] = (miss, rep["lens_offset_sigma_mm"], err, np.array(rep["lens_rotation_sigma_deg"]))
                table[(seed, cam, model)] = r
                print(f"{seed:4d} {cam:34s} {model:14s} {r['rmse']:9.4f} {r['p95']:8.4f} {r['agreement_median']:9.4f} "
                      f"{lens:>18s} {rot:>24s} {', '.join(r['findings']) or '—'}", flush=True)
            true = _workflow.true_calibration_rmse(scen, os.path.join(scen, "runs", "true_camera"))
            table[(seed, cam, "true camera")] = {"rmse": true}
            print(f"{seed:4d} {cam:34s} {'true camera':14s} {true:9.4f}", flush=True)
    print()
    for cam, _ in CAMERAS[1:]:
        for model in ("single centre", "nominal", "calibrated"):
            ratios = [table[(s, cam, model)]["rmse"] / table[(s, "one centre", "calibrated")]["rmse"]
                      for s in a.seeds if (s, cam, model) in table and (s, "one centre", "calibrated") in table]
            agree = [table[(s, cam, model)]["agreement_median"] for s in a.seeds if (s, cam, model) in table]
            if ratios:
                print(f"{cam}, {model}: heading RMSE / one-centre rendering's {np.mean(ratios):.2f} mean, "
                      f"{np.max(ratios):.2f} worst (target ≤ 1.2 calibrated); markers' agreement median "
                      f"{np.median(agree):.4f}° (target ≤ 0.03°)")
        floor = [table[(s, cam, "calibrated")]["rmse"] / table[(s, cam, "true camera")]["rmse"]
                 for s in a.seeds if (s, cam, "calibrated") in table]
        if floor:
            print(f"{cam}, calibrated: heading RMSE / the same rendering's with its true camera {np.mean(floor):.2f} "
                  f"mean, {np.max(floor):.2f} worst")
        errors = [table[(s, cam, "calibrated")]["lens_error"] for s in a.seeds
                  if "lens_error" in table.get((s, cam, "calibrated"), {})]
        if errors:
            n = len(errors)
            print(f"{cam}, calibrated: lens offset within 2 mm in {sum(abs(e[0]) <= 2.0 for e in errors)} of {n}, "
                  f"|error|/σ ≤ 2.5 in {sum(abs(e[0]) / e[1] <= 2.5 for e in errors)} of {n} (worst "
                  f"{max(abs(e[0]) for e in errors):.2f} mm); relative rotation within 0.02° on every axis in "
                  f"{sum(np.max(np.abs(e[2])) <= 0.02 for e in errors)} of {n}, |error|/σ ≤ 2.5 in "
                  f"{sum(np.max(np.abs(e[2]) / e[3]) <= 2.5 for e in errors)} of {n} (worst "
                  f"{max(np.max(np.abs(e[2])) for e in errors):.3f}°); targets: ≥ 9 of 10")
    return 0


if __name__ == "__main__":
    sys.exit(main())

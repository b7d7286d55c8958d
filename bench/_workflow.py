"""The user's CLI workflow on rendered scenarios, shared by the benches that run it (realism, calibration, lenses).

In: a scenario configuration (rendered once into .cache/bench/<name>/, keyed by a digest of its whole
configuration) and the options of each step. Out: :func:`workflow`'s dict: the calibration's report (its JSON
line), the evaluation's heading errors and per-marker agreement against truth.tum, the self-check's findings,
the offline throughput, or ``{"refused": why}`` when calibrate refuses. Every step is the installed CLI run as a
subprocess (``python -m aruco_abs_orient.offline.cli``), as tools/demo.sh runs it.
"""
import hashlib
import json
import math
import os
import re
import subprocess
import sys
import time

import numpy as np
import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from aruco_abs_orient.calibration.io import LENSES_KEY, READOUT_KEY  # noqa: E402
from aruco_abs_orient.camera import angle_between  # noqa: E402
from aruco_abs_orient.synthetic.bag import generate  # noqa: E402
from aruco_abs_orient.transforms import matrix_to_rpy, quat_to_matrix  # noqa: E402
from aruco_abs_orient.tum import read_tum  # noqa: E402

CLI = [sys.executable, "-m", "aruco_abs_orient.offline.cli"]


def scenario_dir(config, bench: str, workers: int = 2) -> str:
    """The rendered scenario of ``config`` under .cache/bench/``bench``/ (rendered when missing)."""
    digest = hashlib.sha1(json.dumps(config.to_dict(), sort_keys=True).encode()).hexdigest()[:10]
    key = f"{config.world}_s{config.seed}_{config.duration:g}s_rs{config.rolling_shutter_readout * 1e3:g}_{digest}"
    out = os.path.join(ROOT, ".cache", "bench", bench, key)
    if not os.path.exists(os.path.join(out, "scenario.bag")):
        print(f"rendering {out}", file=sys.stderr, flush=True)
        generate(config, out, progress=False, force=True, workers=workers)
    return out


def hidden_of(scen: str) -> dict:
    """The scenario's hidden.yaml (its truth)."""
    with open(os.path.join(scen, "hidden.yaml")) as f:
        return yaml.safe_load(f)


def true_calibration(scen: str) -> str:
    """The scenario's camera as a calibration file (its true mounting, readout and lenses), in its directory."""
    hidden = hidden_of(scen)
    path = os.path.join(scen, "true_calibration.yaml")

    def entry(T):
        T = np.array(T, dtype=float)
        return {"xyz": T[:3, 3].tolist(), "rpy_deg": np.degrees(matrix_to_rpy(T[:3, :3])).tolist()}

    lenses = hidden["realism"]["camera_lenses"]
    with open(path, "w") as f:
        yaml.safe_dump({"base_link_to_camera": entry(hidden["base_T_camera_true"]),
                        "base_link_to_prism": entry(hidden["base_T_prism"]),
                        READOUT_KEY: 1e3 * hidden["config"]["rolling_shutter_readout"],
                        LENSES_KEY: {"lens_offset_mm": 1e3 * lenses["lens_offset_m"],
                                     "back_lens_rotation_deg": lenses["back_lens_rotation_deg"],
                                     "stitch_distance_m": lenses["stitch_distance_m"],
                                     "blend_band_deg": lenses["blend_band_deg"]}}, f)
    return path


def true_calibration_rmse(scen: str, run: str) -> float:
    """Heading RMSE (deg) of the scenario processed with its true calibration and time offset into ``run``: the
    floor a perfect calibration reaches on this recording."""
    bag, markers = os.path.join(scen, "scenario.bag"), os.path.join(scen, "markers.yaml")
    cli("process", bag, "--markers", markers, "--out", run, "--time-offset", hidden_of(scen)["camera_time_offset"],
        "--calibration", true_calibration(scen), "--quiet")
    cli("evaluate", run, "--reference", os.path.join(scen, "truth.tum"))
    with open(os.path.join(run, "report.json")) as f:
        return json.load(f)["heading_ape"]["rmse_deg"]


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


def workflow(scen: str, run: str, calibrate_args=(), calib_scen: str = None, process_args=()) -> dict:
    """timesync → calibrate (the line timesync suggests, plus ``calibrate_args``) → process (plus
    ``process_args``) → evaluate on one scenario, as tools/demo.sh does. With ``calib_scen`` timesync and
    calibrate run on that calibration run instead, and the scenario is processed with its calibration file and
    time offset (the same camera, mounting and clocks)."""
    os.makedirs(run, exist_ok=True)
    cal_dir = calib_scen or scen
    cal_bag, cal_markers = os.path.join(cal_dir, "scenario.bag"), os.path.join(cal_dir, "markers.yaml")
    hidden = hidden_of(scen)
    try:   # as a user would: with the marker map, then (refused) without it
        text = cli("timesync", cal_bag, "--markers", cal_markers)
    except RuntimeError:
        try:
            text = cli("timesync", cal_bag)
        except RuntimeError as e:   # no time offset: the reason is the figure
            return {"refused": "timesync: " + str(e).strip().splitlines()[-1][-400:]}
    offset, every = offset_from(text), re.findall(r"--every ([0-9]+)", text)
    cal = os.path.join(run, "calibration.yaml")
    try:   # the calibrate line timesync suggests, plus calibrate_args
        text = cli("calibrate", cal_bag, "--markers", cal_markers, "--time-offset", offset, "--refine-time-offset",
                   "--every", every[-1] if every else 1, "--out", cal, "--json", *calibrate_args)
    except RuntimeError as e:   # refused: the reason is the figure
        return {"refused": str(e).strip().splitlines()[-1][-400:]}
    report = json.loads(next(line for line in text.splitlines() if line.startswith("{")))
    offset = offset_from(text) or offset
    bag, markers = os.path.join(scen, "scenario.bag"), os.path.join(scen, "markers.yaml")
    t0 = time.perf_counter()
    cli("process", bag, "--markers", markers, "--out", run, "--time-offset", offset, "--calibration", cal, "--quiet",
        *process_args)
    wall = time.perf_counter() - t0
    cli("evaluate", run, "--reference", os.path.join(scen, "truth.tum"))
    with open(os.path.join(run, "report.json")) as f:
        ev = json.load(f)
    with open(os.path.join(run, "summary.json")) as f:
        summary = json.load(f)
    agreement = ev.get("per_marker_agreement", {}).get("all_pairs", {})
    return {"report": report, "hidden": hidden, "offset": offset,
            "rmse": ev["heading_ape"]["rmse_deg"], "p95": ev["heading_ape"]["p95_deg"],
            "coverage": ev["coverage"]["share"], "agreement_median": agreement.get("median_deg", math.nan),
            "offset_err_ms": (offset - hidden["camera_time_offset"]) * 1e3,
            "readout_ms": summary.get("readout_ms", 0.0),
            "findings": [f["kind"] for f in summary["selfcheck"]["findings"]],
            "tilt_rmse": tilt_rmse_deg(run, os.path.join(scen, "truth.tum")),
            "fps": summary["frames"] / wall, "rtf": summary["bag_duration_s"] / wall}

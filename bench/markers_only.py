#!/usr/bin/env python3
"""Absolute pose without a total station, and the tilt sources (issue 15): the figures of the README's
"Without a total station" and of the field guide, on the generator's scenarios.

    python bench/markers_only.py                 # all sections (feed: a minute; rendered: a few minutes)
    python bench/markers_only.py --only coverage distance dropout tilt   # no rendering

Sections:
- ``coverage``: markers only (no prism), 19 cm markers 3–10 m from a 12×18 m loop, driving from the first
  frame, exact bearings + 0.02° noise (``synthetic.feed``: no rendering); 4, 6 and 10 markers in the same
  hall (the same track, seeds 0–2): heading and position RMSE of the filtered pose, the frames with
  ≥ 3 and with ≥ 2 markers, the frames with a pose.
- ``distance``: markers only, 10 markers at 2–5, 4–8 and 7–12 m from the track.
- ``dropout``: with the prism and a 5 s prism dropout (10 markers): heading RMSE inside vs outside.
- ``tilt``: VO roll/pitch drifting 1°/min: yaw RMSE with a perfect tilt, with an IMU, without an IMU (tilt
  from the markers), and uncorrected (the VO's tilt alone).
- ``rendered``: markers only on a rendered 3840×1920 bag (10 markers, 10 s at 10 fps), through
  ``aruco-abs-orient process --no-prism``: detection included.
"""
import argparse
import math
import os
import sys
import tempfile
from dataclasses import replace

import numpy as np

from aruco_abs_orient.pipeline import AbsOrientPipeline, PipelineParams
from aruco_abs_orient.synthetic.feed import feed
from aruco_abs_orient.synthetic.scenario import Scenario, ScenarioConfig
from aruco_abs_orient.transforms import wrap_angle, yaw_of

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NOISE = math.radians(0.02)
HALL = ScenarioConfig(duration=30.0, fps=10.0, width=3840, standstill=0.0, accel_time=0.5, n_markers=10,
                      marker_size=0.19, marker_distance=(3.0, 10.0), boresight_deg=0.0)


def run(cfg: ScenarioConfig, params: PipelineParams):
    """(relative times s, heading errors rad, position errors m (NaN without a pose), markers per frame)."""
    sc = Scenario(cfg)
    pipe = AbsOrientPipeline(sc.markers, sc.base_T_camera_nominal, sc.base_T_prism, params)
    rel, eh, ep, n = [], [], [], []
    for t, res in feed(sc, pipe, None, NOISE, np.random.default_rng(cfg.seed)):
        T = sc.map_T_base(t)
        rel.append(t - sc.frame_times[0])
        n.append(len(res.observations))
        ok = res.map_T_base is not None
        eh.append(float(wrap_angle(res.yaw - yaw_of(T[:3, :3]))) if ok else math.nan)
        ep.append(float(np.linalg.norm(res.map_T_base[:3, 3] - T[:3, 3])) if ok else math.nan)
    return np.array(rel), np.array(eh), np.array(ep), np.array(n)


def rms(x) -> float:
    x = np.asarray(x)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan


def coverage() -> None:
    print("## markers only (no prism): synthetic.feed, 19 cm markers 3-10 m, 30 s at 10 fps, seeds 0-2")
    print("| markers in the hall | heading RMSE | position RMSE | on frames with >= 3 markers: heading, position | "
          "frames >= 3 markers | >= 2 markers | frames with a pose |")
    print("|---|---|---|---|---|---|---|")
    for n in (4, 6, 10):
        eh, ep, cnt = [], [], []
        for seed in range(3):
            _, h, p, c = run(replace(HALL, n_markers=n, seed=seed), PipelineParams(markers_only=True))
            eh.append(h), ep.append(p), cnt.append(c)
        eh, ep, cnt = np.concatenate(eh), np.concatenate(ep), np.concatenate(cnt)
        three = cnt >= 3
        print(f"| {n} | {math.degrees(rms(eh)):.3f}° | {100 * rms(ep):.2f} cm | {math.degrees(rms(eh[three])):.3f}°, "
              f"{100 * rms(ep[three]):.2f} cm | {100 * np.mean(three):.0f} % | "
              f"{100 * np.mean(cnt >= 2):.0f} % | {100 * np.mean(np.isfinite(eh)):.0f} % |")


def distance() -> None:
    print("\n## markers only by marker distance: 10 markers, the same loop, seeds 0-2")
    print("| markers from the track | heading RMSE | position RMSE | frames >= 3 markers |")
    print("|---|---|---|---|")
    for band in ((2.0, 5.0), (4.0, 8.0), (7.0, 12.0)):
        eh, ep, cnt = [], [], []
        for seed in range(3):
            _, h, p, c = run(replace(HALL, marker_distance=band, seed=seed), PipelineParams(markers_only=True))
            eh.append(h), ep.append(p), cnt.append(c)
        eh, ep, cnt = np.concatenate(eh), np.concatenate(ep), np.concatenate(cnt)
        print(f"| {band[0]:g}-{band[1]:g} m | {math.degrees(rms(eh)):.3f}° | {100 * rms(ep):.2f} cm | "
              f"{100 * np.mean(cnt >= 3):.0f} % |")


def dropout() -> None:
    print("\n## prism + a 5 s prism dropout (10 to 15 s), 10 markers, seeds 0-2")
    inside, outside = [], []
    for seed in range(3):
        rel, h, _, _ = run(replace(HALL, seed=seed, prism_outage=(10.0, 5.0), prism_gaps=0), PipelineParams())
        gap = (rel >= 10.0) & (rel < 15.0)
        late = rel >= 2.0
        inside.append(h[gap]), outside.append(h[~gap & late])
    i, o = rms(np.concatenate(inside)), rms(np.concatenate(outside))
    print(f"heading RMSE during the dropout {math.degrees(i):.4f}°, outside it (from 2 s) {math.degrees(o):.4f}°: "
          f"ratio {i / o:.2f}")


def tilt() -> None:
    print("\n## VO roll/pitch drifting 1°/min, with the prism, 10 markers, 60 s, seeds 0-2 (yaw RMSE from 2 s)")
    cases = [("perfect VO tilt", {"vo_tilt_drift_deg_per_min": 0.0}, {}),
             ("drift + IMU (100 Hz, 0.02°)", {"imu_rate": 100.0}, {}),
             ("drift, no IMU: tilt from the markers", {}, {"tilt_from_markers": True}),
             ("drift, uncorrected (VO tilt only)", {}, {})]
    out = {}
    for name, extra, pp in cases:
        errs = []
        for seed in range(3):
            cfg = replace(HALL, seed=seed, duration=60.0, **{"vo_tilt_drift_deg_per_min": 1.0, **extra})
            rel, h, _, _ = run(cfg, PipelineParams(**pp))
            errs.append(h[rel >= 2.0])
        out[name] = math.degrees(rms(np.concatenate(errs)))
    base = out["perfect VO tilt"]
    for name, v in out.items():
        print(f"{name}: {v:.4f}° ({v - base:+.4f}° against the perfect tilt)")


def rendered() -> None:
    from aruco_abs_orient.markers import MarkerMap
    from aruco_abs_orient.offline.process import RunSetup, process_bag
    from aruco_abs_orient.params import parse_params
    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.tum import read_tum

    cfg = replace(HALL, duration=10.0, fps=10.0, profile="realistic")
    out = os.path.join(ROOT, ".cache", "bench", "markers_only_rendered")
    if not os.path.exists(os.path.join(out, "scenario.bag")):
        print(f"rendering a 10 s 3840x1920 10 fps scenario into {out} (once)", file=sys.stderr)
        generate(cfg, out, progress=True, force=True)
    sc = Scenario(cfg)
    with tempfile.TemporaryDirectory() as run_dir:
        res = process_bag(os.path.join(out, "scenario.bag"), MarkerMap.load(os.path.join(out, "markers.yaml")),
                          run_dir, RunSetup(cfg.camera_time_offset, progress=False),
                          parse_params({"pipeline": {"markers_only": True}}))
        traj = read_tum(res.trajectory_path)
    T = sc.map_T_base(traj.stamps)
    est = traj.transforms
    eh = wrap_angle(yaw_of(est[:, :3, :3]) - yaw_of(T[:, :3, :3]))
    ep = np.linalg.norm(est[:, :3, 3] - T[:, :3, 3], axis=1)
    print("\n## rendered 3840x1920, markers only (process --no-prism), 10 markers 3-10 m, 10 s at 10 fps, seed 0")
    print(f"frames {res.summary['frames']}, with a pose {res.summary['frames_with_pose']}; heading RMSE "
          f"{math.degrees(rms(eh)):.4f}°, position RMSE {100 * rms(ep):.2f} cm")


SECTIONS = {"coverage": coverage, "distance": distance, "dropout": dropout, "tilt": tilt, "rendered": rendered}

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="+", choices=sorted(SECTIONS), help="run only these sections")
    a = ap.parse_args()
    for name in a.only or SECTIONS:
        SECTIONS[name]()

"""``aruco-abs-orient evaluate``: a processed run against a reference (paper figs. 11–13 and more).

Reads the outputs of ``process`` (``trajectory.tum``, ``observations.csv``) and a reference TUM
file of base_link in map (the synthetic truth, or any better trajectory), and writes plots and a
Markdown + JSON report: yaw-only APE and RPE of the filtered heading, each marker's own yaw
trajectory and the pairwise differences between markers (the paper's statistics), the per-marker
yaw error vs the reference, the error by position in the frame, and the position error.
"""

from __future__ import annotations

import csv
import math
import os
from typing import Dict, Optional

import numpy as np

from .. import evaluation as ev
from ..transforms import wrap_angle, yaw_of
from ..tum import TumError, read_tum

__all__ = ["EvaluateError", "read_observations", "evaluate_run", "odometry_from_bag", "fused_errors",
           "overview_figure"]


class EvaluateError(ValueError):
    """Inputs that cannot be evaluated: names the file and what is missing."""


def read_observations(path: str) -> Dict[str, np.ndarray]:
    """Columns of an ``observations.csv`` written by ``process`` (angles converted to radians)."""
    cols: Dict[str, list] = {"time": [], "id": [], "azimuth": [], "elevation": [], "yaw": [], "accepted": []}
    try:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if not row.get("yaw_deg"):
                    continue
                cols["time"].append(float(row["time"]))
                cols["id"].append(int(row["id"]))
                cols["azimuth"].append(math.radians(float(row["azimuth_deg"])))
                cols["elevation"].append(math.radians(float(row["elevation_deg"])))
                cols["yaw"].append(math.radians(float(row["yaw_deg"])))
                cols["accepted"].append(row["accepted"] == "1")
    except OSError as e:
        raise EvaluateError(f"{path}: cannot read: {e.strerror}") from None
    except (KeyError, ValueError) as e:
        raise EvaluateError(f"{path}: not an observations.csv of `aruco-abs-orient process` ({e})") from None
    return {k: np.asarray(v) for k, v in cols.items()}


def odometry_from_bag(bag: str, topic: str = "/odometry/filtered", clock_offset: float = 0.0):
    """The poses of a nav_msgs/Odometry topic of a bag as a TUM trajectory, stamps minus
    ``clock_offset`` (s; e.g. the camera offset when the outputs carry camera-clock stamps)."""
    from ..transforms import make_T, quat_to_matrix
    from ..tum import Trajectory
    from .bagio import BagError, open_reader

    reader = open_reader(bag)
    stamps, poses = [], []
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            raise BagError(f"{bag}: no topic {topic}")
        for c, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, c.msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            stamps.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - clock_offset)
            poses.append(make_T(quat_to_matrix([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z]))
    finally:
        reader.close()
    order = np.argsort(stamps, kind="stable")
    return Trajectory.from_transforms(np.asarray(stamps)[order], np.asarray(poses).reshape(-1, 4, 4)[order])


def fused_errors(trajectory, reference: str, after: float = 0.0, max_gap: float = 0.2) -> Dict[str, object]:
    """Heading APE and position RMSE of a trajectory (e.g. the EKF's) vs a reference TUM file,
    from time ``after`` on (s, reference clock)."""
    ref = read_tum(reference)
    sel = trajectory.stamps >= after
    if not np.any(sel):
        raise EvaluateError(f"no fused pose after t = {after:.3f} s")
    t, T = trajectory.stamps[sel], trajectory.transforms[sel]
    ape = ev.yaw_ape(t, yaw_of(T[:, :3, :3]), ref.stamps, yaw_of(ref.rotations), max_gap=max_gap)
    p_ref, _, ok = ref.interpolate(t)
    d = np.linalg.norm(T[ok, :3, 3] - p_ref[ok], axis=1)
    return {"heading_ape": ape, "position": {"rmse_m": float(np.sqrt(np.mean(d * d))), "n": int(ok.sum())}}


def evaluate_run(run_dir: str, reference: str, out_dir: Optional[str] = None, max_gap: float = 0.2,
                 extra: Optional[Dict[str, object]] = None) -> Dict[str, object]:
    """Evaluate ``run_dir`` (outputs of ``process``) against the TUM file ``reference``.

    Writes ``report.md``, ``report.json`` and PNG plots into ``out_dir`` (default ``run_dir``)
    and returns the results (objects of :mod:`aruco_abs_orient.evaluation`); ``extra`` sections
    (e.g. :func:`fused_errors` of the EKF) are added to the report.
    """
    out_dir = out_dir or run_dir
    os.makedirs(out_dir, exist_ok=True)
    try:
        est = read_tum(os.path.join(run_dir, "trajectory.tum"))
        ref = read_tum(reference)
    except TumError as e:
        raise EvaluateError(str(e)) from None
    if len(est.stamps) == 0:
        raise EvaluateError(f"{run_dir}/trajectory.tum: no poses (the run never initialised)")
    yaw_est, yaw_ref = yaw_of(est.rotations), yaw_of(ref.rotations)
    results: Dict[str, object] = {}
    plots: Dict[str, str] = {}
    try:
        ape = ev.yaw_ape(est.stamps, yaw_est, ref.stamps, yaw_ref, max_gap=max_gap)
        rpe = ev.yaw_rpe(est.stamps, yaw_est, ref.stamps, yaw_ref, delta=1.0, max_gap=max_gap)
    except ev.EvaluationError as e:
        raise EvaluateError(f"{reference}: {e}") from None
    results["heading_ape"] = ape
    results["heading_rpe_1s"] = rpe
    plots["heading error vs reference"] = ev.plot_yaw_errors(os.path.join(out_dir, "heading_error.png"),
                                                               {"filtered heading": ape})
    # position of base_link vs the reference
    p_ref, _, ok = ref.interpolate(est.stamps)
    if np.any(ok):
        d = np.linalg.norm(est.positions[ok] - p_ref[ok], axis=1)
        results["position"] = {"rmse_m": float(np.sqrt(np.mean(d * d))), "median_m": float(np.median(d)),
                               "p95_m": float(np.percentile(d, 95)), "n": int(ok.sum())}

    obs_path = os.path.join(run_dir, "observations.csv")
    if os.path.exists(obs_path):
        obs = read_observations(obs_path)
        if len(obs["time"]):
            series = ev.per_marker_series(obs["time"], obs["id"], obs["yaw"])
            truth_at, ok = ev.interp_yaw(obs["time"], ref.stamps, yaw_ref, max_gap)
            err = wrap_angle(obs["yaw"] - truth_at)
            per_marker = {}
            for mid in sorted(series):
                sel = ok & (obs["id"] == mid)
                if np.any(sel):
                    per_marker[f"marker {mid}"] = ev.error_stats(err[sel])
            results["per_marker_yaw_vs_reference"] = per_marker
            try:
                pw = ev.pairwise_differences(series)
                results["per_marker_agreement"] = pw
            except ev.EvaluationError as e:
                pw = None
                results["per_marker_agreement"] = {"not_available": str(e)}
            plots["yaw from each marker (paper fig. 11-12)"] = ev.plot_marker_yaws(
                os.path.join(out_dir, "marker_yaws.png"), series, pw)
            if np.any(ok):
                bias = ev.error_by_frame_position(obs["azimuth"][ok], obs["elevation"][ok], err[ok])
                results["error_by_frame_position"] = bias
                plots["yaw error by position in the frame (paper fig. 13)"] = ev.plot_frame_position(
                    os.path.join(out_dir, "frame_position.png"), bias)
    results.update(extra or {})
    results["plots"] = plots
    md, js = ev.write_report(out_dir, results, title=f"aruco_abs_orient evaluation of {os.path.abspath(run_dir)}")
    results["report_md"], results["report_json"] = md, js
    return results


def overview_figure(path: str, bag: str, run_dir: str, reference: str, marker_map, topics=None) -> str:
    """One picture of a run (the README's): the 360° frame from the middle of the bag with the
    markers found in it outlined and labelled, above the corrected trajectory of base_link vs the
    reference, with its absolute heading and the markers. Returns ``path`` (PNG)."""
    from matplotlib.figure import Figure

    from ..detection import decode_jpeg
    from ..tracking import MarkerTracker
    from .bagio import BagTopics, iter_images, open_reader

    topics = topics or BagTopics()
    reader = open_reader(bag)
    middle = sum(c.msgcount for c in reader.connections if c.topic == topics.image) // 2
    reader.close()
    frames = iter_images(bag, topics)
    grey = None
    for i, (_, payload) in enumerate(frames):
        if i >= middle and isinstance(payload, bytes):
            grey = decode_jpeg(payload)
            break
    frames.close()
    if grey is None:
        raise EvaluateError(f"{bag}: no decodable image from the middle of the bag on")
    obs = MarkerTracker(marker_map).process(grey).observations
    est, ref = read_tum(os.path.join(run_dir, "trajectory.tum")), read_tum(reference)

    fig = Figure(figsize=(12, 10), dpi=100)
    ax = fig.add_axes([0.03, 0.52, 0.94, 0.45])
    ax.imshow(grey, cmap="gray", vmin=0, vmax=255)
    for o in obs:
        u, v = o.corners_px[:, 0], o.corners_px[:, 1]
        ax.plot(np.append(u, u[0]), np.append(v, v[0]), "-", color="lime", lw=1.5)
        ax.text(o.pixel[0], o.pixel[1] - 0.02 * grey.shape[0], f"id {o.id}", color="yellow", fontsize=9,
                ha="center", bbox={"facecolor": "black", "alpha": 0.5, "pad": 1, "lw": 0})
    ax.set_title(f"360° frame: {len(obs)} markers found (outlined, with ids)")
    ax.set_axis_off()
    ax2 = fig.add_axes([0.08, 0.05, 0.88, 0.42])
    ax2.plot(ref.positions[:, 0], ref.positions[:, 1], "-", color="0.6", lw=3, label="truth")
    ax2.plot(est.positions[:, 0], est.positions[:, 1], "-", color="C0", lw=1, label="corrected base_link")
    step = max(len(est.stamps) // 25, 1)
    yaw = yaw_of(est.rotations[::step])
    ax2.quiver(est.positions[::step, 0], est.positions[::step, 1], np.cos(yaw), np.sin(yaw), color="C0",
               scale=30, width=0.003, label="absolute heading")
    pos = marker_map.positions()
    ax2.plot(pos[:, 0], pos[:, 1], "s", color="k", ms=6, label="markers")
    for m in marker_map:
        ax2.annotate(str(m.id), m.position[:2], xytext=(4, 4), textcoords="offset points", fontsize=8)
    ax2.set_aspect("equal")
    ax2.set_xlabel("map x [m]")
    ax2.set_ylabel("map y [m]")
    ax2.legend(loc="best", fontsize=8)
    ax2.grid(True, alpha=0.3)
    return ev.save_figure(fig, path)

"""``aruco-abs-orient evaluate``: the report of a processed run (paper figs. 11–13 and more).

Reads the outputs of ``process`` (``summary.json``, ``trajectory.tum``, ``observations.csv``). Without a
reference it reports what the run shows by itself — the paper's own evaluation: each marker's yaw
trajectory and the pairwise differences between markers, the residuals and their σ consistency,
coverage and gaps, the run's self-checks. With a reference TUM file of base_link in map (the synthetic
truth, or any better trajectory) it adds yaw-only APE and RPE of the filtered heading, the per-marker
yaw error, the error by position in the frame and the position error. Writes ``report.md`` (a page of
headline figures beside the paper's, the plots, then tables), ``report.json`` and the plots.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
from typing import Dict, Optional, Tuple

import numpy as np

from .. import evaluation as ev
from ..errors import InputFileError
from ..transforms import wrap_angle, yaw_of
from ..tum import TumError, read_tum

__all__ = ["EvaluateError", "read_observations", "read_summary", "parse_after", "evaluate_run", "odometry_from_bag",
           "first_stamp", "fused_errors", "overview_figure"]


class EvaluateError(InputFileError, ValueError):
    """Inputs that cannot be evaluated: names the file and what is missing."""


PAPER = {  # Hasler & Nebiker's figures (real data), beside ours in the report
    "agreement": "median 0.66°, mean 1.17°, std 1.66°",
    "time_offset": "11 frames (367 ms), one-frame resolution",
}
DOC_DIR = os.path.join(os.path.dirname(os.path.realpath(__file__)), "..", "..", "..", "doc")  # in a checkout


def _doc(anchor: str, text: str, out_dir: str) -> str:
    """A Markdown link into doc/troubleshooting.md (relative to the report when the docs are here)."""
    path = os.path.join(DOC_DIR, "troubleshooting.md")
    target = (os.path.relpath(os.path.abspath(path), os.path.abspath(out_dir)) if os.path.exists(path)
              else "doc/troubleshooting.md")
    return f"[{text}]({target}#{anchor})"


def read_observations(path: str) -> Dict[str, np.ndarray]:
    """Columns of an ``observations.csv`` written by ``process`` with a marker yaw (angles converted to
    radians; ``yaw_sigma`` and ``residual`` NaN where empty)."""
    cols: Dict[str, list] = {"time": [], "id": [], "azimuth": [], "elevation": [], "yaw": [], "yaw_sigma": [],
                             "residual": [], "accepted": []}

    def rad(text: str) -> float:
        return math.radians(float(text)) if text else math.nan

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
                cols["yaw_sigma"].append(rad(row.get("yaw_sigma_deg", "")))
                cols["residual"].append(rad(row.get("residual_deg", "")))
                cols["accepted"].append(row["accepted"] == "1")
    except OSError as e:
        raise EvaluateError(f"{path}: cannot read: {e.strerror}") from None
    except (KeyError, ValueError) as e:
        raise EvaluateError(f"{path}: not an observations.csv of `aruco-abs-orient process` ({e})") from None
    return {k: np.asarray(v) for k, v in cols.items()}


def read_summary(run_dir: str) -> Dict[str, object]:
    """The run's ``summary.json`` (written by ``process``)."""
    path = os.path.join(run_dir, "summary.json")
    try:
        with open(path) as f:
            return json.load(f)
    except OSError as e:
        raise EvaluateError(f"{path}: cannot read: {e.strerror} (is {run_dir} an output directory of "
                            "`aruco-abs-orient process`?)") from None
    except ValueError as e:
        raise EvaluateError(f"{path}: not JSON: {e}") from None


def parse_after(text: str) -> Tuple[str, float]:
    """``--after``: ``"4"`` = 4 s after the start of the recording → ("since_start", 4.0);
    ``"1700000000.5abs"`` = that stamp on the total-station clock → ("absolute", 1700000000.5)."""
    absolute = text.endswith("abs")
    try:
        value = float(text[:-3] if absolute else text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds since the start of the recording (e.g. 4.5) or an absolute stamp with the suffix "
            f"abs (e.g. 1700000000.5abs), got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}") from None
    return ("absolute" if absolute else "since_start", value)


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
            raise BagError(f"{bag}: no topic {topic} (the EKF's output): record it with postprocess.launch "
                           "use_ekf:=true record:=<bag>")
        for c, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, c.msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            stamps.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - clock_offset)
            poses.append(make_T(quat_to_matrix([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z]))
    finally:
        reader.close()
    order = np.argsort(stamps, kind="stable")
    return Trajectory.from_transforms(np.asarray(stamps)[order], np.asarray(poses).reshape(-1, 4, 4)[order])


def first_stamp(bag: str, topic: str = "/abs_orient/orientation", clock_offset: float = 0.0) -> Optional[float]:
    """Header stamp (s) minus ``clock_offset`` of the first message on ``topic`` of ``bag`` (None: none)."""
    from .bagio import open_reader

    reader = open_reader(bag)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:  # (no connections would read every topic)
            return None
        for c, _, raw in reader.messages(connections=conns):
            h = reader.deserialize(raw, c.msgtype).header.stamp
            return h.sec + 1e-9 * h.nanosec - clock_offset
    finally:
        reader.close()
    return None


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
    return {"heading_ape": ape, "position": {"rmse_m": float(np.sqrt(np.mean(d * d))), "n": int(ok.sum())},
            "after_s": float(after)}


def evaluate_run(run_dir: str, reference: Optional[str] = None, out_dir: Optional[str] = None,
                 params: Optional[ev.EvaluationParams] = None, fused: Optional[str] = None,
                 fused_clock_offset: Optional[float] = None, after: Optional[Tuple[str, float]] = None,
                 overview: Optional[str] = None) -> Dict[str, object]:
    """Evaluate ``run_dir`` (outputs of ``process``), against the TUM file ``reference`` when given.

    Without a reference: what a user can check on the run alone (the paper's own evaluation): the
    markers' yaw agreement (pairwise, per-marker trajectories), the residuals and their σ consistency,
    coverage and gaps, the run's self-checks. With it: the heading/position errors too. ``fused``: a bag
    of ``postprocess.launch record:=`` whose ``/odometry/filtered`` is judged against the reference, its
    stamps minus ``fused_clock_offset`` (default: the run's time offset, from summary.json), from
    ``after`` (("since_start", s) or ("absolute", s); default ``params.settle`` s after its first absolute yaw)
    on. ``params``: :class:`~aruco_abs_orient.evaluation.EvaluationParams` (the gaps, the settling time).
    ``overview``: path of an overview PNG to show first. Writes ``report.md``, ``report.json`` and
    PNG plots into ``out_dir`` (default ``run_dir``); returns the results.
    """
    out_dir = out_dir or run_dir
    params = params or ev.EvaluationParams()
    max_gap = params.max_gap
    os.makedirs(out_dir, exist_ok=True)
    summary = read_summary(run_dir)
    try:
        est = read_tum(os.path.join(run_dir, "trajectory.tum"))
        ref = read_tum(reference) if reference else None
    except TumError as e:
        raise EvaluateError(str(e)) from None
    t0 = float(summary.get("recording_start_s", est.stamps[0] if len(est.stamps) else 0.0))
    offset = float(summary.get("time_offset_s", 0.0))
    bag_name = os.path.basename(str(summary.get("bag", ""))) or "?"
    rep = ev.Report(title=f"aruco_abs_orient report: {bag_name} ({os.path.basename(os.path.abspath(run_dir))})")
    results: Dict[str, object] = {}
    frames, with_pose = int(summary.get("frames", 0)), int(summary.get("frames_with_pose", len(est.stamps)))
    duration = float(summary.get("bag_duration_s", 0.0))
    rep.intro = (f"Recording `{summary.get('bag', '?')}`: {duration:.1f} s, {frames} images, time offset "
                 f"{1e3 * offset:+.1f} ms, lever arms from {summary.get('lever_arms', '?')}; "
                 + (f"reference `{reference}`." if reference else "no reference: the figures below are what the "
                    "run shows by itself.") + " Times are seconds since the start of the recording.")
    findings = (summary.get("selfcheck") or {}).get("findings", [])
    for w in summary.get("warnings", []):
        if w not in {c["message"] for c in findings}:
            rep.notes.append(f"warning: {w}")
    for c in findings:
        rep.notes.append(f"{c['message']} ({_doc(c.get('doc', 'time-offset'), 'troubleshooting', out_dir)})")
    if overview:
        rep.plots["overview: a frame with its markers, the trajectory"] = overview

    # coverage and gaps: what the run delivered
    if len(est.stamps) == 0:
        reason = "; ".join(summary.get("warnings") or []) or "its summary.json says what it counted"
        raise EvaluateError(f"{run_dir}/trajectory.tum: no poses (the run never initialised: {reason})")
    end = t0 + duration if duration else None
    holes = ev.gaps(est.stamps, params.min_gap, end=end)
    results["coverage"] = {"frames": frames, "frames_with_pose": with_pose,
                           "share": with_pose / frames if frames else None,
                           "first_pose_s": float(est.stamps[0] - t0),
                           "gaps_s": [[a - t0, b - t0] for a, b in holes]}
    longest = holes[0] if holes else None
    cover = (f"{100 * with_pose / max(frames, 1):.1f} % of the images have a pose (from {est.stamps[0] - t0:.1f} s); "
             + (f"longest gap {longest[1] - longest[0]:.1f} s at {longest[0] - t0:.1f} s" if longest else
                f"no gap over {params.min_gap:g} s"))
    rep.headline.append(("coverage", cover, "–", _doc("no-markers-found", "no markers found", out_dir)))

    obs_path = os.path.join(run_dir, "observations.csv")
    obs = read_observations(obs_path) if os.path.exists(obs_path) else None
    series, pw = {}, None
    if obs is not None and len(obs["time"]):
        series = ev.per_marker_series(obs["time"], obs["id"], obs["yaw"])
        try:
            pw = ev.pairwise_differences(series)
            results["per_marker_agreement"] = pw
            st = pw.stats
            rep.headline.append(("markers' yaws agree (pairwise, same image)",
                                 f"median {ev.fmt_angle(st.median)}, mean {ev.fmt_angle(st.mean)}, "
                                 f"std {ev.fmt_angle(st.std)}", PAPER["agreement"],
                                 _doc("jumps-in-the-heading", "a moved or wrongly surveyed marker", out_dir)))
        except ev.EvaluationError as e:
            results["per_marker_agreement"] = {"not_available": str(e)}
        acc = obs["accepted"]
        res_ok = acc & np.isfinite(obs["residual"])
        if np.any(res_ok):
            rs = ev.error_stats(obs["residual"][res_ok])
            results["residuals"] = rs
            z = ev.normalised_residuals(obs["residual"][res_ok], obs["yaw_sigma"][res_ok])
            results["normalised_residuals"] = z
            rep.headline.append(("residuals (each accepted marker yaw − filtered yaw)",
                                 f"RMS {ev.fmt_angle(rs.rmse)}, p95 {ev.fmt_angle(rs.p95)}; "
                                 f"{100 * float(np.mean(acc)):.0f} % of marker yaws accepted", "–",
                                 _doc("time-offset", "time offset", out_dir)))
            rep.headline.append(("σ consistency (RMS of residual/σ; 1 = honest σ)",
                                 f"{z['rms']:.2f}; {100 * z['share_within_2_sigma']:.0f} % within 2σ", "–",
                                 _doc("time-offset", "time offset, calibration", out_dir)))
        rows = []
        for mid in sorted(series):
            sel = obs["id"] == mid
            good = sel & res_ok
            z_m = ev.normalised_residuals(obs["residual"][good], obs["yaw_sigma"][good]) if np.any(good) else None
            r = obs["residual"][good]
            rows.append([mid, int(sel.sum()), f"{100 * float(np.mean(acc[sel])):.0f} %",
                         ev.fmt_angle(float(np.mean(r))) if len(r) else "–",
                         ev.fmt_angle(float(np.std(r))) if len(r) else "–",
                         f"{z_m['rms']:.2f}" if z_m else "–"])
        per_marker_cols = ["marker", "observations", "accepted", "residual mean", "residual std", "RMS residual/σ"]
        per_marker_rows = rows
        rep.plots["yaw from each marker alone and their pairwise differences (paper figs. 11–12)"] = \
            ev.plot_marker_yaws(os.path.join(out_dir, "marker_yaws.png"), series, pw, t0=t0)
    else:
        per_marker_cols, per_marker_rows = [], []

    if ref is not None:
        yaw_est, yaw_ref = yaw_of(est.rotations), yaw_of(ref.rotations)
        try:
            ape = ev.yaw_ape(est.stamps, yaw_est, ref.stamps, yaw_ref, max_gap=max_gap)
            rpe = ev.yaw_rpe(est.stamps, yaw_est, ref.stamps, yaw_ref, delta=1.0, max_gap=max_gap)
        except ev.EvaluationError as e:
            raise EvaluateError(f"{reference}: {e}") from None
        results["heading_ape"], results["heading_rpe_1s"] = ape, rpe
        rep.headline.insert(0, ("heading of base_link vs reference",
                                f"RMSE {ev.fmt_angle(ape.stats.rmse)}, p95 {ev.fmt_angle(ape.stats.p95)} "
                                f"({100 * ape.stats.coverage:.1f} % of the poses compared)", "–",
                                _doc("time-offset", "time offset", out_dir) + ", "
                                + _doc("heading-wrong-by-180", "180°", out_dir)))
        errors = {"processed heading": ape}
        p_ref, _, ok = ref.interpolate(est.stamps)
        if np.any(ok):
            d = np.linalg.norm(est.positions[ok] - p_ref[ok], axis=1)
            results["position"] = {"rmse_m": float(np.sqrt(np.mean(d * d))), "median_m": float(np.median(d)),
                                   "p95_m": float(np.percentile(d, 95)), "n": int(ok.sum())}
            rep.headline.insert(1, ("position of base_link vs reference",
                                    f"RMSE {1e3 * results['position']['rmse_m']:.1f} mm", "–",
                                    _doc("no-markers-found", "prism, lever arms", out_dir)))
        if fused:
            clock = offset if fused_clock_offset is None else fused_clock_offset
            traj = odometry_from_bag(fused, clock_offset=clock)
            first = first_stamp(fused, clock_offset=clock)
            link = "[robot_localization.md](" + os.path.relpath(os.path.join(DOC_DIR, "robot_localization.md"),
                                                                os.path.abspath(out_dir)) + ")"
            if after is None and first is None:
                why = (f"not judged: {os.path.basename(fused)} has no abs_orient/orientation, the EKF had no absolute "
                       "yaw (the replay's last line says why)")
                results["fused_ekf"] = {"not_available": why}
                rep.headline.insert(2, ("robot_localization EKF (odometry/filtered)", why, "–",
                                        _doc("a-replay-that-ends-or-fails", "replay", out_dir)))
            else:
                if after is None:
                    start = first + params.settle
                    how = f"from {start - t0:.1f} s: {params.settle:g} s after its first absolute yaw"
                else:
                    start = after[1] + (t0 if after[0] == "since_start" else 0.0)
                    how = f"from {start - t0:.1f} s (--after)"
                f = fused_errors(traj, reference, after=start, max_gap=max_gap)
                f["clock_offset_s"] = clock
                results["fused_ekf"] = f
                errors["robot_localization EKF"] = f["heading_ape"]
                rep.headline.insert(2, ("robot_localization EKF (odometry/filtered)",
                                        f"heading RMSE {ev.fmt_angle(f['heading_ape'].stats.rmse)}, position RMSE "
                                        f"{1e3 * f['position']['rmse_m']:.1f} mm ({how})", "–", link))
        rep.plots["heading error vs reference"] = ev.plot_yaw_errors(os.path.join(out_dir, "heading_error.png"),
                                                                     errors, t0=t0)
        if obs is not None and len(obs["time"]):
            truth_at, ok = ev.interp_yaw(obs["time"], ref.stamps, yaw_ref, max_gap)
            err = wrap_angle(obs["yaw"] - truth_at)
            per = {}
            for row in per_marker_rows:
                sel = ok & (obs["id"] == row[0])
                st = ev.error_stats(err[sel]) if np.any(sel) else None
                per[f"marker {row[0]}"] = st
                row += [ev.fmt_angle(st.bias) if st else "–", ev.fmt_angle(st.rmse) if st else "–"]
            per_marker_cols += ["vs reference: bias", "vs reference: RMSE"]
            results["per_marker_yaw_vs_reference"] = {k: v for k, v in per.items() if v is not None}
            if np.any(ok):
                bias = ev.error_by_frame_position(obs["azimuth"][ok], obs["elevation"][ok], err[ok])
                results["error_by_frame_position"] = bias
                rep.plots["yaw error by position in the frame (paper fig. 13)"] = ev.plot_frame_position(
                    os.path.join(out_dir, "frame_position.png"), bias)
    sync_png = next((os.path.join(d, "timesync.png") for d in (out_dir, run_dir)
                     if os.path.exists(os.path.join(d, "timesync.png"))), None)
    if sync_png:  # written by `timesync --plot` into the run's directory
        rep.plots["camera ↔ total-station time offset (timesync)"] = sync_png
    rep.headline.append(("time offset in use (camera − total station)", f"{1e3 * offset:+.1f} ms", PAPER["time_offset"],
                         _doc("time-offset", "time offset", out_dir)))
    if per_marker_rows:
        rep.tables.append(("Per marker", per_marker_cols, per_marker_rows))
    if isinstance(pw, ev.PairwiseDifferences):
        rep.tables.append(("Marker pairs (same image)", ["pair", "n", "median", "mean", "std", "< 0.5°", "< 1°"],
                           [[f"{a} − {b}", st.n, ev.fmt_angle(st.median), ev.fmt_angle(st.mean), ev.fmt_angle(st.std),
                             f"{100 * st.share_under[0]:.0f} %", f"{100 * st.share_under[1]:.0f} %"]
                            for (a, b), st in sorted(pw.per_pair.items())]))
    stat_rows = [[name, r.stats.n, ev.fmt_angle(r.stats.rmse), ev.fmt_angle(r.stats.median), ev.fmt_angle(r.stats.p95),
                  ev.fmt_angle(r.stats.max), ev.fmt_angle(r.stats.bias)]
                 for name, r in (("heading vs reference", results.get("heading_ape")),
                                 ("heading change over 1 s vs reference", results.get("heading_rpe_1s")),
                                 ("EKF heading vs reference", (results.get("fused_ekf") or {}).get("heading_ape")))
                 if r is not None]
    if stat_rows:
        rep.tables.append(("Heading errors", ["", "n", "RMSE", "median", "p95", "max", "bias"], stat_rows))
    if holes:
        rep.tables.append(("Gaps without a pose (over 0.5 s)", ["from [s]", "to [s]", "length [s]"],
                           [[f"{a - t0:.1f}", f"{b - t0:.1f}", f"{b - a:.1f}"] for a, b in holes[:10]]))
    stats = summary.get("pipeline_stats") or {}
    if stats:
        rep.tables.append(("Pipeline counters (summary.json pipeline_stats)", ["counter", "count"],
                           [[k, v] for k, v in sorted(stats.items())]))
    rep.data = {"recording_start_s": t0, "time_offset_s": offset, "reference": reference, **results,
                "selfcheck": summary.get("selfcheck"), "warnings": summary.get("warnings", [])}
    md, js = ev.write_report(out_dir, rep)
    results["report_md"], results["report_json"], results["headline"] = md, js, rep.headline
    results["notes"] = rep.notes
    return results


def overview_figure(path: str, bag: str, run_dir: str, reference: Optional[str], marker_map, topics=None) -> str:
    """One picture of a run (the README's): the 360° frame from the middle of the bag (or of a video:
    ``bag`` with a video file's extension) with the markers found in it outlined and labelled, above the
    corrected trajectory of base_link vs the reference (when given), with its absolute heading and the
    markers, in the trajectory's coordinates (full ones with a map origin). Returns ``path`` (PNG)."""
    from matplotlib.figure import Figure

    from ..detection import decode_jpeg
    from ..tracking import MarkerTracker
    from .bagio import BagTopics, iter_images, open_reader
    from .video import VIDEO_EXTENSIONS, video_frames, video_summary

    topics = topics or BagTopics()
    grey = None
    if os.path.splitext(bag)[1].lower() in VIDEO_EXTENSIONS:
        middle = video_summary(bag)[0] // 2
        video = video_frames(bag)
        grey = next((image for k, _, image in video if k >= middle), None)
        video.close()
    else:
        reader = open_reader(bag)
        middle = sum(c.msgcount for c in reader.connections if c.topic == topics.image) // 2
        reader.close()
        frames = iter_images(bag, topics)
        for i, (_, payload) in enumerate(frames):
            if i >= middle and isinstance(payload, bytes):
                grey = decode_jpeg(payload)
                break
        frames.close()
    if grey is None:
        raise EvaluateError(f"{bag}: no decodable image from the middle of the bag on")
    obs = MarkerTracker(marker_map).process(grey).observations
    est = read_tum(os.path.join(run_dir, "trajectory.tum"))

    fig = Figure(figsize=(12, 10), dpi=100)
    ax = fig.add_axes([0.03, 0.52, 0.94, 0.45])
    ax.imshow(grey, cmap="gray", vmin=0, vmax=255)
    for o in obs:
        u, v = o.corners_px[:, 0], o.corners_px[:, 1]
        ax.plot(np.append(u, u[0]), np.append(v, v[0]), "-", color="lime", lw=1.5)
        ax.text(o.pixel[0], o.pixel[1] - 0.02 * grey.shape[0], f"id {o.id}", color="yellow", fontsize=9,
                ha="center", bbox={"facecolor": "black", "alpha": 0.5, "pad": 1, "lw": 0})
    ax.set_title(f"360° frame from the middle of the recording: {len(obs)} marker{'s' if len(obs) != 1 else ''} "
                 "found (outlined, with ids)")
    ax.set_axis_off()
    ax2 = fig.add_axes([0.08, 0.05, 0.88, 0.42])
    if reference:
        ref = read_tum(reference)
        ax2.plot(ref.positions[:, 0], ref.positions[:, 1], "-", color="0.6", lw=3, label="reference")
    ax2.plot(est.positions[:, 0], est.positions[:, 1], "-", color="C0", lw=1, label="corrected base_link")
    step = max(len(est.stamps) // 25, 1)
    yaw = yaw_of(est.rotations[::step])
    ax2.quiver(est.positions[::step, 0], est.positions[::step, 1], np.cos(yaw), np.sin(yaw), color="C0",
               scale=30, width=0.003, label="absolute heading")
    pos = marker_map.to_full(marker_map.positions())
    ax2.plot(pos[:, 0], pos[:, 1], "s", color="k", ms=6, label="markers")
    for m in marker_map:
        ax2.annotate(str(m.id), marker_map.to_full(m.position)[:2], xytext=(4, 4), textcoords="offset points",
                     fontsize=8)
    ax2.set_aspect("equal")
    ax2.set_xlabel("map x [m]")
    ax2.set_ylabel("map y [m]")
    ax2.legend(loc="best", fontsize=8)
    ax2.grid(True, alpha=0.3)
    return ev.save_figure(fig, path)

"""``aruco-abs-orient evaluate``: the report of a processed run (paper figs. 11–13 and more).

Reads the outputs of ``process`` (``summary.json``, ``trajectory.tum``, ``observations.csv``). Without a
reference it reports what the run shows by itself — the paper's own evaluation: each marker's yaw
trajectory and the pairwise differences between markers, the residuals and their σ consistency,
coverage and gaps, the run's self-checks. With a reference TUM file of base_link in map (the synthetic
truth, or any better trajectory) it adds yaw-only APE and RPE of the filtered heading, the per-marker
yaw error, the error by position in the frame and the position error. Writes ``report.md`` (a page of
headline figures beside the paper's, the plots, then tables), ``report.json`` and the plots (:mod:`..plots`:
each answers its question in its title): ``marker_yaws.png``, ``heading_error.png`` (with the filter's own σ
from ``heading_sigma.csv`` and the stretches without absolute updates, with why), ``frame_position.png``, and
``timesync.png`` drawn again with the run's offset when ``timesync --plot`` left ``timesync.json`` in the run's
directory; ``calibration.png`` (``calibrate --plot``) is shown when it is there.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
from collections import Counter
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from .. import evaluation as ev
from .. import plots
from ..errors import InputFileError
from ..transforms import wrap_angle, yaw_of
from ..tum import TumError, read_tum

__all__ = ["EvaluateError", "read_observations", "read_summary", "parse_after", "evaluate_run", "odometry_from_bag",
           "topic_stamps", "fused_errors", "no_update_spans"]


class EvaluateError(InputFileError):
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


def read_observations(path: str, every_row: bool = False) -> Dict[str, np.ndarray]:
    """Columns of an ``observations.csv`` written by ``process``: the rows with a marker yaw, or with
    ``every_row`` all of them (angles converted to radians; ``yaw``, ``yaw_sigma`` and ``residual`` NaN where
    empty; ``reason`` the pipeline's, '' when accepted)."""
    cols: Dict[str, list] = {"time": [], "id": [], "azimuth": [], "elevation": [], "yaw": [], "yaw_sigma": [],
                             "residual": [], "accepted": [], "reason": []}

    def rad(text: str) -> float:
        return math.radians(float(text)) if text else math.nan

    try:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if not (every_row or row.get("yaw_deg")):
                    continue
                cols["time"].append(float(row["time"]))
                cols["id"].append(int(row["id"]))
                cols["azimuth"].append(math.radians(float(row["azimuth_deg"])))
                cols["elevation"].append(math.radians(float(row["elevation_deg"])))
                cols["yaw"].append(rad(row["yaw_deg"]))
                cols["yaw_sigma"].append(rad(row.get("yaw_sigma_deg", "")))
                cols["residual"].append(rad(row.get("residual_deg", "")))
                cols["accepted"].append(row["accepted"] == "1")
                cols["reason"].append(row.get("reason") or "")
    except OSError as e:
        raise EvaluateError(f"{path}: cannot read: {e.strerror}") from None
    except (KeyError, ValueError) as e:
        raise EvaluateError(f"{path}: not an observations.csv of `aruco-abs-orient process` ({e})") from None
    return {k: np.asarray(v) for k, v in cols.items()}


def read_heading_sigma(run_dir: str) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """(stamps s, the filter's heading 1-σ rad) of ``heading_sigma.csv`` (None when the run has none)."""
    path = os.path.join(run_dir, "heading_sigma.csv")
    if not os.path.exists(path):
        return None
    try:
        data = np.atleast_2d(np.genfromtxt(path, delimiter=",", skip_header=1, usecols=(0, 2)))
    except (OSError, ValueError) as e:
        raise EvaluateError(f"{path}: not a heading_sigma.csv of `aruco-abs-orient process` ({e})") from None
    if data.size == 0:
        return np.empty(0), np.empty(0)
    return data[:, 0], np.radians(data[:, 1])


def no_update_spans(obs: Dict[str, np.ndarray], start: float, end: float, min_gap: float) -> List[plots.Span]:
    """The stretches from ``start`` to ``end`` (s) longer than ``min_gap`` s without an accepted marker yaw (the
    filter coasted on the odometry), each with why: the most common reason the pipeline gave for the markers it
    saw then, or "no marker seen"."""
    accepted = np.unique(obs["time"][obs["accepted"]])
    edges = np.concatenate([[start], accepted[(accepted > start) & (accepted < end)], [end]])
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a <= min_gap:
            continue
        inside = (obs["time"] > a) & (obs["time"] < b)
        why = Counter(r.split(" (")[0] for r in obs["reason"][inside] if r)
        out.append(plots.Span(float(a), float(b), why.most_common(1)[0][0] if why else "no marker seen"))
    return out


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
    """The poses of a nav_msgs/Odometry topic of a bag as a TUM trajectory, stamps minus ``clock_offset`` (s;
    e.g. the camera offset when the outputs carry camera-clock stamps), and their yaw 1-σ (rad, (N,); from the
    pose covariance, NaN where it is not positive)."""
    from ..transforms import make_T, quat_to_matrix
    from ..tum import Trajectory
    from .bagio import BagError, open_reader

    reader = open_reader(bag)
    stamps, poses, sigmas = [], [], []
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
            var = float(msg.pose.covariance[35])
            sigmas.append(math.sqrt(var) if var > 0 else math.nan)
    finally:
        reader.close()
    order = np.argsort(stamps, kind="stable")
    traj = Trajectory.from_transforms(np.asarray(stamps)[order], np.asarray(poses).reshape(-1, 4, 4)[order])
    return traj, np.asarray(sigmas)[order]


def topic_stamps(bag: str, topic: str = "/abs_orient/orientation", clock_offset: float = 0.0) -> np.ndarray:
    """Header stamps (s) minus ``clock_offset`` of the messages on ``topic`` of ``bag``, sorted (none: empty)."""
    from .bagio import open_reader

    reader = open_reader(bag)
    stamps = []
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if conns:  # (no connections would read every topic)
            for c, _, raw in reader.messages(connections=conns):
                h = reader.deserialize(raw, c.msgtype).header.stamp
                stamps.append(h.sec + 1e-9 * h.nanosec - clock_offset)
    finally:
        reader.close()
    return np.sort(np.asarray(stamps, dtype=float))


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


def _timesync_and_calibration(run_dir: str, out_dir: str, offset: float) -> Dict[str, str]:
    """caption → path of the plots ``timesync --plot`` and ``calibrate --plot`` left in the run's directory (or
    the report's): ``timesync.png`` drawn again from its ``timesync.json`` with the run's ``offset`` (s) on it."""
    found = {}
    for d in (out_dir, run_dir):
        data = os.path.join(d, "timesync.json")
        if "sync" not in found and os.path.exists(data):
            from .sync import plot_offset_file

            try:
                found["sync"] = plot_offset_file(data, os.path.join(out_dir, "timesync.png"), in_use=offset)
            except (OSError, ValueError, KeyError, TypeError) as e:
                raise EvaluateError(f"{data}: not a timesync.json of `aruco-abs-orient timesync --plot` ({e})") \
                    from None
        for key, name in (("sync", "timesync.png"), ("calibration", "calibration.png")):
            if key not in found and os.path.exists(os.path.join(d, name)):
                found[key] = os.path.join(d, name)
    captions = {"sync": "is the time offset right? the marker bearings against the offset, the offset in use",
                "calibration": "was the camera mounted as the lever arms say? residuals before and after calibrate"}
    return {captions[k]: v for k, v in found.items()}


class _RunFacts(NamedTuple):
    """What summary.json says of the run, for the report: its start (s, total-station clock), time offset (s),
    images, images with a pose and duration (s)."""

    t0: float
    offset: float
    frames: int
    with_pose: int
    duration: float


def _start_report(run_dir: str, reference: Optional[str], summary, facts: _RunFacts, out_dir: str,
                  overview: Optional[str]) -> ev.Report:
    """The report's title, introduction, notes (the run's warnings and self-check findings) and overview."""
    bag_name = os.path.basename(str(summary.get("bag", ""))) or "?"
    rep = ev.Report(title=f"aruco_abs_orient report: {bag_name} ({os.path.basename(os.path.abspath(run_dir))})")
    rep.intro = (f"Recording `{summary.get('bag', '?')}`: {facts.duration:.1f} s, {facts.frames} images, time offset "
                 f"{1e3 * facts.offset:+.1f} ms, lever arms from {summary.get('lever_arms', '?')}; "
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
    return rep


def _coverage(rep: ev.Report, results: Dict[str, object], est, facts: _RunFacts, params, out_dir: str):
    """Coverage and gaps, what the run delivered: into ``results`` and the headline; returns the gaps."""
    t0, frames, with_pose = facts.t0, facts.frames, facts.with_pose
    end = t0 + facts.duration if facts.duration else None
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
    return holes


def _per_marker_table(obs: Dict[str, np.ndarray], markers, res_ok: np.ndarray, z_ok: np.ndarray) -> List[list]:
    """A row per marker: its observations, the share accepted, its residuals' mean and std, RMS residual/σ."""
    table = []
    for mid in sorted(markers):
        sel = obs["id"] == mid
        good = sel & res_ok
        z_m = ev.normalised_residuals(obs["residual"][sel & z_ok], obs["yaw_sigma"][sel & z_ok]) \
            if np.any(sel & z_ok) else None
        r = obs["residual"][good]
        table.append([mid, int(sel.sum()), f"{100 * float(np.mean(obs['accepted'][sel])):.0f} %",
                     ev.fmt_angle(float(np.mean(r))) if len(r) else "–",
                     ev.fmt_angle(float(np.std(r))) if len(r) else "–",
                     f"{z_m['rms']:.2f}" if z_m else "–"])
    return table


def _marker_sections(rep: ev.Report, results: Dict[str, object], obs: Dict[str, np.ndarray], out_dir: str):
    """What the marker yaws show without a reference: the pairwise agreement, the residuals, their σ consistency
    (from the rows with a finite positive σ), the per-marker table and the agreement plot. Returns (the pairwise
    differences or None, the per-marker table's rows)."""
    series = ev.per_marker_series(obs["time"], obs["id"], obs["yaw"])
    pw = None
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
    # a frame's yaw from a resection (no prism) carries no per-marker σ
    z_ok = res_ok & np.isfinite(obs["yaw_sigma"]) & (obs["yaw_sigma"] > 0)
    if np.any(res_ok):
        rs = ev.error_stats(obs["residual"][res_ok])
        results["residuals"] = rs
        rep.headline.append(("residuals (each accepted marker yaw − filtered yaw)",
                             f"RMS {ev.fmt_angle(rs.rmse)}, p95 {ev.fmt_angle(rs.p95)}; "
                             f"{100 * float(np.mean(acc)):.0f} % of marker yaws accepted", "–",
                             _doc("time-offset", "time offset", out_dir)))
    if np.any(z_ok):
        z = ev.normalised_residuals(obs["residual"][z_ok], obs["yaw_sigma"][z_ok])
        results["normalised_residuals"] = z
        rep.headline.append(("σ consistency (RMS of residual/σ; 1 = honest σ)",
                             f"{z['rms']:.2f}; {100 * z['share_within_2_sigma']:.0f} % within 2σ", "–",
                             _doc("time-offset", "time offset, calibration", out_dir)))
    table = _per_marker_table(obs, series, res_ok, z_ok)
    judged = np.array([not r.startswith("filter: buffered") for r in obs["reason"]], dtype=bool)  # not before
    agreement = ev.marker_agreement(obs["time"][judged], obs["id"][judged], obs["residual"][judged],
                                    acc[judged], obs["reason"][judged])                       # the filter ran
    results["marker_agreement"] = agreement
    rep.plots["do the markers agree? each marker's yaw against the frame's consensus, the pairs"] = \
        plots.plot_marker_agreement(os.path.join(out_dir, "marker_yaws.png"), agreement, pw)
    return pw, table


def _heading_and_position(rep: ev.Report, results: Dict[str, object], est, ref, reference: str, max_gap: float,
                          out_dir: str):
    """The heading's APE and 1 s RPE and the position error against the reference (results and headline).
    Returns the heading APE."""
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
    p_ref, _, ok = ref.interpolate(est.stamps)
    if np.any(ok):
        d = np.linalg.norm(est.positions[ok] - p_ref[ok], axis=1)
        results["position"] = {"rmse_m": float(np.sqrt(np.mean(d * d))), "median_m": float(np.median(d)),
                               "p95_m": float(np.percentile(d, 95)), "n": int(ok.sum())}
        rep.headline.insert(1, ("position of base_link vs reference",
                                f"RMSE {1e3 * results['position']['rmse_m']:.1f} mm", "–",
                                _doc("no-markers-found", "prism, lever arms", out_dir)))
    return ape


def _fused_section(rep: ev.Report, results: Dict[str, object], fused: str, clock: float, reference: str,
                   after: Optional[Tuple[str, float]], t0: float, params, out_dir: str, plotted) -> None:
    """The robot_localization EKF's output recorded in ``fused`` (stamps minus ``clock`` s) against the reference,
    from ``after`` or ``params.settle`` s after its first absolute yaw on; its heading curve and the stretches
    the node gave it no absolute yaw join ``plotted`` (the heading plot's (curves, spans))."""
    curves, spans = plotted
    max_gap = params.max_gap
    traj, ekf_sigma = odometry_from_bag(fused, clock_offset=clock)
    fed = topic_stamps(fused, clock_offset=clock)   # the absolute yaws the node gave the EKF
    first = float(fed[0]) if len(fed) else None
    link = "[robot_localization.md](" + os.path.relpath(os.path.join(DOC_DIR, "robot_localization.md"),
                                                        os.path.abspath(out_dir)) + ")"
    if after is None and first is None:
        why = (f"not judged: {os.path.basename(fused)} has no abs_orient/orientation, the EKF had no absolute "
               "yaw (the replay's last line says why)")
        results["fused_ekf"] = {"not_available": why}
        rep.headline.insert(2, ("robot_localization EKF (odometry/filtered)", why, "–",
                                _doc("a-replay-that-ends-or-fails", "replay", out_dir)))
        return
    if after is None:
        start = first + params.settle
        how = f"from {start - t0:.1f} s: {params.settle:g} s after its first absolute yaw"
    else:
        start = after[1] + (t0 if after[0] == "since_start" else 0.0)
        how = f"from {start - t0:.1f} s (--after)"
    f = fused_errors(traj, reference, after=start, max_gap=max_gap)
    f["clock_offset_s"] = clock
    results["fused_ekf"] = f
    curves.append(plots.HeadingCurve("robot_localization EKF", f["heading_ape"],
                                     np.interp(f["heading_ape"].t, traj.stamps, ekf_sigma)))
    spans += [plots.Span(a, b, "the node gave the EKF no absolute yaw")
              for a, b in ev.gaps(fed[fed >= start], params.min_gap, start, float(traj.stamps[-1]))]
    rep.headline.insert(2, ("robot_localization EKF (odometry/filtered)",
                            f"heading RMSE {ev.fmt_angle(f['heading_ape'].stats.rmse)}, position RMSE "
                            f"{1e3 * f['position']['rmse_m']:.1f} mm ({how})", "–", link))


def _markers_vs_reference(rep: ev.Report, results: Dict[str, object], obs: Dict[str, np.ndarray], ref,
                          per_marker_rows: List[list], max_gap: float, out_dir: str) -> bool:
    """Each marker's yaw error against the reference (two more columns of the per-marker rows) and the error by
    position in the frame (paper fig. 13). Returns whether the columns were added."""
    if obs is None or not len(obs["time"]):
        return False
    truth_at, ok = ev.interp_yaw(obs["time"], ref.stamps, yaw_of(ref.rotations), max_gap)
    err = wrap_angle(obs["yaw"] - truth_at)
    per = {}
    for row in per_marker_rows:
        sel = ok & (obs["id"] == row[0])
        st = ev.error_stats(err[sel]) if np.any(sel) else None
        per[f"marker {row[0]}"] = st
        row += [ev.fmt_angle(st.bias) if st else "–", ev.fmt_angle(st.rmse) if st else "–"]
    results["per_marker_yaw_vs_reference"] = {k: v for k, v in per.items() if v is not None}
    if np.any(ok):
        bias = ev.error_by_frame_position(obs["azimuth"][ok], obs["elevation"][ok], err[ok])
        results["error_by_frame_position"] = bias
        rep.plots["yaw error by position in the frame (paper fig. 13)"] = plots.plot_frame_position(
            os.path.join(out_dir, "frame_position.png"), bias)
    return True


def _tables(rep: ev.Report, results: Dict[str, object], per_marker, pw, holes, t0: float, summary) -> None:
    """The report's tables: per marker (``per_marker``: (columns, rows)), marker pairs, heading errors, gaps,
    the pipeline's counters."""
    per_marker_cols, per_marker_rows = per_marker
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
    os.makedirs(out_dir, exist_ok=True)
    summary = read_summary(run_dir)
    try:
        est = read_tum(os.path.join(run_dir, "trajectory.tum"))
        ref = read_tum(reference) if reference else None
    except TumError as e:
        raise EvaluateError(str(e)) from None
    facts = _RunFacts(float(summary.get("recording_start_s", est.stamps[0] if len(est.stamps) else 0.0)),
                      float(summary.get("time_offset_s", 0.0)), int(summary.get("frames", 0)),
                      int(summary.get("frames_with_pose", len(est.stamps))), float(summary.get("bag_duration_s", 0.0)))
    t0, offset = facts.t0, facts.offset
    rep = _start_report(run_dir, reference, summary, facts, out_dir, overview)
    results: Dict[str, object] = {}
    if len(est.stamps) == 0:
        reason = "; ".join(summary.get("warnings") or []) or "its summary.json says what it counted"
        raise EvaluateError(f"{run_dir}/trajectory.tum: no poses (the run never initialised: {reason})")
    holes = _coverage(rep, results, est, facts, params, out_dir)
    obs_path = os.path.join(run_dir, "observations.csv")
    rows = read_observations(obs_path, every_row=True) if os.path.exists(obs_path) else None
    obs = None if rows is None else {k: v[np.isfinite(rows["yaw"])] for k, v in rows.items()}   # with a marker yaw
    pw, per_marker_cols, per_marker_rows = None, [], []
    if obs is not None and len(obs["time"]):
        pw, per_marker_rows = _marker_sections(rep, results, obs, out_dir)
        per_marker_cols = ["marker", "observations", "accepted", "residual mean", "residual std", "RMS residual/σ"]
    if ref is not None:
        ape = _heading_and_position(rep, results, est, ref, reference, params.max_gap, out_dir)
        own = read_heading_sigma(run_dir)
        curves = [plots.HeadingCurve("processed heading", ape,
                                     None if own is None or not len(own[0]) else np.interp(ape.t, *own))]
        spans = [] if rows is None else no_update_spans(rows, float(est.stamps[0]), float(est.stamps[-1]),
                                                        params.min_gap)
        if fused:
            clock = offset if fused_clock_offset is None else fused_clock_offset
            _fused_section(rep, results, fused, clock, reference, after, t0, params, out_dir, (curves, spans))
        rejected = [] if obs is None else [
            (float(t), str(r)) for t, r, a in zip(obs["time"], obs["reason"], obs["accepted"])
            if not a and r and not r.startswith("filter: buffered")]
        rep.plots["is the heading right? its error, the filter's own ±2σ, the stretches without updates"] = \
            plots.plot_heading_error(os.path.join(out_dir, "heading_error.png"), curves, spans, rejected, t0=t0)
        if _markers_vs_reference(rep, results, obs, ref, per_marker_rows, params.max_gap, out_dir):
            per_marker_cols += ["vs reference: bias", "vs reference: RMSE"]
    rep.plots.update(_timesync_and_calibration(run_dir, out_dir, offset))
    rep.headline.append(("time offset in use (camera − total station)", f"{1e3 * offset:+.1f} ms", PAPER["time_offset"],
                         _doc("time-offset", "time offset", out_dir)))
    _tables(rep, results, (per_marker_cols, per_marker_rows), pw, holes, t0, summary)
    rep.data = {"recording_start_s": t0, "time_offset_s": offset, "reference": reference, **results,
                "selfcheck": summary.get("selfcheck"), "warnings": summary.get("warnings", [])}
    md, js = ev.write_report(out_dir, rep)
    results["report_md"], results["report_json"], results["headline"] = md, js, rep.headline
    results["notes"] = rep.notes
    return results

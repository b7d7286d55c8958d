"""``aruco-abs-orient timesync``: the camera/VO ↔ total-station time offset of a recording.

Uses the odometry yaw (``odom → base_link`` on /tf, camera clock) and the prism track (total-station
clock) of a bag: the phase-coherence estimate of :mod:`aruco_abs_orient.timesync` (doc/design.md §10,
invariant to the unknown yaw offset), with the paper's cross-correlation printed beside it.

With the marker map, the estimate is refined with the marker bearings: a time offset moves the
camera along its track by speed × offset, which turns the bearing of every marker by an amount that
depends on its range and direction; the least squares of :func:`aruco_abs_orient.calibration.calibrate`
with the offset as an unknown (beside the boresight, which it must not absorb) find it to a fraction
of a millisecond, where the heading alone is limited by the VO's yaw drift and random walk. Where the
heading gives no estimate (a drive at a constant turn rate has no phase to follow), the marker bearings
alone start the refinement: :func:`marker_offset_scan` over the searched offsets.

The plot (``timesync.png``, :func:`aruco_abs_orient.plots.plot_time_offset`) shows what the answer rests on:
the marker bearings' residual with the offset held at offsets around it (:func:`marker_offset_cost`), the
coarse estimate's coherence as context; ``timesync.json`` beside it keeps those curves, so that ``evaluate``
draws them again with the offset a run was processed with (:func:`plot_offset_file`).
"""

from __future__ import annotations

import json
import math
import os
from typing import Dict, Optional, Tuple

import numpy as np

from .. import timesync
from ..calibration import Calibration, CalibrationError, CalibrationParams, Unknowns
from ..markers import MarkerMap
from ..params import Tunables, parse_params
from ..transforms import yaw_of
from ..tum import atomic_write_text
from .bagio import BagData, BagTopics, bag_name, read_bag_data
from .calibrate import calibrate_bag, collect_observations
from .commandlines import calibration_every

__all__ = ["estimate_bag_offset", "marker_offset_estimate", "marker_offset_cost", "marker_offset_scan",
           "plot_offset_file"]

#: σ (s) at which the confidence of a marker-bearing estimate has fallen to 1/2: about a frame at 30-50 fps
MARKER_SIGMA_REF = 0.020
#: the scan's grid (s) and its most offsets: a grid step moves a marker 3 m away by ≤ 2° at 1 m/s, inside the
#: refinement's reach; a wider search is sampled evenly with at most that many offsets
SCAN_STEP, SCAN_MAX = 0.1, 51
#: a bearing residual counts up to this (rad) in the scan's cost: a far-off offset's outliers do not decide it
SCAN_CAP = math.radians(2.0)
#: the refinement's largest accepted 1-σ (s): it is judged by its confidence, not refused at calibrate's 5 ms
MARKER_MAX_SIGMA = 0.05


def marker_offset_estimate(coarse: float, cal: Calibration) -> timesync.OffsetEstimate:
    """The offset (s) refined by a calibration with ``estimate_time_offset``: ``coarse`` (the offset
    the calibration was given) + its Δτ, as an :class:`~aruco_abs_orient.timesync.OffsetEstimate`
    (method "marker bearings"; confidence = share of observations kept × 1/(1 + (σ/5 ms)²))."""
    sigma = float(cal.time_offset_sigma)
    confidence = cal.n_used / max(cal.n_observations, 1) / (1.0 + (sigma / MARKER_SIGMA_REF) ** 2)
    return timesync.OffsetEstimate(offset=coarse + cal.time_offset_delta, sigma=sigma, confidence=confidence,
                                   coherence=float("nan"), taus=np.empty(0), curve=np.empty(0),
                                   method="marker bearings", n_samples=cal.n_used, overlap=cal.moving_time,
                                   extra={"boresight_rpy_deg": [math.degrees(float(a)) for a in cal.boresight_rpy]})


def marker_offset_cost(bag: str, marker_map: MarkerMap, observations, cal: Calibration, offset: float, coarse,
                       topics: Optional[BagTopics] = None, n: int = 15) -> Tuple[np.ndarray, np.ndarray]:
    """The marker bearings against the time offset: (offsets s, RMS rad) of the bearing residuals of the
    observations ``cal`` (a refinement at ``offset`` s) kept, the boresight fitted again with the offset held at
    each of ``n`` offsets spanning ``offset`` ± 60 ms and the ``coarse`` estimate ± 2σ; offsets the recording
    cannot be calibrated at are left out."""
    lo = min(offset - 0.06, coarse.offset - 2.0 * coarse.sigma)
    hi = max(offset + 0.06, coarse.offset + 2.0 * coarse.sigma)
    lo, hi = max(lo, offset - 0.5), min(hi, offset + 0.5)   # a loose coarse σ: the bowl, not the whole search
    params = CalibrationParams(max_boresight_sigma_deg=1.0, heading_model=cal.heading_model)
    offsets, rms = [], []
    for tau in np.unique(np.append(np.linspace(lo, hi, n), offset)):
        try:
            res = calibrate_bag(bag, marker_map, float(tau), topics, observations=observations, params=params)
        except CalibrationError:
            continue
        r = res.residuals_after[cal.used]
        r = r[np.isfinite(r)]
        if len(r):
            offsets.append(float(tau))
            rms.append(float(np.sqrt(np.mean(r * r))))
    return np.asarray(offsets), np.asarray(rms)


def marker_offset_scan(bag: str, marker_map: MarkerMap, observations, search: Tuple[float, float],
                       topics: Optional[BagTopics] = None) -> timesync.OffsetEstimate:
    """The offset (s) from the marker bearings alone, where the VO heading gives none: the boresight fitted at
    offsets :data:`SCAN_STEP` apart over ``search`` (at most :data:`SCAN_MAX`, evenly), each judged by the mean
    of its squared bearing residuals capped at :data:`SCAN_CAP`; the best, with σ = the grid step (method
    "marker scan", its cost curve in ``taus``/``curve``, the confidence of that σ), starts
    :func:`marker_offset_estimate`'s refinement. Raises ``timesync.TimeSyncError`` when no offset of the
    search can be calibrated."""
    n = int(min(SCAN_MAX, max(3, math.floor((search[1] - search[0]) / SCAN_STEP) + 1)))
    params = CalibrationParams(max_boresight_sigma_deg=1.0)
    taus, cost = [], []
    for tau in np.linspace(search[0], search[1], n):
        try:
            res = calibrate_bag(bag, marker_map, float(tau), topics, progress=False, observations=observations,
                                params=params)
        except CalibrationError:
            continue
        r = np.asarray(res.residuals_after, dtype=float)
        r = np.minimum(np.abs(r[np.isfinite(r)]), SCAN_CAP)
        if len(r):
            taus.append(float(tau))
            cost.append(float(np.mean(r * r)))
    if not taus:
        raise timesync.TimeSyncError(f"no offset from {search[0]:+.2f} to {search[1]:+.2f} s fits the marker "
                                     "bearings: check the marker map and the search (--search)")
    best = int(np.argmin(cost))
    step = (search[1] - search[0]) / max(n - 1, 1)
    return timesync.OffsetEstimate(offset=taus[best], sigma=step, coherence=float("nan"),
                                   confidence=1.0 / (1.0 + (step / MARKER_SIGMA_REF) ** 2),
                                   taus=np.asarray(taus), curve=np.sqrt(np.asarray(cost)), method="marker scan",
                                   n_samples=len(observations.times), overlap=float("nan"))


def _estimate_dict(est) -> Optional[dict]:
    if not isinstance(est, timesync.OffsetEstimate):
        return None
    return {"offset_s": est.offset, "sigma_s": est.sigma, "confidence": est.confidence, "method": est.method,
            "peak": None if not math.isfinite(est.coherence) else est.coherence, "samples": est.n_samples,
            "overlap_s": est.overlap, "taus_s": [float(x) for x in est.taus], "curve": [float(x) for x in est.curve]}


def _estimate(d: Optional[dict]):
    if not d:
        return None
    return timesync.OffsetEstimate(offset=d["offset_s"], sigma=d["sigma_s"], confidence=d["confidence"],
                                   coherence=float("nan") if d["peak"] is None else d["peak"],
                                   taus=np.asarray(d["taus_s"]), curve=np.asarray(d["curve"]), method=d["method"],
                                   n_samples=d["samples"], overlap=d["overlap_s"])


def _write_plot(plot_dir: str, out: Dict[str, object]) -> str:
    """``timesync.png`` and ``timesync.json`` (the curves it draws) of :func:`estimate_bag_offset`'s results."""
    from ..plots import plot_time_offset

    os.makedirs(plot_dir, exist_ok=True)
    cost = out.get("cost")
    data = {"coarse": _estimate_dict(out["timesync"]), "baseline": _estimate_dict(out.get("timesync_baseline")),
            "refined": _estimate_dict(out.get("timesync_markers")),
            "cost": None if cost is None else {"offsets_s": [float(x) for x in cost[0]],
                                               "rms_rad": [float(x) for x in cost[1]]}}
    atomic_write_text(os.path.join(plot_dir, "timesync.json"), json.dumps(data) + "\n")
    return plot_time_offset(os.path.join(plot_dir, "timesync.png"), out["timesync"], _estimate(data["refined"]),
                            cost, baseline=_estimate(data["baseline"]))


def plot_offset_file(json_path: str, png_path: str, in_use: Optional[float] = None) -> str:
    """``timesync.png`` drawn again from the ``timesync.json`` that ``timesync --plot`` wrote, with the offset
    ``in_use`` (s) by a processed run judged against it; returns ``png_path``. Raises ValueError (or OSError)
    for a file that is not one."""
    from ..plots import plot_time_offset

    with open(json_path) as f:
        data = json.load(f)
    cost = data.get("cost")
    return plot_time_offset(png_path, _estimate(data["coarse"]), _estimate(data.get("refined")),
                            None if not cost else (np.asarray(cost["offsets_s"]), np.asarray(cost["rms_rad"])),
                            in_use=in_use, baseline=_estimate(data.get("baseline")))


def default_search(data: BagData, min_overlap: float = 10.0) -> Tuple[float, float]:
    """Offsets (s) to search when none are given: ±1 s for a bag (one clock, a small latency); for
    separate clocks (a video) every offset at which the VO and the prism track overlap by
    ``min_overlap`` s or more (an offset of hundreds of seconds, or of an epoch, is found as well)."""
    if not data.separate_clocks or len(data.prism_stamps) < 2:
        return (-1.0, 1.0)
    lo = data.odom.stamps[0] - data.prism_stamps[-1] + min_overlap
    hi = data.odom.stamps[-1] - data.prism_stamps[0] - min_overlap
    if hi <= lo:
        raise timesync.TimeSyncError(
            f"the trajectory ({data.odom.stamps[-1] - data.odom.stamps[0]:.1f} s) and the prism log "
            f"({data.prism_stamps[-1] - data.prism_stamps[0]:.1f} s) cannot overlap by {min_overlap:g} s")
    return (float(lo), float(hi))


def estimate_bag_offset(bag: str, topics: Optional[BagTopics] = None, search: Optional[Tuple[float, float]] = None,
                        plot_dir: Optional[str] = None, marker_map: Optional[MarkerMap] = None,
                        every: Optional[int] = None,
                        progress: bool = False, params: Optional[Tunables] = None) -> Dict[str, object]:
    """``{"timesync": OffsetEstimate, "timesync_baseline": OffsetEstimate or reason}`` of a bag, and
    with ``marker_map`` ``"timesync_markers"``: the estimate refined with the marker bearings of every
    ``every``-th image (default :func:`~.commandlines.calibration_every`; an OffsetEstimate, or the reason it is
    not possible). ``"timesync"`` is the VO
    heading's estimate; where the heading gives none and ``marker_map`` is given, the marker bearings'
    :func:`marker_offset_scan` (``"heading_refused"``: why the heading gave none); ``"image_rate"``: images/s.
    ``search``: the offsets
    searched (default :func:`default_search`). ``params``: the tunables (``load_params``): the estimate's
    ``timesync`` knobs, and the ``detection`` knobs of the marker search (default: every default).

    Offsets in seconds, camera stamps = total-station time + offset. Raises
    ``timesync.TimeSyncError`` when the recording cannot determine it (no motion, too short).
    """
    params = params or parse_params({})
    data = read_bag_data(bag, topics)
    if len(data.prism_stamps) < 2:
        raise timesync.TimeSyncError(f"{bag_name(bag)}: no prism track: the time offset needs the total "
                                     "station's positions")
    search = search or default_search(data)
    t_vo, yaw_vo = data.odom.stamps, yaw_of(data.odom.rotations)
    t_tr, xy = data.prism_stamps, data.prism_positions[:, :2]
    out: Dict[str, object] = {"image_rate": data.image_rate}
    try:
        out["timesync"] = timesync.estimate_offset(t_vo, yaw_vo, t_tr, xy, search=search, params=params.timesync,
                                                   prism_in_base=data.base_T_prism[:3, 3])
    except timesync.TimeSyncError as e:
        if marker_map is None:
            raise
        out["heading_refused"] = str(e)
    try:
        out["timesync_baseline"] = timesync.cross_correlation_offset(t_vo, yaw_vo, t_tr, xy, search=search,
                                                                     track_heading="smoothed")
    except timesync.TimeSyncError as e:
        out["timesync_baseline"] = {"not_available": str(e)}
    if marker_map is not None:
        _refine_with_markers(out, bag, marker_map, topics, data, search, every, progress, params, plot_dir)
    if plot_dir:
        out["plot"] = _write_plot(plot_dir, out)
    return out


def _refine_with_markers(out: Dict[str, object], bag: str, marker_map: MarkerMap, topics, data: BagData,
                         search: Tuple[float, float], every: Optional[int], progress: bool, params: Tunables,
                         plot_dir: Optional[str]) -> None:
    """:func:`estimate_bag_offset`'s refinement with the marker bearings, into ``out`` (the scan first where the
    heading gave no estimate)."""
    obs = collect_observations(bag, marker_map, topics, progress, params.detection, data=data,
                               every=every or calibration_every(data.image_rate), label="timesync: detect")
    if "timesync" not in out:
        out["timesync"] = marker_offset_scan(bag, marker_map, obs, search, topics)
    coarse = out["timesync"]
    try:
        cal = calibrate_bag(bag, marker_map, coarse.offset, topics, progress=False, observations=obs,
                            unknowns=Unknowns(time_offset=True),
                            params=CalibrationParams(max_boresight_sigma_deg=1.0,
                                                     max_time_offset_sigma=MARKER_MAX_SIGMA))
    except CalibrationError as e:
        out["timesync_markers"] = {"not_available": str(e)}
        return
    refined = marker_offset_estimate(coarse.offset, cal)
    out["timesync_markers"] = refined
    if plot_dir:
        out["cost"] = marker_offset_cost(bag, marker_map, obs, cal, refined.offset, coarse, topics)

"""Self-checks of a run from its own observations: does the run agree with itself, and if not, why?

In: a run's marker yaws and observations (times, ids, bearings, σ, the pipeline's counters), the prism track and,
optionally, the calibration's model (:class:`ModelContext`: map, mounting, lenses, readout, offset in use). Out:
findings, each with its size, σ, likely cause and the command that fixes it: a wrong time offset, a tilted
camera, a boresight yaw (or a crabbing platform), a moved or wrongly surveyed marker, and the rates and σ
consistency (the share accepted, the RMS of residual/σ). ``check_run`` is what ``process`` calls at the end of a
run; :class:`RollingSelfCheck` keeps a bounded window for a live node (``diagnostics()``: a level, a message and
key/values for ``/diagnostics``). The fits: doc/design.md §12. ROS-free; radians and seconds inside, degrees and
ms in messages.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field, replace
from typing import Deque, Dict, List, Mapping, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .calibration import CalibrationError, CalibrationParams, Recording, Unknowns, calibrate
from .camera import SINGLE_CENTRE, DualFisheye, azel_to_bearing
from .markers import MarkerMap
from .paramspec import Params, param
from .transforms import wrap_angle
from .tum import Trajectory
from .yawfit import FitData, bearing_rate, moved_markers, tilt_fit

__all__ = ["SelfCheckParams", "Finding", "YawObservation", "RunContext", "ModelContext", "bearing_rate",
           "observation_columns", "check_run", "RollingSelfCheck"]


@dataclass(frozen=True)
class SelfCheckParams(Params):
    """Thresholds of the self-checks (cfg/params.yaml's ``selfcheck`` section): a finding needs both the
    significance and the size."""

    knot_spacing: float = param(5.0, "spacing of the hat functions of the common (filter) part of the residuals",
                                "s", above=0.0)
    common_drift_sigma: float = param(math.radians(0.5), "1-σ of the second difference of the common part over "
                                      "three adjacent knots (how far its drift may bend; markers seen only in "
                                      "separate stretches of the run are compared through it)", "rad", above=0.0)
    sigma_floor: float = param(math.radians(0.02), "added to each yaw σ (model errors beyond the pixel noise)",
                               "rad", 0.0)
    significance: float = param(5.0, "a finding needs |estimate| > this × its σ", "σ", 0.0)
    tilt_significance: float = param(4.0, "the same for the camera tilt (two components, fitted on every yaw)",
                                     "σ", 0.0)
    min_offset: float = param(0.02, "smallest time offset error reported", "s", 0.0)
    min_tilt: float = param(math.radians(0.1), "smallest camera tilt reported", "rad", 0.0)
    min_heading_travel: float = param(math.radians(0.15), "smallest heading vs direction of travel difference "
                                      "reported", "rad", 0.0)
    min_marker_bias: float = param(math.radians(0.5), "a marker this far off the others is reported", "rad", 0.0)
    min_accepted_share: float = param(0.7, "below this share of marker yaws accepted the rejections are reported",
                                      "", 0.0, 1.0)
    max_normalised_rms: float = param(3.0, "above this RMS of residual/σ the σ are reported as too optimistic", "",
                                      0.0)
    straight_speed: float = param(0.2, "slower is not driving straight", "m/s", 0.0)
    straight_turn_rate: float = param(math.radians(2.0), "faster is turning", "rad/s", 0.0)
    min_samples: int = param(30, "fewer marker yaws give no finding", "", 1)
    model_observations: int = param(1500, "the calibration model's check takes at most this many bearings (whole "
                                    "frames)", "", 1)
    live_model_observations: int = param(600, "the node's model check takes at most this many (about a second of "
                                         "CPU a minute, beside the image thread)", "", 1)
    model_interval: float = param(60.0, "wall time between a live node's model checks (a few s of CPU each)", "s",
                                  0.0)


@dataclass
class Finding:
    """One self-check that failed: ``kind`` (time_offset, camera_tilt, boresight_yaw, marker, rejections,
    sigma), ``message`` (cause and fix, one line), ``doc`` (anchor in doc/troubleshooting.md)."""

    kind: str
    message: str
    doc: str = "time-offset"
    value: Optional[float] = None

    def as_dict(self) -> Dict[str, object]:
        return {"kind": self.kind, "message": self.message, "doc": self.doc, "value": self.value}


def _deg(x: float) -> str:
    return f"{math.degrees(x):+.2f}°"


class YawObservation(NamedTuple):
    """One marker yaw for the self-checks: ``time`` (s, total-station clock), ``id``, ``azimuth``, ``elevation``
    (rad, camera frame), ``yaw_sigma``, ``residual`` (rad; NaN before the filter started), ``accepted`` (the
    filter took it), and when known ``yaw`` and ``odom_yaw`` (rad: the marker's yaw of base_link and the
    odometry's at that time) and ``bearing_sigma`` (rad: the detection's, for the calibration model's check)."""

    time: float
    id: int
    azimuth: float
    elevation: float
    yaw_sigma: float
    residual: float
    accepted: bool
    yaw: float = math.nan
    odom_yaw: float = math.nan
    bearing_sigma: float = math.nan


def observation_columns(rows: Sequence[Sequence]) -> Dict[str, np.ndarray]:
    """:func:`check_run`'s ``obs`` from rows in :class:`YawObservation`'s order."""
    cols = list(zip(*rows)) if rows else [()] * len(YawObservation._fields)
    return {k: np.asarray(v) for k, v in zip(YawObservation._fields, cols)}


class RunContext(NamedTuple):
    """What :func:`check_run` says about the run besides its data: the pipeline's counters ``stats`` and the
    number of ``frames``; the ``time_offset`` (s) in use; ``commands``: the command lines that fix things
    ({"timesync": ..., "calibrate": ...}), quoted in the messages; ``prism_lever``: the prism in base_link (m;
    None: at its origin), whose swing in turns (yaw rate × lever arm) is taken out of the track's direction
    of travel."""

    stats: Optional[Mapping[str, int]] = None
    frames: int = 0
    time_offset: float = 0.0
    commands: Optional[Mapping[str, str]] = None
    prism_lever: Optional[Sequence[float]] = None
    model: Optional[ModelContext] = None


class ModelContext(NamedTuple):
    """What ``calibrate``'s model needs beside the observations, as the run used it: the ``marker_map``, the
    ``odometry`` (odom_T_base_link on the observations' clock: the total station's), the mounting in use
    (``base_T_camera``, ``base_T_prism``, 4×4), the camera's ``lenses``, its rolling-shutter ``readout`` (s) and
    calibrate's ``params`` (its heading model)."""

    marker_map: MarkerMap
    odometry: Trajectory
    base_T_camera: np.ndarray
    base_T_prism: np.ndarray
    lenses: DualFisheye = SINGLE_CENTRE
    readout: float = 0.0
    params: Optional[CalibrationParams] = None


def model_check(obs: Mapping[str, np.ndarray], prism, model: ModelContext, time_offset: float,
                commands: Mapping[str, str], p: SelfCheckParams) -> Tuple[Dict[str, object], List[Finding]]:
    """The calibration's model on the run's own marker bearings (``obs``: :func:`check_run`'s, with
    ``bearing_sigma``), the mounting, lenses and time offset in use as the nominal: what ``calibrate`` would still
    change (boresight, time offset) with its σ, and a finding for each change beyond its significance and size.
    Returns (the estimates, in degrees and seconds; the findings)."""
    t = np.asarray(obs.get("time", ()), dtype=float)
    sig = np.asarray(obs.get("bearing_sigma", np.full(len(t), np.nan)), dtype=float)
    az, el = np.asarray(obs.get("azimuth", ()), dtype=float), np.asarray(obs.get("elevation", ()), dtype=float)
    ok = np.isfinite(t) & np.isfinite(sig) & (sig > 0) & np.isfinite(az) & np.isfinite(el)
    frames = np.unique(t[ok])
    if len(frames) and ok.sum() > p.model_observations:   # whole frames, evenly: at most model_observations
        keep = frames[::int(math.ceil(ok.sum() / p.model_observations))]
        ok &= np.isin(t, keep)
    ids = np.asarray(obs.get("id", ()), dtype=int)
    # the check judges by significance, it refuses nothing; a time offset error well below the smallest it reports
    # needs no second solve with the clock moved by it (that moves the estimates by a fraction of their σ)
    params = model.params or CalibrationParams()
    params = replace(params, max_boresight_sigma_deg=1e9, max_time_offset_sigma=1e9,
                     clock_tolerance=max(p.min_offset / 4, params.clock_tolerance))
    rec = Recording(t[ok], ids[ok], azel_to_bearing(az[ok], el[ok]), sig[ok], model.odometry,
                    np.asarray(prism[0], dtype=float), np.asarray(prism[1], dtype=float).reshape(-1, 3),
                    model.marker_map, model.base_T_camera, model.base_T_prism, -el[ok] / math.pi, model.lenses)
    try:
        cal = calibrate(rec, Unknowns(time_offset=True), params, readout=model.readout)
    except CalibrationError as e:
        return {"model": f"not possible: {e}"}, []
    rpy, sd = cal.boresight_rpy, cal.boresight_sigma
    eps, eps_sigma = float(cal.time_offset_delta), float(cal.time_offset_sigma)
    out: Dict[str, object] = {
        "model": f"calibrate on {cal.n_used} bearings ({cal.heading_model})",
        "boresight_correction_deg": [math.degrees(float(a)) for a in rpy],
        "boresight_sigma_deg": [math.degrees(float(a)) for a in sd],
        "time_offset": {"in_use_s": time_offset, "error_s": eps, "sigma_s": eps_sigma,
                        "suggested_s": time_offset + eps, "samples": int(cal.n_used)}}
    fix = commands.get("calibrate", "aruco-abs-orient calibrate")
    findings: List[Finding] = []
    if _offset_error_significant(eps, eps_sigma, p):
        findings.append(Finding("time_offset", f"the marker bearings fit a time offset of {time_offset + eps:+.4f} s "
                                f"(in use {time_offset:+.4f} s: {1e3 * eps:+.1f} ± {1e3 * eps_sigma:.1f} ms); run "
                                f"`{fix}` (or `{commands.get('timesync', 'aruco-abs-orient timesync')}`)",
                                "time-offset", time_offset + eps))
    tilted = [abs(a) > max(p.tilt_significance * s, p.min_tilt) for a, s in zip(rpy[:2], sd[:2])]
    if any(tilted):
        findings.append(Finding("camera_tilt", f"the marker bearings fit a camera turned by roll {_deg(rpy[0])} ± "
                                f"{math.degrees(sd[0]):.2f}°, pitch {_deg(rpy[1])} ± {math.degrees(sd[1]):.2f}° from "
                                f"its calibration; calibrate the boresight: run `{fix}`", "heading-wrong-by-180",
                                math.degrees(float(np.hypot(rpy[0], rpy[1])))))
    if abs(rpy[2]) > max(p.significance * sd[2], p.min_heading_travel):
        findings.append(Finding("boresight_yaw", f"the marker bearings fit a camera turned by {_deg(rpy[2])} ± "
                                f"{math.degrees(sd[2]):.2f}° in yaw from its calibration ({cal.heading_model_reason}); "
                                f"run `{fix}`", "heading-wrong-by-180", math.degrees(float(rpy[2]))))
    return out, findings


def _offset_error_significant(error: float, sigma: float, p: SelfCheckParams) -> bool:
    """Whether a time-offset error (s) with its 1-σ (s) is a finding: beyond ``significance`` σ and
    ``min_offset``."""
    return abs(error) > max(p.significance * sigma, p.min_offset)


def _rates(out: Dict[str, object], findings: List[Finding], acc: np.ndarray, res: np.ndarray, sig: np.ndarray,
           ok: np.ndarray, stats, frames: int, p: SelfCheckParams) -> None:
    """The share accepted, the rejections per frame (a finding when too few are accepted) and the RMS of
    residual/σ, into ``out`` and ``findings``."""
    out["accepted_share"] = float(np.mean(acc)) if len(acc) else None
    if stats:
        out["rejections_per_frame"] = {k: v / max(frames, 1) for k, v in sorted(stats.items())
                                       if k.startswith("rejected") and v}
    if len(acc) >= p.min_samples and float(np.mean(acc)) < p.min_accepted_share:
        worst = max((out.get("rejections_per_frame") or {"-": 0}).items(), key=lambda kv: kv[1])
        findings.append(Finding("rejections", f"only {100 * float(np.mean(acc)):.0f} % of the marker yaws were "
                                f"accepted (most rejections: {worst[0]}, {worst[1]:.2f} per frame): the markers "
                                "disagree with the prism, the odometry or each other; see the other checks",
                                "no-markers-found", float(np.mean(acc))))
    z_all = wrap_angle(res[ok & acc]) / np.hypot(sig[ok & acc], p.sigma_floor) if np.any(ok & acc) else np.zeros(0)
    out["normalised_residual_rms"] = float(np.sqrt(np.mean(z_all ** 2))) if len(z_all) else None


def _fit_data(obs: Mapping[str, np.ndarray], t: np.ndarray, ids: np.ndarray, res: np.ndarray, ok: np.ndarray,
              sig: np.ndarray, prism, marker_xyz) -> Tuple[FitData, np.ndarray]:
    """(the fits' data, which yaws can be fitted): the map→odom yaw of each marker yaw when ``obs`` has the
    odometry's yaws (else the residual), with the bearing rate of its marker from the prism track."""
    prism_t, prism_xyz = prism
    y, fit_ok = res, ok
    if "odom_yaw" in obs and len(obs["odom_yaw"]) == len(t):  # the map→odom yaw of each marker yaw
        y = wrap_angle(np.asarray(obs["yaw"], dtype=float) - np.asarray(obs["odom_yaw"], dtype=float))
        if np.any(np.isfinite(y)):  # centred: the fit's linear terms need no wrap
            y = wrap_angle(y - float(np.angle(np.mean(np.exp(1j * y[np.isfinite(y)])))))
        fit_ok = np.isfinite(y) & np.isfinite(sig) & (sig > 0)
    if prism_t is not None and len(prism_t) >= 2 and len(t) > 0:
        mxyz = np.array([marker_xyz.get(int(i), (np.nan, np.nan, np.nan)) for i in ids], dtype=float).reshape(-1, 3)
        k = bearing_rate(t, mxyz, prism_t, prism_xyz)
    else:
        k = np.full(len(t), np.nan)
    az = np.asarray(obs.get("azimuth", ()), dtype=float)
    el = np.asarray(obs.get("elevation", ()), dtype=float)
    return FitData(t, ids, y, sig, k, az, el), fit_ok


def _offset_and_tilt(out: Dict[str, object], findings: List[Finding], fits, samples: int, time_offset: float,
                     commands: Mapping[str, str], p: SelfCheckParams) -> None:
    """The time offset's error and the camera tilt from the run's own fits (``fits``: (x, cov) with the
    per-marker offsets, and the tilt fit or None), their findings (the tilt not while the offset is off)."""
    (x, cov), own_tilt = fits
    eps, eps_sigma = float(x[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    xt, ct = own_tilt if own_tilt is not None else (x, cov)
    tilt = np.array(xt[1:3])
    tilt_sigma = float(math.sqrt(max(ct[1, 1] + ct[2, 2], 0.0) / 2))
    suggested = time_offset + eps
    out["time_offset"] = {"in_use_s": time_offset, "error_s": eps, "sigma_s": eps_sigma,
                          "suggested_s": suggested, "samples": samples}
    out["camera_tilt_deg"] = {"roll": math.degrees(tilt[0]), "pitch": math.degrees(tilt[1]),
                              "sigma": math.degrees(tilt_sigma)}
    if _offset_error_significant(eps, eps_sigma, p):
        fix = commands.get("timesync", "aruco-abs-orient timesync")
        findings.append(Finding("time_offset", f"observations disagree with a time offset: this run suggests "
                                f"{suggested:+.2f} s (in use {time_offset:+.3f} s, error {1e3 * eps:+.0f} ± "
                                f"{1e3 * eps_sigma:.0f} ms); run `{fix}`", "time-offset", suggested))
    size = float(np.hypot(*tilt))
    offset_found = findings and findings[-1].kind == "time_offset"  # it biases the tilt: fix it first
    if size > max(p.tilt_significance * tilt_sigma, p.min_tilt) and not offset_found:
        fix = commands.get("calibrate", "aruco-abs-orient calibrate")
        findings.append(Finding("camera_tilt", f"marker yaws depend on where the marker is in the image: the "
                                f"camera looks tilted by {math.degrees(size):.2f}° (roll {_deg(tilt[0])}, "
                                f"pitch {_deg(tilt[1])}) against its lever arms; calibrate the boresight: "
                                f"run `{fix}`", "heading-wrong-by-180", math.degrees(size)))


def _heading_vs_travel(out: Dict[str, object], findings: List[Finding], poses, prism, prism_lever,
                       commands: Mapping[str, str], p: SelfCheckParams) -> None:
    """Boresight yaw: on straight stretches the heading of base_link against the direction the prism track runs
    in (the prism's swing in turns taken out with ``prism_lever``)."""
    prism_t, prism_xyz = prism
    pose_t = np.asarray(poses[0], dtype=float)
    pose_yaw = np.asarray(poses[1], dtype=float)
    if not (len(pose_t) > 10 and prism_t is not None and len(prism_t) >= 2):
        return
    pt, pp = np.asarray(prism_t, dtype=float), np.asarray(prism_xyz, dtype=float).reshape(-1, 3)
    h = 0.25
    inside = (pose_t - h >= pt[0]) & (pose_t + h <= pt[-1])
    vx = (np.interp(pose_t + h, pt, pp[:, 0]) - np.interp(pose_t - h, pt, pp[:, 0])) / (2 * h)
    vy = (np.interp(pose_t + h, pt, pp[:, 1]) - np.interp(pose_t - h, pt, pp[:, 1])) / (2 * h)
    rate = np.gradient(np.unwrap(pose_yaw), pose_t) if len(pose_t) > 1 else np.zeros(0)
    if prism_lever is not None:  # base_link origin's velocity: the prism's minus ω ẑ × (Rz(ψ) · lever)
        lx, ly = float(prism_lever[0]), float(prism_lever[1])
        c, s = np.cos(pose_yaw), np.sin(pose_yaw)
        vx = vx + rate * (s * lx + c * ly)
        vy = vy - rate * (c * lx - s * ly)
    straight = inside & (np.hypot(vx, vy) > p.straight_speed) & (np.abs(rate) < p.straight_turn_rate)
    if straight.sum() < p.min_samples:
        return
    d = wrap_angle(pose_yaw[straight] - np.arctan2(vy[straight], vx[straight]))
    med = float(np.median(d))
    sem = 1.4826 * float(np.median(np.abs(d - med))) / math.sqrt(len(d))
    out["heading_minus_travel_deg"] = {"median": math.degrees(med), "sigma": math.degrees(sem),
                                       "samples": int(straight.sum())}
    if abs(med) > max(p.min_heading_travel, p.significance * sem):
        fix = commands.get("calibrate", "aruco-abs-orient calibrate")
        findings.append(Finding("boresight_yaw", f"on straight stretches the heading differs from the "
                                f"direction of travel by {_deg(med)} ({int(straight.sum())} poses): the "
                                f"camera's mounting yaw (or a platform that crabs); run `{fix}`",
                                "heading-wrong-by-180", math.degrees(med)))


def _marker_findings(findings: List[Finding], moved: List[int], per_marker, ids: np.ndarray,
                     acc: np.ndarray) -> None:
    """A finding per marker off the others (moved or wrongly surveyed)."""
    for mid in moved:
        med, n, _ = per_marker[mid]
        share = float(np.mean(acc[ids == mid]))
        findings.append(Finding("marker", f"marker {mid}: its yaws are off the other markers' by {_deg(med)} "
                                f"({n} yaws, {100 * share:.0f} % accepted): moved or wrongly surveyed; "
                                "re-survey its centre or take it out of the marker map", "jumps-in-the-heading",
                                math.degrees(med)))


def _concluded(out: Dict[str, object], findings: List[Finding], p: SelfCheckParams) -> List[Finding]:
    """The findings as reported: no marker finding beside a time offset one (a wrong offset biases each
    marker's yaws: fix it first), then σ's when the residuals are larger than their σ say, naming the causes."""
    if any(f.kind == "time_offset" for f in findings):
        findings = [f for f in findings if f.kind != "marker"]
    rms = out["normalised_residual_rms"]
    if rms is not None and rms > p.max_normalised_rms:
        causes = ", ".join(f.kind.replace("_", " ") for f in findings if f.kind in
                           ("time_offset", "camera_tilt", "boresight_yaw", "marker")) or "none of the checks above"
        findings.append(Finding("sigma", f"the residuals are {rms:.1f} times their predicted σ (1 when honest); "
                                f"likely cause: {causes}", "time-offset", rms))
    return findings


def check_run(obs: Mapping[str, np.ndarray], prism, marker_xyz: Mapping[int, Sequence[float]], poses=((), ()),
              run: Optional[RunContext] = None, params: Optional[SelfCheckParams] = None) -> Dict[str, object]:
    """The self-checks of a run (see the module docstring).

    ``obs``: per marker observation with a yaw, the arrays of :class:`YawObservation`'s fields
    (:func:`observation_columns`; ``yaw`` and ``odom_yaw`` optional: with them the time offset and tilt are
    fitted to their difference, the map→odom yaw, independent of what the filter accepted); ``prism``: the
    prism track (stamps (M,) s, positions (M, 3) m); the marker map's positions {id: [x, y, z]}; ``poses``:
    the filtered poses' (stamps, yaws (rad)); ``run``: :class:`RunContext` (with its ``model``, the time offset,
    tilt and boresight yaw are :func:`model_check`'s). Returns a JSON-able dict with the estimates (degrees,
    seconds) and ``findings`` (a list of :class:`Finding` dicts; empty when the run agrees with itself).
    """
    stats, frames, time_offset, commands, prism_lever, model = run or RunContext()
    commands = dict(commands or {})
    p = params or SelfCheckParams()
    out: Dict[str, object] = {}
    findings: List[Finding] = []
    t = np.asarray(obs.get("time", ()), dtype=float)
    ids = np.asarray(obs.get("id", ()), dtype=int)
    res = np.asarray(obs.get("residual", ()), dtype=float)
    sig = np.asarray(obs.get("yaw_sigma", ()), dtype=float)
    acc = np.asarray(obs.get("accepted", ()), dtype=bool)
    ok = np.isfinite(res) & np.isfinite(sig) & (sig > 0)
    out["observations"] = int(len(t))
    _rates(out, findings, acc, res, sig, ok, stats, frames, p)

    # one robust fit: a smooth common part + time offset + camera tilt; a marker off it is moved
    d, fit_ok = _fit_data(obs, t, ids, res, ok, sig, prism, marker_xyz)
    base = fit_ok & np.isfinite(d.k) & (np.abs(d.el) < math.radians(60))
    moved: List[int] = []
    x = cov = own_tilt = None
    per_marker: Dict[int, Tuple[float, int, float]] = {}
    if base.sum() >= p.min_samples:
        x, cov, per_marker, moved = moved_markers(d, base, p)
        out["marker_offset_deg"] = {m: math.degrees(v[0]) for m, v in per_marker.items()}
    keep = base & ~np.isin(ids, moved)
    if x is not None and keep.sum() >= p.min_samples:
        own_tilt = tilt_fit(d, keep, p)
    _marker_findings(findings, moved, per_marker, ids, acc)
    if model is not None:   # the time offset, tilt and boresight yaw as calibrate's own model sees them
        estimates, model_findings = model_check(obs, prism, model, time_offset, commands, p)
        out["model_check"] = estimates
        if "time_offset" in estimates:
            out["time_offset"] = estimates["time_offset"]
        findings += model_findings
    elif x is not None:
        _offset_and_tilt(out, findings, ((x, cov), own_tilt), int(base.sum()), time_offset, commands, p)
    if model is None:
        _heading_vs_travel(out, findings, poses, prism, prism_lever, commands, p)
    out["findings"] = [f.as_dict() for f in _concluded(out, findings, p)]
    return out


@dataclass
class RollingSelfCheck:
    """The self-checks over the last ``window`` s of a live node. Feed it with ``add_observation``,
    ``add_prism`` and ``add_pose`` (total-station clock), call ``diagnostics()`` every few seconds (it
    fits ~a few thousand observations: milliseconds) for ``/diagnostics``: (level ``ok``/``warn``,
    message, {key: value}). With ``model`` (a :class:`ModelContext` whose odometry is ignored: the window's
    poses are used) the time offset, tilt and boresight yaw are calibrate's model's on the window, first after
    ``model_interval`` s of data, then every ``model_interval`` s (about a second of CPU each), kept in between."""

    marker_xyz: Mapping[int, Sequence[float]]
    time_offset: float = 0.0
    window: float = 120.0
    params: Optional[SelfCheckParams] = None
    prism_lever: Optional[Sequence[float]] = None    # m, the prism in base_link (check_run's)
    last_time_offset: Optional[Dict[str, float]] = None  # the last check's time-offset estimate (check_run's)
    model: Optional[ModelContext] = None
    _obs: Deque[tuple] = field(default_factory=collections.deque)
    _prism: Deque[tuple] = field(default_factory=collections.deque)
    _poses: Deque[tuple] = field(default_factory=collections.deque)
    _odometry: Deque[tuple] = field(default_factory=collections.deque)
    _model_report: Optional[Tuple[float, Dict[str, object], List[dict]]] = None   # (data time, estimates, findings)

    def _trim(self, q: Deque[tuple], now: float) -> None:
        while q and q[0][0] < now - self.window:
            q.popleft()

    def add_observation(self, o: YawObservation) -> None:
        """One marker yaw: its bearing in the camera, σ, residual, whether the filter took it, and, when known,
        the yaw itself and the odometry's yaw (then the fit does not depend on what the filter accepted)."""
        self._obs.append(tuple(o))
        self._trim(self._obs, o.time)

    def add_prism(self, t: float, xyz: Sequence[float]) -> None:
        self._prism.append((t, tuple(float(v) for v in xyz)))
        self._trim(self._prism, t)

    def add_pose(self, t: float, yaw: float) -> None:
        self._poses.append((t, yaw))
        self._trim(self._poses, t)

    def add_odometry(self, t: float, odom_T_base) -> None:
        """The odometry's pose (4×4) at a frame's time (s): the model check's odometry."""
        self._odometry.append((t, np.asarray(odom_T_base, dtype=float)))
        self._trim(self._odometry, t)

    def _model_due(self) -> Optional[ModelContext]:
        """The model context for this check when one is due (``model_interval`` s of data since the last)."""
        if self.model is None or len(self._odometry) < 2 or not self._obs:
            return None
        newest, interval = self._obs[-1][0], (self.params or SelfCheckParams()).model_interval
        last = self._obs[0][0] if self._model_report is None else self._model_report[0]
        if newest - last < interval:      # the first after a window's worth of data, then every interval
            return None
        odometry = sorted(self._odometry, key=lambda p: p[0])
        traj = Trajectory.from_transforms(np.array([p[0] for p in odometry]), np.array([p[1] for p in odometry]))
        return self.model._replace(odometry=traj)

    def check(self) -> Dict[str, object]:
        obs = observation_columns(self._obs)
        if not np.any(np.isfinite(obs["odom_yaw"].astype(float))):
            del obs["yaw"], obs["odom_yaw"]
        prism = sorted(self._prism)
        poses = sorted(self._poses)
        model = self._model_due()
        run = RunContext(time_offset=self.time_offset, prism_lever=self.prism_lever, model=model)
        out = check_run(obs, ([p[0] for p in prism], [p[1] for p in prism]), self.marker_xyz,
                        ([p[0] for p in poses], [p[1] for p in poses]), run, self.params)
        kinds = ("time_offset", "camera_tilt", "boresight_yaw")
        if model is not None:
            self._model_report = (self._obs[-1][0], out.get("model_check", {}),
                                  [f for f in out["findings"] if f["kind"] in kinds])
        elif self._model_report is not None:   # the last model check's, not the regression's, in between
            _, estimates, found = self._model_report
            out["model_check"] = estimates
            if "time_offset" in estimates:
                out["time_offset"] = estimates["time_offset"]
            out["findings"] = found + [f for f in out["findings"] if f["kind"] not in kinds]
        return out

    def supports(self, offset: float) -> bool:
        """Whether the marker yaws of the last :meth:`diagnostics` agree with the time offset ``offset`` (s):
        within the time-offset check's own bound (``significance`` × its σ, at least ``min_offset``) of the
        offset they suggest. False while no check has estimated one."""
        off = self.last_time_offset
        if not off:
            return False
        return not _offset_error_significant(offset - off["suggested_s"], off["sigma_s"],
                                             self.params or SelfCheckParams())

    def diagnostics(self) -> Tuple[str, str, Dict[str, object]]:
        r = self.check()
        values: Dict[str, object] = {"self-check findings": len(r["findings"])}
        off = r.get("time_offset")
        self.last_time_offset = off
        if off:
            values["self-check suggested time offset [s]"] = off["suggested_s"]
            values["self-check time offset sigma [ms]"] = 1e3 * off["sigma_s"]
        if r.get("normalised_residual_rms") is not None:
            values["self-check residual/sigma RMS"] = r["normalised_residual_rms"]
        if not r["findings"]:
            return "ok", "self-checks pass", values
        return "warn", "; ".join(f["message"] for f in r["findings"]), values

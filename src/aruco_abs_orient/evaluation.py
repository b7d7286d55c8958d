"""Yaw-only evaluation: APE/RPE against a reference, per-marker agreement, frame-position bias and a
Markdown + JSON report (doc/design.md §12; the paper's figs. 11–13); the pictures are :mod:`.plots`'.

Angles are radians everywhere in this module except in ``report_dict()`` results, the plots and the
report files, which are in degrees (the edge). Yaw differences are always wrapped to [−π, π), and
a reference yaw is interpolated on the unit circle, so 179° vs −179° is a 2° error.

Statistics (``ErrorStats``) follow evo and the paper: ``rmse`` of the error, ``mean``, ``median``,
``std``, ``p95`` and ``max`` of its absolute value, the signed ``bias`` (mean error), the share of
samples with |error| under each threshold (the paper's 0.5/1/2°), and ``coverage`` = the fraction of
the estimate's samples that had a reference to compare with.

Python 3.8 compatible; numpy only.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

from .errors import InputFileError
from .paramspec import Params, param
from .plots import png_title
from .transforms import wrap_angle
from .tum import atomic_write_text, sorted_series

__all__ = [
    "EvaluationParams",
    "EvaluationError",
    "ErrorStats",
    "YawErrors",
    "PairwiseDifferences",
    "FramePositionBias",
    "interp_yaw",
    "error_stats",
    "yaw_ape",
    "yaw_rpe",
    "per_marker_series",
    "pairwise_differences",
    "error_by_frame_position",
    "MarkerAgreement",
    "marker_agreement",
    "fmt_angle",
    "normalised_residuals",
    "gaps",
    "md_table",
    "Report",
    "write_report",
]

DEFAULT_THRESHOLDS = (math.radians(0.5), math.radians(1.0), math.radians(2.0))
_EXACT = 1e-6  # s: stamps this close are the same instant (the same image)
#: a series' own gap: samples further apart than this many times its median interval (a reference written at
#: 5 Hz is not gapped every 0.2 s; a dropout of three intervals is)
GAP_FACTOR = 1.5


class EvaluationError(InputFileError):
    """Inputs that cannot be evaluated (empty, mismatched lengths, no common times); says why."""


@dataclass
class EvaluationParams(Params):
    """What ``aruco-abs-orient evaluate`` computes (cfg/params.yaml's ``evaluation`` section)."""

    error = EvaluationError

    max_gap: float = param(0.2, "a pose (or a marker yaw) is compared with the reference only where the reference "
                           "has samples at most this far apart around it (or 1.5 × its median interval, for a "
                           "reference sampled more slowly): no error is interpolated across a gap", "s", 0.0)
    min_gap: float = param(0.5, "coverage lists the gaps between poses longer than this", "s", 0.0)
    settle: float = param(1.0, "the fused output (--fused) is judged from this long after its first absolute yaw "
                          "(the EKF converges), unless --after says when", "s", 0.0)


def interp_yaw(t_query, t, yaw, max_gap: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Yaw (rad) at ``t_query`` (s), interpolated linearly on the unit circle between the samples
    (``t`` sorted, s; ``yaw`` rad), and a validity mask: a query is valid when it coincides with a
    sample (within 1 µs) or lies between two samples at most ``max_gap`` s apart, or :data:`GAP_FACTOR` times
    the samples' median interval where that is longer (None: any gap; 0: exact matches only). Invalid queries
    get NaN."""
    tq = np.atleast_1d(np.asarray(t_query, dtype=float))
    t = np.asarray(t, dtype=float)
    yaw = np.asarray(yaw, dtype=float)
    out = np.full(tq.shape, np.nan)
    if len(t) == 0:
        return out, np.zeros(tq.shape, dtype=bool)
    if len(t) == 1:
        exact = np.abs(tq - t[0]) <= _EXACT
        out[exact] = yaw[0]
        return out, exact
    i = np.clip(np.searchsorted(t, tq), 1, len(t) - 1)
    left, right = t[i - 1], t[i]
    exact_l = np.abs(tq - left) <= _EXACT
    exact_r = np.abs(tq - right) <= _EXACT
    gap = right - left
    inside = (tq >= left) & (tq <= right) & (gap > 0)
    if max_gap is not None:
        inside &= gap <= (max(max_gap, GAP_FACTOR * float(np.median(np.diff(t)))) if max_gap > 0 else 0.0)
    f = np.where(inside, (tq - left) / np.where(gap > 0, gap, 1.0), 0.0)
    c = (1 - f) * np.cos(yaw[i - 1]) + f * np.cos(yaw[i])
    s = (1 - f) * np.sin(yaw[i - 1]) + f * np.sin(yaw[i])
    valid = inside & (np.hypot(c, s) > 1e-9)  # opposite neighbours: no meaningful interpolation
    out[valid] = np.arctan2(s[valid], c[valid])
    out[exact_l] = yaw[i - 1][exact_l]
    out[exact_r & ~exact_l] = yaw[i][exact_r & ~exact_l]
    return out, valid | exact_l | exact_r


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of a yaw error (radians; fractions in [0, 1]); see the module docstring."""

    n: int
    coverage: float
    rmse: float
    mean: float
    median: float
    std: float
    p95: float
    max: float
    bias: float
    thresholds: Tuple[float, ...]
    share_under: Tuple[float, ...]

    def report_dict(self) -> Dict[str, Any]:
        """Degrees and fractions, for the report."""
        d: Dict[str, Any] = {"n": self.n, "coverage": self.coverage}
        for key in ("rmse", "mean", "median", "std", "p95", "max", "bias"):
            d[key + "_deg"] = math.degrees(getattr(self, key))
        for thr, share in zip(self.thresholds, self.share_under):
            d[f"share_under_{math.degrees(thr):g}_deg"] = share
        return d


def error_stats(error, n_total: Optional[int] = None, thresholds: Sequence[float] = DEFAULT_THRESHOLDS) -> ErrorStats:
    """``ErrorStats`` of signed errors (rad, wrapped here); ``n_total`` the number of samples that
    should have had an error (for ``coverage``; default: all present). Raises EvaluationError
    when there is no error to summarise."""
    e = wrap_angle(np.asarray(error, dtype=float).ravel())
    n_total = len(e) if n_total is None else int(n_total)
    if len(e) == 0:
        raise EvaluationError(f"no samples to compare (0 of {n_total} had a reference)")
    a = np.abs(e)
    return ErrorStats(
        n=len(e), coverage=len(e) / n_total if n_total else 0.0,
        rmse=float(np.sqrt(np.mean(e * e))), mean=float(a.mean()), median=float(np.median(a)),
        std=float(a.std()), p95=float(np.percentile(a, 95)), max=float(a.max()), bias=float(e.mean()),
        thresholds=tuple(float(x) for x in thresholds),
        share_under=tuple(float(np.mean(a < thr)) for thr in thresholds))


@dataclass(frozen=True)
class YawErrors:
    """Signed yaw errors (rad) at times ``t`` (s) and their statistics."""

    t: np.ndarray
    error: np.ndarray
    stats: ErrorStats

    def report_dict(self) -> Dict[str, Any]:
        return self.stats.report_dict()


def yaw_ape(t_est, yaw_est, t_ref, yaw_ref, max_gap: Optional[float] = 0.2) -> YawErrors:
    """Absolute yaw error ``wrap(yaw_est − yaw_ref)`` (rad) at the estimate's stamps (s); the
    reference is interpolated on the unit circle across gaps of at most ``max_gap`` s."""
    t_est, yaw_est = sorted_series(t_est, yaw_est, "estimate", EvaluationError)
    t_ref, yaw_ref = sorted_series(t_ref, yaw_ref, "reference", EvaluationError)
    ref, ok = interp_yaw(t_est, t_ref, yaw_ref, max_gap)
    err = wrap_angle(yaw_est[ok] - ref[ok])
    return YawErrors(t_est[ok], err, error_stats(err, n_total=len(t_est)))


def yaw_rpe(t_est, yaw_est, t_ref, yaw_ref, delta: float = 1.0, max_gap: Optional[float] = 0.2) -> YawErrors:
    """Relative yaw error over ``delta`` s: ``wrap((ψe(t+Δ) − ψe(t)) − (ψr(t+Δ) − ψr(t)))`` (rad)
    for every estimate stamp t where the estimate at t+Δ and the reference at t and t+Δ exist
    (interpolated on the unit circle across gaps ≤ ``max_gap`` s). Insensitive to a constant yaw
    offset; shows drift per Δ."""
    if not delta > 0:
        raise EvaluationError(f"RPE delta must be > 0 s, got {delta}")
    t_est, yaw_est = sorted_series(t_est, yaw_est, "estimate", EvaluationError)
    t_ref, yaw_ref = sorted_series(t_ref, yaw_ref, "reference", EvaluationError)
    e1, ok1 = interp_yaw(t_est + delta, t_est, yaw_est, max_gap)
    r0, ok2 = interp_yaw(t_est, t_ref, yaw_ref, max_gap)
    r1, ok3 = interp_yaw(t_est + delta, t_ref, yaw_ref, max_gap)
    ok = ok1 & ok2 & ok3
    err = wrap_angle(wrap_angle(e1[ok] - yaw_est[ok]) - wrap_angle(r1[ok] - r0[ok]))
    n_possible = int(np.sum(t_est + delta <= t_est[-1])) if len(t_est) else 0
    return YawErrors(t_est[ok], err, error_stats(err, n_total=max(n_possible, int(ok.sum()))))


def per_marker_series(t, marker_ids, yaw) -> Dict[int, Tuple[np.ndarray, np.ndarray]]:
    """Per-observation records (stamp s, marker id, yaw of base_link from that marker alone, rad)
    → {marker id: (stamps, yaws)} sorted by time: each marker's own yaw trajectory (fig. 11)."""
    t = np.asarray(t, dtype=float).ravel()
    ids = np.asarray(marker_ids).ravel()
    yaw = np.asarray(yaw, dtype=float).ravel()
    if not (len(t) == len(ids) == len(yaw)):
        raise EvaluationError(f"marker records: {len(t)} stamps, {len(ids)} ids, {len(yaw)} yaws")
    out = {}
    for mid in np.unique(ids):
        sel = ids == mid
        out[int(mid)] = sorted_series(t[sel], yaw[sel], f"marker {int(mid)}", EvaluationError)
    return out


@dataclass(frozen=True)
class PairwiseDifferences:
    """Yaw differences between markers' trajectories at common times: ``pairs[(a, b)] = (t, d)`` with
    ``d = wrap(ψ_a − ψ_b)`` (rad), their statistics per pair and pooled over all pairs (``stats``)."""

    pairs: Dict[Tuple[int, int], Tuple[np.ndarray, np.ndarray]]
    per_pair: Dict[Tuple[int, int], ErrorStats]
    stats: ErrorStats

    def report_dict(self) -> Dict[str, Any]:
        d = {"all_pairs": self.stats.report_dict()}
        for (a, b), st in self.per_pair.items():
            d[f"{a}-{b}"] = st.report_dict()
        return d


def pairwise_differences(series: Mapping[int, Tuple[np.ndarray, np.ndarray]], max_gap: float = 0.0,
                         thresholds: Sequence[float] = DEFAULT_THRESHOLDS) -> PairwiseDifferences:
    """Differences between every pair of per-marker yaw series (``per_marker_series``) at common
    times: the stamps of marker a where marker b was seen in the same image (``max_gap`` = 0) or
    can be interpolated on the unit circle across a gap ≤ ``max_gap`` s. Pairs without common
    times are left out; raises EvaluationError if no pair has any (the paper's statistics —
    median, mean, std, share under 0.5/1/2° — are in ``stats``)."""
    ids = sorted(series)
    pairs: Dict[Tuple[int, int], Tuple[np.ndarray, np.ndarray]] = {}
    per_pair: Dict[Tuple[int, int], ErrorStats] = {}
    for n, a in enumerate(ids):
        ta, ya = series[a]
        for b in ids[n + 1:]:
            tb, yb = series[b]
            yb_at_a, ok = interp_yaw(ta, tb, yb, max_gap)
            if not np.any(ok):
                continue
            d = wrap_angle(ya[ok] - yb_at_a[ok])
            pairs[(a, b)] = (ta[ok], d)
            per_pair[(a, b)] = error_stats(d, thresholds=thresholds)
    if not pairs:
        raise EvaluationError(
            f"no two markers were seen at common times (markers {ids}): no pairwise differences; "
            "raise max_gap to compare interpolated trajectories")
    pooled = np.concatenate([d for _, d in pairs.values()])
    return PairwiseDifferences(pairs, per_pair, error_stats(pooled, thresholds=thresholds))


@dataclass(frozen=True)
class FramePositionBias:
    """Signed yaw error binned by where the marker was in the frame: ``mean[i, j]`` (rad, NaN where
    empty) and ``count[i, j]`` for elevation bin i (``el_edges``, rad) and azimuth bin j
    (``az_edges``, rad); ``by_elevation`` the mean per elevation bin over all azimuths;
    ``max_abs_bias`` the largest |mean| over bins with at least ``min_count`` samples (rad)."""

    az_edges: np.ndarray
    el_edges: np.ndarray
    mean: np.ndarray
    count: np.ndarray
    by_elevation: np.ndarray
    min_count: int
    max_abs_bias: float

    def report_dict(self) -> Dict[str, Any]:
        return {
            "max_abs_bias_deg": math.degrees(self.max_abs_bias),
            "min_count": self.min_count,
            "elevation_bins_deg": [[math.degrees(a), math.degrees(b)]
                                   for a, b in zip(self.el_edges[:-1], self.el_edges[1:])],
            "mean_by_elevation_deg": [None if not np.isfinite(x) else math.degrees(x) for x in self.by_elevation],
            "samples": int(self.count.sum()),
        }


def error_by_frame_position(az, el, error, az_bins: int = 12, el_bins: int = 6,
                            el_range: Optional[Tuple[float, float]] = None, min_count: int = 5) -> FramePositionBias:
    """Bin signed yaw errors (rad) by the marker's azimuth ``az`` in [−π, π) and elevation ``el``
    (rad, camera frame) — the paper's fig. 13. Azimuth bins span the full circle; elevation bins
    span ``el_range`` (default: the data's range). A bias that depends on the position in the
    frame shows as bins with a mean far from zero."""
    az = wrap_angle(np.asarray(az, dtype=float).ravel())
    el = np.asarray(el, dtype=float).ravel()
    err = wrap_angle(np.asarray(error, dtype=float).ravel())
    if not (len(az) == len(el) == len(err)):
        raise EvaluationError(f"frame position: {len(az)} azimuths, {len(el)} elevations, {len(err)} errors")
    if len(err) == 0:
        raise EvaluationError("frame position: no marker observations to bin")
    lo, hi = el_range if el_range is not None else (float(el.min()), float(el.max()) + 1e-9)
    az_edges = np.linspace(-math.pi, math.pi, az_bins + 1)
    el_edges = np.linspace(lo, hi, el_bins + 1)
    ia = np.clip(np.digitize(az, az_edges) - 1, 0, az_bins - 1)
    ie = np.digitize(el, el_edges) - 1
    inside = (ie >= 0) & (ie < el_bins)
    count = np.zeros((el_bins, az_bins), dtype=np.int64)
    total = np.zeros((el_bins, az_bins))
    np.add.at(count, (ie[inside], ia[inside]), 1)
    np.add.at(total, (ie[inside], ia[inside]), err[inside])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
        by_el = total.sum(axis=1) / count.sum(axis=1)
    well = count >= min_count
    max_abs = float(np.max(np.abs(mean[well]))) if np.any(well) else float("nan")
    return FramePositionBias(az_edges, el_edges, mean, count, by_el, min_count, max_abs)


@dataclass(frozen=True)
class MarkerAgreement:
    """Each marker's yaw against the frame's consensus (the filtered heading, which the other markers, the
    odometry and the prism made): per observation ``t`` (s), ``ids``, ``deviation`` (rad, wrapped; NaN without
    a consensus) and ``accepted``; per marker (``markers``, sorted ids) ``n`` (observations with a deviation),
    ``median`` and ``spread`` (rad; 1.4826 × the median absolute deviation: a robust σ; NaN when none),
    ``rejected``: id → {the pipeline's reason: count}; ``typical_spread`` (rad): the median of the spreads of
    the markers seen ``min_count`` times or more; ``flagged``: the markers whose median deviation exceeds
    ``flag_factor`` × the typical spread and ``min_flag`` (rad): moved or wrongly surveyed."""

    markers: Tuple[int, ...]
    n: np.ndarray
    median: np.ndarray
    spread: np.ndarray
    rejected: Dict[int, Dict[str, int]]
    typical_spread: float
    flagged: Tuple[int, ...]
    t: np.ndarray
    ids: np.ndarray
    deviation: np.ndarray
    accepted: np.ndarray

    def report_dict(self) -> Dict[str, Any]:
        return {"typical_spread_deg": math.degrees(self.typical_spread), "flagged": list(self.flagged),
                "markers": {str(m): {"n": int(n), "median_deg": math.degrees(med), "spread_deg": math.degrees(sp),
                                     "rejected": dict(self.rejected.get(m, {}))}
                            for m, n, med, sp in zip(self.markers, self.n, self.median, self.spread)}}


def marker_agreement(t, ids, deviation, accepted, reasons=None, flag_factor: float = 4.0,
                     min_flag: float = math.radians(0.05), min_count: int = 5) -> MarkerAgreement:
    """:class:`MarkerAgreement` of marker observations: stamps ``t`` (s), ``ids``, ``deviation`` = each yaw −
    the frame's consensus (rad; ``observations.csv``'s residual: the yaw − the filtered yaw; NaN: none),
    ``accepted`` (bool) and the pipeline's ``reasons`` for the rejected ones (strings; '' when accepted)."""
    t = np.asarray(t, dtype=float).ravel()
    ids = np.asarray(ids).astype(int).ravel()
    dev = np.asarray(deviation, dtype=float).ravel()
    acc = np.asarray(accepted, dtype=bool).ravel()
    why = [""] * len(t) if reasons is None else [str(r) for r in reasons]
    if not (len(t) == len(ids) == len(dev) == len(acc) == len(why)):
        raise EvaluationError(f"marker agreement: {len(t)} stamps, {len(ids)} ids, {len(dev)} deviations, "
                              f"{len(acc)} flags, {len(why)} reasons")
    dev = np.where(np.isfinite(dev), wrap_angle(np.nan_to_num(dev)), np.nan)
    markers = tuple(int(m) for m in np.unique(ids))
    n, med, spread, rejected = [], [], [], {}
    for m in markers:
        sel = ids == m
        d = dev[sel & np.isfinite(dev)]
        n.append(len(d))
        centre = float(np.median(d)) if len(d) else float("nan")
        med.append(centre)
        spread.append(1.4826 * float(np.median(np.abs(d - centre))) if len(d) else float("nan"))
        counts: Dict[str, int] = {}
        for k in np.flatnonzero(sel & ~acc):
            counts[why[k] or "rejected"] = counts.get(why[k] or "rejected", 0) + 1
        if counts:
            rejected[m] = counts
    n_a, med_a, spread_a = np.array(n, dtype=int), np.array(med), np.array(spread)
    seen = (n_a >= min_count) & np.isfinite(spread_a)
    typical = float(np.median(spread_a[seen])) if np.any(seen) else float("nan")
    limit = max(flag_factor * typical, min_flag) if math.isfinite(typical) else float("inf")
    flagged = tuple(m for m, k, c in zip(markers, n_a, med_a) if k >= min_count and abs(c) > limit)
    return MarkerAgreement(markers, n_a, med_a, spread_a, rejected, typical, flagged, t, ids, dev, acc)


# --------------------------------------------------------------------------- report


def _jsonable(value):
    if hasattr(value, "report_dict"):
        return _jsonable(value.report_dict())
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def fmt_angle(rad: Optional[float]) -> str:
    """An angle (rad) for a person: degrees, 3 decimals below 1°, 2 below 10°, else 1; '–' for None/NaN."""
    if rad is None or not math.isfinite(rad):
        return "–"
    d = math.degrees(rad)
    return f"{d:.3f}°" if abs(d) < 1 else f"{d:.2f}°" if abs(d) < 10 else f"{d:.1f}°"


def normalised_residuals(residual, sigma) -> Dict[str, Any]:
    """σ consistency of residuals (rad) with their predicted 1-σ (rad): ``rms`` of residual/σ (1 when
    the σ are honest, larger when they are too optimistic), the shares within 1, 2 and 3 σ (0.68, 0.95,
    0.997 for a normal error) and ``n``. Non-finite or non-positive σ are left out."""
    r = np.asarray(residual, dtype=float).ravel()
    s = np.asarray(sigma, dtype=float).ravel()
    ok = np.isfinite(r) & np.isfinite(s) & (s > 0)
    if not np.any(ok):
        raise EvaluationError("no residual with a positive σ to normalise")
    z = wrap_angle(r[ok]) / s[ok]
    a = np.abs(z)
    return {"n": int(ok.sum()), "rms": float(np.sqrt(np.mean(z * z))), "mean": float(z.mean()),
            "share_within_1_sigma": float(np.mean(a < 1)), "share_within_2_sigma": float(np.mean(a < 2)),
            "share_within_3_sigma": float(np.mean(a < 3))}


def gaps(stamps, min_gap: float = 0.5, start: Optional[float] = None, end: Optional[float] = None):
    """Gaps longer than ``min_gap`` s in sorted ``stamps`` (s), including a missing start (from ``start``)
    and end (to ``end``): a list of (from, to) in s, longest first."""
    t = np.asarray(stamps, dtype=float).ravel()
    edges = ([start] if start is not None else []) + list(t) + ([end] if end is not None else [])
    e = np.asarray(edges, dtype=float)
    if len(e) < 2:
        return []
    d = np.diff(e)
    idx = np.flatnonzero(d > min_gap)
    return sorted(((float(e[i]), float(e[i + 1])) for i in idx), key=lambda g: g[0] - g[1])


def _md_cell(value) -> str:
    if isinstance(value, float):
        return "–" if not math.isfinite(value) else f"{value:.4g}"
    if value is None:
        return "–"
    return str(value).replace("|", "\\|")


def md_table(columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> list:
    """Lines of a Markdown table (floats to 4 significant digits, None as '–')."""
    out = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    out += ["| " + " | ".join(_md_cell(v) for v in row) + " |" for row in rows]
    return out + [""]


@dataclass
class Report:
    """What a person reads first and then the details.

    ``headline``: rows (quantity, this run, the paper, what to check if it is bad — Markdown); ``notes``:
    warnings and self-check findings (Markdown lines); ``plots``: caption → PNG path (the overview
    first); ``tables``: (heading, columns, rows) detail tables; ``data``: the machine-readable results
    (``report_dict`` objects or JSON-able values) for ``report.json``."""

    title: str
    intro: str = ""
    headline: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    plots: Dict[str, str] = field(default_factory=dict)
    tables: list = field(default_factory=list)
    data: Dict[str, Any] = field(default_factory=dict)


def write_report(out_dir: str, report: Report, name: str = "report") -> Tuple[str, str]:
    """Write ``<out_dir>/<name>.md`` (one page of headline figures, the findings and the plots inline,
    then the detail tables) and ``<out_dir>/<name>.json`` (``report.data`` with the headline, the plots'
    paths and their titles: each plot's answer) atomically; returns their paths. Plot paths are made relative
    to ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    rel = {caption: os.path.relpath(os.path.abspath(p), os.path.abspath(out_dir))
           for caption, p in report.plots.items()}
    lines = [f"# {report.title}", ""]
    if report.intro:
        lines += [report.intro, ""]
    if report.headline:
        lines += md_table(("", "this run", "the paper (real data)", "if it is bad, check"), report.headline)
    if report.notes:
        lines += ["**Checks:**", ""] + [f"- {n}" for n in report.notes] + [""]
    lines += [f"![{caption}]({p})" for caption, p in rel.items()] + ([""] if rel else [])
    if report.tables:
        lines += ["## Details", ""]
        for heading, columns, rows in report.tables:
            lines += [f"### {heading}", ""] + md_table(columns, rows)
    titles = {rel[caption]: png_title(p) for caption, p in report.plots.items()}
    data = {"title": report.title, "headline": [list(r) for r in report.headline], "notes": list(report.notes),
            **{k: _jsonable(v) for k, v in report.data.items()}, "plots": rel, "plot_titles": titles}
    md_path = os.path.join(out_dir, name + ".md")
    json_path = os.path.join(out_dir, name + ".json")
    atomic_write_text(json_path, json.dumps(data, indent=2, allow_nan=False) + "\n")
    atomic_write_text(md_path, "\n".join(lines))
    return md_path, json_path

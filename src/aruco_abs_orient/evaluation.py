"""Yaw-only evaluation: APE/RPE against a reference, per-marker agreement, frame-position bias, plots
and a Markdown + JSON report (DESIGN §4.9; the paper's figs. 11–13).

Angles are radians everywhere in this module except in ``report_dict()`` results, the plots and the
report files, which are in degrees (the edge). Yaw differences are always wrapped to [−π, π), and
a reference yaw is interpolated on the unit circle, so 179° vs −179° is a 2° error.

Statistics (``ErrorStats``) follow evo and the paper: ``rmse`` of the error, ``mean``, ``median``,
``std``, ``p95`` and ``max`` of its absolute value, the signed ``bias`` (mean error), the share of
samples with |error| under each threshold (the paper's 0.5/1/2°), and ``coverage`` = the fraction of
the estimate's samples that had a reference to compare with.

matplotlib is imported only inside the plotting functions (Agg canvas, no pyplot state).
Python 3.8 compatible; numpy only otherwise.
"""

from __future__ import annotations

import io
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

from .errors import InputFileError
from .paramcheck import Validated, check_non_negative
from .transforms import wrap_angle
from .tum import atomic_write_bytes, atomic_write_text, sorted_series

__all__ = [
    "EvaluationParams",
    "EvaluationError",
    "save_figure",
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
    "plot_yaw_errors",
    "plot_marker_yaws",
    "plot_frame_position",
    "plot_coherence",
    "fmt_angle",
    "normalised_residuals",
    "gaps",
    "md_table",
    "Report",
    "write_report",
]

DEFAULT_THRESHOLDS = (math.radians(0.5), math.radians(1.0), math.radians(2.0))
_EXACT = 1e-6  # s: stamps this close are the same instant (the same image)


class EvaluationError(InputFileError, ValueError):
    """Inputs that cannot be evaluated (empty, mismatched lengths, no common times); says why."""


@dataclass
class EvaluationParams(Validated):
    """What ``aruco-abs-orient evaluate`` computes (cfg/params.yaml's ``evaluation`` section).

    - ``max_gap``: a pose (or a marker yaw) is compared with the reference only where the reference has
      samples at most this far apart (s) around it: no error is interpolated across a gap.
    - ``min_gap``: coverage lists the gaps between poses longer than this (s).
    - ``settle``: the fused output (``--fused``) is judged from this long (s) after its first absolute yaw
      (the EKF converges), unless ``--after`` says when.
    """

    max_gap: float = 0.2
    min_gap: float = 0.5
    settle: float = 1.0

    def validate(self) -> None:
        """Raise EvaluationError naming the first out-of-range field."""
        check_non_negative(self, EvaluationError)


def interp_yaw(t_query, t, yaw, max_gap: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Yaw (rad) at ``t_query`` (s), interpolated linearly on the unit circle between the samples
    (``t`` sorted, s; ``yaw`` rad), and a validity mask: a query is valid when it coincides with a
    sample (within 1 µs) or lies between two samples at most ``max_gap`` s apart (None: any gap;
    0: exact matches only). Invalid queries get NaN."""
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
        inside &= gap <= max_gap
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


# --------------------------------------------------------------------------- plots


def _figure(width_px: int, height_px: int, dpi: int = 100):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str) -> str:
    """Write the figure as PNG atomically (never a half-written plot)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _time_axis(ax, times, t0: Optional[float] = None) -> float:
    """Label ``ax``'s x axis as seconds since ``t0`` (s; the start of the recording, so every plot of a
    report shares it), or since the earliest of ``times`` (arrays of stamps, s) when None; return it."""
    if t0 is not None:
        ax.set_xlabel("time since the start of the recording [s]")
        return float(t0)
    t0 = min((float(np.min(t)) for t in times if len(t)), default=0.0)
    ax.set_xlabel(f"time since {t0:.3f} s [s]")
    return t0


def plot_yaw_errors(path: str, errors: Mapping[str, YawErrors], title: str = "Heading error",
                    size: Tuple[int, int] = (1200, 500), t0: Optional[float] = None) -> str:
    """Heading error (deg) over time (s since ``t0``) for each labelled ``YawErrors``; PNG of ``size`` pixels."""
    fig = _figure(*size)
    ax = fig.add_subplot(1, 1, 1)
    t0 = _time_axis(ax, [e.t for e in errors.values()], t0)
    for label, e in errors.items():
        ax.plot(e.t - t0, np.degrees(e.error), ".", ms=2, label=f"{label} (RMSE {math.degrees(e.stats.rmse):.3f}°)")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_ylabel("yaw error [deg]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if errors:
        ax.legend(loc="upper right", fontsize="small", markerscale=4)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_marker_yaws(path: str, series: Mapping[int, Tuple[np.ndarray, np.ndarray]],
                     pairwise: Optional[PairwiseDifferences] = None, size: Tuple[int, int] = (1200, 800),
                     t0: Optional[float] = None) -> str:
    """Per-marker yaw trajectories (deg; paper fig. 11) and, below, their pairwise differences
    (deg; figs. 11–12), over s since ``t0``; PNG of ``size`` pixels."""
    fig = _figure(*size)
    ax1 = fig.add_subplot(2, 1, 1)
    ax2 = fig.add_subplot(2, 1, 2, sharex=ax1)
    t0 = _time_axis(ax2, [t for t, _ in series.values()], t0)
    for mid, (t, yaw) in sorted(series.items()):
        ax1.plot(t - t0, np.degrees(yaw), ".", ms=2, label=f"marker {mid}")
    ax1.set_ylabel("yaw [deg]")
    ax1.set_title("Yaw from each marker alone")
    ax1.grid(True, alpha=0.3)
    if series:
        ax1.legend(loc="upper right", fontsize="small", markerscale=4)
    if pairwise is not None:
        for (a, b), (t, d) in sorted(pairwise.pairs.items()):
            ax2.plot(t - t0, np.degrees(d), ".", ms=2, label=f"{a} − {b}")
        st = pairwise.stats
        ax2.set_title(f"Pairwise differences: median {math.degrees(st.median):.3f}°, "
                      f"mean {math.degrees(st.mean):.3f}°, std {math.degrees(st.std):.3f}°")
        if pairwise.pairs:
            ax2.legend(loc="upper right", fontsize="small", markerscale=4, ncol=3)
    ax2.axhline(0.0, color="k", lw=0.5)
    ax2.set_ylabel("difference [deg]")
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_frame_position(path: str, bias: FramePositionBias, size: Tuple[int, int] = (1200, 600)) -> str:
    """Heatmap of the mean signed yaw error (deg) over the marker's azimuth × elevation in the frame
    (paper fig. 13); bins with fewer than ``min_count`` samples are blank. PNG of ``size`` pixels."""
    fig = _figure(*size)
    ax = fig.add_subplot(1, 1, 1)
    shown = np.where(bias.count >= bias.min_count, np.degrees(bias.mean), np.nan)
    finite = shown[np.isfinite(shown)]
    lim = max(float(np.max(np.abs(finite))) if finite.size else 0.0, 0.05)
    mesh = ax.pcolormesh(np.degrees(bias.az_edges), np.degrees(bias.el_edges), np.ma.masked_invalid(shown),
                         cmap="coolwarm", vmin=-lim, vmax=lim, shading="flat")
    fig.colorbar(mesh, ax=ax, label="mean yaw error [deg]")
    ax.set_xlabel("azimuth in the frame [deg] (0 = image centre, + = left)")
    ax.set_ylabel("elevation [deg]")
    ax.set_title(f"Yaw error by position in the frame (max |bias| {math.degrees(bias.max_abs_bias):.3f}°)")
    ax.invert_xaxis()  # as in the image: azimuth grows to the left
    fig.tight_layout()
    return save_figure(fig, path)


def plot_coherence(path: str, estimate, baseline=None, size: Tuple[int, int] = (1000, 500)) -> str:
    """The time-sync curve of an ``OffsetEstimate`` (coherence vs offset, ms) with its optimum and
    σ, and the baseline's correlation curve on a second axis if given. PNG of ``size`` pixels."""
    fig = _figure(*size)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(1e3 * np.asarray(estimate.taus), estimate.curve, "-", color="C0", label="phase coherence")
    ax.axvline(1e3 * estimate.offset, color="C0", ls="--",
               label=f"τ = {1e3 * estimate.offset:.1f} ± {1e3 * estimate.sigma:.1f} ms "
                     f"(confidence {estimate.confidence:.2f})")
    ax.set_xlabel("offset τ: camera stamp − total-station time [ms]")
    ax.set_ylabel("coherence")
    ax.grid(True, alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if baseline is not None:
        ax2 = ax.twinx()
        ax2.plot(1e3 * np.asarray(baseline.taus), baseline.curve, ".", color="C1", ms=3,
                 label="heading cross-correlation (paper)")
        ax2.axvline(1e3 * baseline.offset, color="C1", ls=":", label=f"baseline τ = {1e3 * baseline.offset:.1f} ms")
        ax2.set_ylabel("correlation")
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    ax.legend(handles, labels, loc="lower center", fontsize="small")
    ax.set_title("Camera ↔ total-station time offset")
    fig.tight_layout()
    return save_figure(fig, path)


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
    then the detail tables) and ``<out_dir>/<name>.json`` (``report.data`` with the headline and the
    plots' paths) atomically; returns their paths. Plot paths are made relative to ``out_dir``."""
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
    data = {"title": report.title, "headline": [list(r) for r in report.headline], "notes": list(report.notes),
            **{k: _jsonable(v) for k, v in report.data.items()}, "plots": rel}
    md_path = os.path.join(out_dir, name + ".md")
    json_path = os.path.join(out_dir, name + ".json")
    atomic_write_text(json_path, json.dumps(data, indent=2, allow_nan=False) + "\n")
    atomic_write_text(md_path, "\n".join(lines))
    return md_path, json_path

"""The phase-coherence estimate of the time offset (this package's method; doc/design.md §10).

In: VO yaws (camera clock) and/or absolute marker yaws, and prism fixes (total-station clock).
Out: an :class:`~.estimate.OffsetEstimate` (:func:`estimate_offset`,
:func:`estimate_offset_from_marker_yaws`) with its σ and confidence, or :class:`~.estimate.TimeSyncError`
saying why not (too little turning, too short, no peak). The knobs are :class:`TimeSyncParams`
(cfg/params.yaml's ``timesync`` section): the windows, each with its own constant phase and bounded linear
drift, the speed below which a sample counts nothing, the turn-rate variation asked for. The curve C(τ) is
smooth in τ (the track heading interpolated through the velocity vector), so a coarse grid and a
golden-section search find its peak to well under a frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from ..paramspec import Params, param
from ..tum import sorted_series
from .estimate import OffsetEstimate, TimeSyncError, _check_search
from .heading import _HeadingGrid

__all__ = ["TimeSyncParams", "YawSeries", "estimate_offset", "estimate_offset_from_marker_yaws"]

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class TimeSyncParams(Params):
    """The knobs of the phase-coherence time-offset estimate (``aruco-abs-orient timesync``, the node's
    ``~estimate_time_offset``); cfg/params.yaml's ``timesync`` section."""

    error = TimeSyncError

    smooth: float = param(0.5, "σ of the local-quadratic fit that gives the prism track's direction of travel", "s",
                          above=0.0)
    min_speed: float = param(0.05, "below this platform speed the track heading is not used", "m/s", 0.0)
    window: float = param(60.0, "each window of the camera's yaws gets its own yaw offset and VO drift (0: one "
                          "window)", "s", 0.0)
    max_drift_deg_per_min: float = param(20.0, "largest VO yaw drift fitted in a window", "deg/min", 0.0)
    step: float = param(0.02, "grid of candidate offsets, refined by golden section around the best", "s",
                        above=0.0)
    min_duration: float = param(10.0, "moving overlap needed at the best offset, else no estimate", "s", 0.0)
    min_turn_rate_deg: float = param(2.0, "RMS variation of the turn rate needed, else no estimate (driving "
                                     "straight or turning at a constant rate makes a time offset look like a yaw "
                                     "offset)", "deg/s", 0.0)
    sigma_ref: float = param(0.01, "σ at which the confidence's sharpness factor 1/(1 + (σ/sigma_ref)²) is ½", "s",
                             above=0.0)

    @property
    def max_drift(self) -> float:
        """``max_drift_deg_per_min`` in rad/s."""
        return math.radians(self.max_drift_deg_per_min) / 60.0


class YawSeries(NamedTuple):
    """Yaws ``yaw`` (rad) of base_link stamped ``t`` (s, camera clock); ``ids`` (optional) the marker that gave
    each (marker yaws: one constant phase per marker, which absorbs a per-marker bias)."""

    t: np.ndarray
    yaw: np.ndarray
    ids: Optional[np.ndarray] = None


@dataclass
class _Channel:
    """Yaw samples on the camera clock: each window gets its own constant phase (and drift)."""

    t: np.ndarray
    phasor: np.ndarray  # exp(i yaw)
    weight: np.ndarray
    window: np.ndarray  # window index per sample
    n_windows: int
    drift: bool


def _make_channel(t, yaw, weights, name: str, window: Optional[float], drift: bool) -> _Channel:
    raw_t = np.asarray(t, dtype=float).ravel()
    w = np.ones_like(raw_t) if weights is None else np.asarray(weights, dtype=float).ravel()
    if len(w) != len(raw_t):
        raise TimeSyncError(f"{name}: {len(raw_t)} samples but {len(w)} weights")
    t, yaw = sorted_series(raw_t, yaw, name, TimeSyncError)
    w = w[np.argsort(raw_t, kind="stable")]  # the order sorted_series sorted the samples into
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise TimeSyncError(f"{name}: weights must be finite and ≥ 0")
    if window is None or len(t) == 0 or window <= 0:
        win = np.zeros(len(t), dtype=np.int64)
    else:
        span = t[-1] - t[0]
        n_win = max(1, int(round(span / window)))
        win = np.minimum(((t - t[0]) / (span / n_win if span > 0 else 1.0)).astype(np.int64), n_win - 1)
    return _Channel(t, np.exp(1j * yaw), w, win, int(win.max(initial=0)) + 1, drift)


def _channel_sums(ch: _Channel, grid: _HeadingGrid, taus: np.ndarray, max_drift: float):
    """Coherent sum magnitude and total weight per τ (arrays over ``taus``), plus the per-sample
    residual phases, weights, turn rates and fitted drift per window (for the peak statistics)."""
    ux, uy, wt, rate = grid.at(ch.t[None, :] - taus[:, None])
    w = ch.weight[None, :] * wt
    z = w * ch.phasor[None, :] * (ux - 1j * uy)  # w·exp(i(ψ_vo − ψ_track))
    total = np.zeros(len(taus))
    weight = np.zeros(len(taus))
    residual = np.zeros_like(w)
    drifts = np.zeros((len(taus), ch.n_windows))
    for j in range(ch.n_windows):
        sel = ch.window == j
        if not np.any(sel):
            continue
        zj, wj, tj = z[:, sel], w[:, sel], ch.t[sel]
        s0 = zj.sum(axis=1)
        wsum = wj.sum(axis=1)
        c0 = np.angle(s0)
        e = np.angle(zj * np.exp(-1j * c0)[:, None])  # residual phase around the mean, rad
        if ch.drift:
            safe = np.where(wsum > 0, wsum, 1.0)
            tbar = (wj * tj[None, :]).sum(axis=1) / safe
            dt = tj[None, :] - tbar[:, None]
            ebar = (wj * e).sum(axis=1) / safe
            stt = (wj * dt * dt).sum(axis=1)
            d = np.where(stt > 0, (wj * dt * (e - ebar[:, None])).sum(axis=1) / np.where(stt > 0, stt, 1.0), 0.0)
            d = np.clip(d, -max_drift, max_drift)
            zj = zj * np.exp(-1j * d[:, None] * dt)
            s0 = zj.sum(axis=1)
            e = np.angle(zj * np.exp(-1j * np.angle(s0))[:, None])
            drifts[:, j] = d
        total += np.abs(s0)
        weight += wsum
        residual[:, sel] = e
    return total, weight, residual, w, rate, drifts, np.angle(z.sum(axis=1))


class _Coherence:
    """C(τ) over one or more channels sharing the track heading."""

    def __init__(self, channels: Sequence[_Channel], grid: _HeadingGrid, max_drift: float):
        self.channels = list(channels)
        self.grid = grid
        self.max_drift = max_drift

    def curve(self, taus) -> Tuple[np.ndarray, np.ndarray]:
        taus = np.atleast_1d(np.asarray(taus, dtype=float))
        total = np.zeros(len(taus))
        weight = np.zeros(len(taus))
        for ch in self.channels:
            chunk = max(1, 2_000_000 // max(1, len(ch.t)))  # bounded memory on long recordings
            for k in range(0, len(taus), chunk):
                s, w = _channel_sums(ch, self.grid, taus[k:k + chunk], self.max_drift)[:2]
                total[k:k + chunk] += s
                weight[k:k + chunk] += w
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(weight > 0, total / np.where(weight > 0, weight, 1.0), 0.0), weight

    def value(self, tau: float) -> float:
        return float(self.curve([tau])[0][0])


def _golden_max(f, a: float, b: float, tol: float) -> float:
    """Maximiser of a unimodal ``f`` on [a, b] to ``tol`` (golden-section search)."""
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc >= fd:
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def _highpass(t: np.ndarray, values: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """``values`` minus their weighted Gaussian (σ = ``sigma`` s) moving average (0 where weight is 0)."""
    out = np.zeros_like(values)
    used = weights > 0
    if not np.any(used) or sigma <= 0:
        return np.where(used, values, 0.0)
    tu, vu, wu = t[used], values[used], weights[used]
    lo = np.searchsorted(tu, tu - 3.0 * sigma, side="left")
    hi = np.searchsorted(tu, tu + 3.0 * sigma, side="right")
    # prefix sums over the Gaussian are not separable; a banded sum keeps it O(N · band)
    band = int((hi - lo).max(initial=1))
    idx = np.minimum(lo[:, None] + np.arange(band)[None, :], len(tu) - 1)
    inside = (lo[:, None] + np.arange(band)[None, :]) < hi[:, None]
    k = np.exp(-0.5 * ((tu[idx] - tu[:, None]) / sigma) ** 2) * inside * wu[idx]
    out[used] = vu - (k * vu[idx]).sum(axis=1) / k.sum(axis=1)
    return out


class _PeakStats(NamedTuple):
    used_time: float  # s of samples with a moving track
    n_used: int
    rms_rate: float  # rad/s, RMS turn-rate variation left after the nuisance terms
    sigma: float  # s
    yaw_offset: float  # rad
    drift: float  # rad/s


def _peak_stats(channels: List[_Channel], grid: _HeadingGrid, tau: float, max_drift: float,
                corr_time: float) -> _PeakStats:
    """Statistics at offset ``tau``. Linearised, the coherence maximiser is the weighted least
    squares δτ = Σ w ω̃ e / Σ w ω̃² of the residual phases e on the track's turn rate ω̃ (each
    window's constant and drift regressed out: they absorb that part of ω). Its σ is a Newey-West
    (Bartlett) sum over lags up to ``corr_time`` s: the track heading's noise is correlated over the
    smoothing. The residuals are high-passed first: their slow part is the smoothing's
    deterministic, time-symmetric bias of the track heading, which does not move τ but would
    inflate σ."""
    used_time = info = var = wsum = 0.0
    n_used = 0
    yaw_offset = drift = 0.0
    for n, ch in enumerate(channels):
        _, _, residual, w, rate, drifts, mean_phase = _channel_sums(ch, grid, np.array([tau]), max_drift)
        w, rate, residual = w[0], rate[0], residual[0]
        if n == 0:
            yaw_offset, drift = float(mean_phase[0]), float(drifts[0, 0])
        moving = w > 0
        n_used += int(np.sum(moving))
        period = float(np.median(np.diff(ch.t))) if len(ch.t) > 1 else 0.0
        used_time += period * int(np.sum(moving))
        rate_tilde = np.zeros_like(rate)
        for j in range(ch.n_windows):
            sel = (ch.window == j) & moving
            m = int(np.sum(sel))
            if m < 3:
                continue
            X = np.stack([np.ones(m), ch.t[sel] - ch.t[sel].mean()] if ch.drift else [np.ones(m)], axis=1)
            sw = np.sqrt(w[sel])
            beta = np.linalg.lstsq(X * sw[:, None], rate[sel] * sw, rcond=None)[0]
            rate_tilde[sel] = rate[sel] - X @ beta
        info += float(np.sum(w * rate_tilde**2))
        wsum += float(np.sum(w))
        u = w * rate_tilde * _highpass(ch.t, residual, w, 3.0 * corr_time / 4.0)
        lags = int(math.ceil(corr_time / period)) if period > 0 else 0
        var += float(u @ u) + 2.0 * sum((1.0 - m / (lags + 1.0)) * float(u[:-m] @ u[m:])
                                        for m in range(1, min(lags, len(u) - 1) + 1))
    rms_rate = math.sqrt(info / wsum) if wsum > 0 else 0.0
    sigma = math.sqrt(max(var, 0.0)) / info if info > 0 else math.inf
    return _PeakStats(used_time, n_used, rms_rate, sigma, yaw_offset, drift)


def _estimate(channels: List[_Channel], grid: _HeadingGrid, search, params: TimeSyncParams) -> OffsetEstimate:
    step, max_drift, min_duration = params.step, params.max_drift, params.min_duration
    min_turn_rate, sigma_ref, corr_time = math.radians(params.min_turn_rate_deg), params.sigma_ref, 4.0 * params.smooth
    lo, hi = _check_search(search)
    if grid.max_speed < grid.min_speed:
        raise TimeSyncError(
            f"the prism never moves (top speed {grid.max_speed:.3f} m/s): the track has no heading, "
            "so the time offset cannot be estimated; use a recording where the platform drives")
    coh = _Coherence(channels, grid, max_drift)
    n_grid = max(3, int(math.ceil((hi - lo) / step)) + 1)
    taus = np.linspace(lo, hi, n_grid)
    curve, weight = coh.curve(taus)
    if not np.any(weight > 0):
        spans = ", ".join(f"[{c.t[0]:.3f}, {c.t[-1]:.3f}]" for c in channels if len(c.t))
        raise TimeSyncError(
            f"no overlap: camera samples {spans or '(none)'} s and moving track samples "
            f"[{grid.span[0]:.3f}, {grid.span[1]:.3f}] s do not overlap for any offset in [{lo}, {hi}] s")
    k = int(np.argmax(curve))
    stats = _peak_stats(channels, grid, float(taus[k]), max_drift, corr_time)
    if stats.used_time < min_duration:
        raise TimeSyncError(
            f"too short: only {stats.used_time:.1f} s of samples overlap a moving track at the best offset; "
            f"need at least {min_duration:.1f} s")
    if stats.rms_rate < min_turn_rate:
        raise TimeSyncError(
            f"the platform's heading does not change enough (turn-rate variation "
            f"{math.degrees(stats.rms_rate):.2f} °/s < {math.degrees(min_turn_rate):.2f} °/s): driving straight or "
            "turning at a constant rate makes a time offset indistinguishable from a yaw offset")
    tau = _golden_max(coh.value, taus[max(k - 1, 0)], taus[min(k + 1, n_grid - 1)], tol=1e-5)
    if min(tau - lo, hi - tau) < 1e-4:
        raise TimeSyncError(
            f"the coherence is highest at the edge of the search interval ({tau:+.3f} s): the offset is "
            f"outside [{lo}, {hi}] s; widen the search")
    peak = coh.value(tau)
    stats = _peak_stats(channels, grid, tau, max_drift, corr_time)
    # confidence: peak coherence × uniqueness (best rival local maximum ≥ 10 % lower) × sharpness
    rivals = [curve[i] for i in range(1, n_grid - 1)
              if curve[i] >= curve[i - 1] and curve[i] >= curve[i + 1] and abs(taus[i] - tau) > 2 * step]
    rival = max(rivals) if rivals else 0.0
    unique = float(np.clip((peak - rival) / (0.1 * peak), 0.0, 1.0)) if peak > 0 else 0.0
    sharp = 1.0 / (1.0 + (stats.sigma / sigma_ref) ** 2)
    confidence = float(np.clip(peak, 0.0, 1.0) * unique * sharp)
    return OffsetEstimate(offset=float(tau), sigma=float(stats.sigma), confidence=confidence, coherence=peak,
                          taus=taus, curve=curve, method="coherence", n_samples=stats.n_used,
                          overlap=stats.used_time, yaw_offset=stats.yaw_offset, drift=stats.drift,
                          extra={"rival_peak": rival, "turn_rate_rms": stats.rms_rate})


def estimate_offset(t_vo, yaw_vo, t_track, xy_track, weights=None, search=(-1.0, 1.0), *,
                    params: Optional[TimeSyncParams] = None, prism_in_base=None) -> OffsetEstimate:
    """Time offset τ (s) with camera/VO stamp = total-station time + τ, by phase coherence.

    ``t_vo`` (N,) s and ``yaw_vo`` (N,) rad: VO yaw of base_link on the camera clock (any constant
    offset, slow drift allowed); ``t_track`` (M,) s and ``xy_track`` (M, 2|3) m: prism fixes on the
    total-station clock; ``weights`` (N,) optional VO sample weights (≥ 0). ``search`` (s): the
    interval of τ searched on a grid of ``params.step`` s then refined by golden section. ``params``
    (:class:`TimeSyncParams`, default its defaults): the track's smoothing and speed threshold, the
    windows with their own yaw offset and drift, and the limits below. Raises TimeSyncError when the
    offset is not observable: fewer than ``min_duration`` s of moving overlap, a platform that never
    moves, a heading whose turn rate varies by less than ``min_turn_rate_deg`` RMS, or a peak at the
    search edge.

    ``prism_in_base`` (x, y[, z]) m: the prism's lever arm in base_link; the track heading is turned
    from the prism's direction of travel to base_link's (a platform driving along its x axis).

    ``confidence`` = peak coherence × uniqueness (1 when every rival peak is ≥ 10 % lower)
    × 1/(1 + (σ/``sigma_ref``)²).
    """
    params = params or TimeSyncParams()
    grid = _HeadingGrid(t_track, xy_track, params.smooth, params.min_speed, prism_in_base=prism_in_base)
    ch = _make_channel(t_vo, yaw_vo, weights, "VO yaw", params.window, drift=True)
    if len(ch.t) < 3:
        raise TimeSyncError(f"too short: only {len(ch.t)} VO samples")
    return _estimate([ch], grid, search, params)


def estimate_offset_from_marker_yaws(markers: YawSeries, t_track, xy_track, vo: Optional[YawSeries] = None,
                                     search=(-1.0, 1.0), *, params: Optional[TimeSyncParams] = None,
                                     prism_in_base=None) -> OffsetEstimate:
    """Time offset τ (s, camera stamp = total-station time + τ) from absolute marker yaws.

    ``markers``: per-frame absolute yaws of base_link derived from markers (:class:`YawSeries` on the camera
    clock; no drift: each marker, if ``markers.ids`` is given, or all of them together get one constant
    phase, which absorbs a per-marker bias); optionally the VO yaw ``vo`` as a second channel with its own
    offset and drift. The other parameters and the errors are those of ``estimate_offset``.
    """
    params = params or TimeSyncParams()
    window = params.window
    grid = _HeadingGrid(t_track, xy_track, params.smooth, params.min_speed, prism_in_base=prism_in_base)
    t_m, yaw_m = np.asarray(markers.t, dtype=float).ravel(), np.asarray(markers.yaw, dtype=float).ravel()
    if len(t_m) != len(yaw_m):
        raise TimeSyncError(f"marker yaws: {len(t_m)} stamps but {len(yaw_m)} yaws")
    if len(t_m) < 3:
        raise TimeSyncError(f"too short: only {len(t_m)} marker yaws (no markers seen?)")
    channels = []
    if markers.ids is None:
        channels.append(_make_channel(t_m, yaw_m, None, "marker yaws", window, drift=False))
    else:
        ids = np.asarray(markers.ids).ravel()
        if len(ids) != len(t_m):
            raise TimeSyncError(f"marker yaws: {len(t_m)} stamps but {len(ids)} marker ids")
        for mid in np.unique(ids):
            sel = ids == mid
            if np.sum(sel) >= 3:
                channels.append(_make_channel(t_m[sel], yaw_m[sel], None, f"marker {mid} yaws", window, drift=False))
    if vo is not None:
        channels.append(_make_channel(vo.t, vo.yaw, None, "VO yaw", window, drift=True))
    return _estimate(channels, grid, search, params)

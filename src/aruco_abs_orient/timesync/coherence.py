"""Time offset between the camera/VO clock and the total-station clock (DESIGN §4.7).

Sign convention, used everywhere in this module and by its callers:

    camera stamp = total-station (true) time + τ          (τ in seconds)

so a VO sample stamped ``t`` was taken at total-station time ``t − τ``; to put camera stamps on
the total station's clock, subtract τ (``OnlineOffsetEstimator.correct_stamp``). A camera that
lags the total station (the paper's 11 frames) has τ > 0.

Method: the prism track gives the direction of travel (the heading of the velocity vector, from a
zero-lag local quadratic fit of the prism positions), the VO gives a yaw with an unknown constant
offset and a slow drift. For a candidate τ the residual phases ``ψ_vo(t_k) − ψ_track(t_k − τ)``
are constant at the true τ except for noise and the drift; the estimate maximises the weighted
phase coherence

    C(τ) = Σ_windows |Σ_k w_k exp(i(ψ_vo(t_k) − ψ_track(t_k − τ) − d_j (t_k − t̄_j)))| / Σ_k w_k

where each window j (default: 60 s) gets its own constant phase (the unknown yaw offset, taken
care of by the modulus) and its own linear drift ``d_j`` (rad/s, fitted, bounded by
``max_drift``). The weights are the VO weights times the squared platform speed (zero below
``min_speed``), so standstill and crawling, where the track heading is noise, do not count. A
coarse grid over the search interval finds the peak, a golden-section search refines it to well
under a frame; the track heading is interpolated continuously on the unit circle (through the
velocity vector), so the curve is smooth in τ. The smoothing's own heading bias
σ²(v'ψ'/v + ψ''/2), which is not time-symmetric where the platform brakes or accelerates in a turn,
is removed before the search. ``sigma`` comes from the linearised least-squares equivalent of the
maximisation with a Newey-West sum over the track noise's correlation time.

The paper's method (normalised cross-correlation of unwrapped headings at whole-frame lags) is
``cross_correlation_offset``, kept as the baseline. Numbers that cannot be estimated raise
``TimeSyncError`` saying why. Python 3.8 compatible; numpy only.
"""

from __future__ import annotations

import collections
import math
import threading
from dataclasses import dataclass, field
from typing import Deque, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from ..tum import sorted_series

__all__ = [
    "TimeSyncError",
    "TrackHeading",
    "OffsetEstimate",
    "heading_from_track",
    "estimate_offset",
    "estimate_offset_from_marker_yaws",
    "cross_correlation_offset",
    "OnlineOffsetEstimator",
]

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


class TimeSyncError(ValueError):
    """The time offset cannot be estimated from these data; the message says why."""


@dataclass(frozen=True)
class TrackHeading:
    """Direction of travel of the prism, evaluated at times ``t`` (s, total-station clock).

    ``heading`` (rad, from map +x towards +y), ``speed`` (m/s), ``turn_rate`` (rad/s) and
    ``valid`` (enough prism fixes on both sides of the time and speed ≥ ``min_speed``).
    """

    t: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    turn_rate: np.ndarray
    valid: np.ndarray


@dataclass
class OffsetEstimate:
    """A camera ↔ total-station time offset (camera stamp = total-station time + ``offset``).

    ``offset`` and ``sigma`` in seconds; ``confidence`` in [0, 1] (peak coherence × uniqueness of
    the peak × sharpness, see ``estimate_offset``); ``coherence`` the peak value of the curve;
    ``taus`` / ``curve`` the coherence (or correlation, for the baseline) over the searched
    offsets (s), for plotting; ``yaw_offset`` (rad) the mean of VO yaw − track heading at the
    optimum; ``drift`` (rad/s) the fitted VO yaw drift of the first window; ``overlap`` (s) the
    time with usable (moving) samples; ``method`` "coherence" or "xcorr".
    """

    offset: float
    sigma: float
    confidence: float
    coherence: float
    taus: np.ndarray
    curve: np.ndarray
    method: str
    n_samples: int
    overlap: float
    yaw_offset: float = 0.0
    drift: float = 0.0
    extra: dict = field(default_factory=dict)

    def report_dict(self) -> dict:
        """The estimate for a report: milliseconds and degrees (the units a reader expects)."""
        return {
            "method": self.method,
            "offset_ms": 1e3 * self.offset,
            "sigma_ms": 1e3 * self.sigma,
            "confidence": self.confidence,
            "peak": self.coherence,
            "samples": self.n_samples,
            "overlap_s": self.overlap,
            "yaw_offset_deg": math.degrees(self.yaw_offset),
            "drift_deg_per_min": math.degrees(self.drift) * 60.0,
        }


# --------------------------------------------------------------------------- track heading


def _local_quadratic(t: np.ndarray, xy: np.ndarray, tq: np.ndarray, smooth: float):
    """Velocity and acceleration (m/s, m/s²) at ``tq`` from a Gaussian-weighted (σ = ``smooth`` s)
    local quadratic fit of positions ``xy`` (N, 2) at sorted times ``t``; and a validity mask
    (at least two fixes within 2σ on each side of the query)."""
    n = len(t)
    lo = np.searchsorted(t, tq - 3.0 * smooth, side="left")
    hi = np.searchsorted(t, tq + 3.0 * smooth, side="right")
    width = int(max(1, (hi - lo).max(initial=1)))
    idx = lo[:, None] + np.arange(width)[None, :]
    inside = idx < hi[:, None]
    idx = np.minimum(idx, n - 1)
    dt = t[idx] - tq[:, None]
    w = np.exp(-0.5 * (dt / smooth) ** 2) * inside
    near = inside & (np.abs(dt) <= 2.0 * smooth)
    valid = (np.sum(near & (dt < 0), axis=1) >= 2) & (np.sum(near & (dt > 0), axis=1) >= 2)
    s = dt / smooth  # scaled for conditioning
    powers = np.stack([np.ones_like(s), s, s * s], axis=-1)  # (q, m, 3)
    A = np.einsum("qm,qmi,qmj->qij", w, powers, powers)
    origin = xy[lo]  # positions relative to a nearby fix (no cancellation far from the origin)
    rel = xy[idx] - origin[:, None, :]
    B = np.einsum("qm,qmi,qmk->qik", w, powers, rel)
    A[~valid] = np.eye(3)
    B[~valid] = 0.0
    coef = np.linalg.solve(A, B)  # (q, 3, 2): c0 + c1 s + c2 s²
    velocity = coef[:, 1, :] / smooth
    acceleration = 2.0 * coef[:, 2, :] / smooth**2
    return velocity, acceleration, valid


def heading_from_track(t, xy, query_t=None, smooth: float = 0.5, min_speed: float = 0.05) -> TrackHeading:
    """Direction of travel of the prism from its positions.

    ``t`` (N,) s and ``xy`` (N, 2) m (extra columns, e.g. z, are ignored) are the prism fixes;
    ``query_t`` the times to evaluate (default: ``t``). A Gaussian-weighted local quadratic fit
    (σ = ``smooth`` s) gives velocity and acceleration without lag, on irregular stamps and across
    short dropouts. ``valid`` is False where fixes are missing around the query or the speed is
    below ``min_speed`` (m/s): there the heading is meaningless. The result is the direction of the
    Gaussian-smoothed velocity, biased by σ²(v'ψ'/v + ψ''/2) rad in turns (σ = ``smooth``);
    ``estimate_offset`` removes that bias.
    """
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] < 2:
        raise TimeSyncError(f"track positions: expected an (N, 2) or (N, 3) array, got shape {xy.shape}")
    t, xy = sorted_series(t, xy[:, :2], "track", TimeSyncError, ncols=2)
    if smooth <= 0:
        raise TimeSyncError(f"smooth must be > 0 s, got {smooth}")
    tq = t if query_t is None else np.asarray(query_t, dtype=float).ravel()
    if len(t) < 5:
        raise TimeSyncError(f"track: only {len(t)} prism fixes; need at least 5")
    velocity, acceleration, valid = _local_quadratic(t, xy, tq, smooth)
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    heading = np.arctan2(velocity[:, 1], velocity[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = velocity[:, 0] * acceleration[:, 1] - velocity[:, 1] * acceleration[:, 0]
        turn_rate = np.where(speed > 0, cross / np.maximum(speed, 1e-12) ** 2, 0.0)
    valid = valid & (speed >= min_speed)
    return TrackHeading(tq, heading, speed, turn_rate, valid)


def _grid_smooth(values: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing (σ = ``sigma`` samples) of a regular series over its ``valid`` samples
    (normalised convolution); NaN where no valid sample is near."""
    half = max(1, int(math.ceil(3.0 * sigma)))
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    v = np.where(valid, values, 0.0)
    num = np.convolve(v, kernel)[half:half + len(v)]
    den = np.convolve(valid.astype(float), kernel)[half:half + len(v)]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-6, num / den, np.nan)


class _HeadingGrid:
    """The track's velocity on a regular grid, interpolated linearly (the unit circle, not the
    angle, is interpolated), with a per-time weight speed² (0 where the heading is invalid)."""

    def __init__(self, t, xy, smooth: float, min_speed: float, step: float = 0.005, prism_in_base=None):
        xy = np.asarray(xy, dtype=float)
        if xy.ndim != 2 or xy.shape[1] < 2:
            raise TimeSyncError(f"track positions: expected an (N, 2) or (N, 3) array, got shape {xy.shape}")
        t, xy2 = sorted_series(t, xy[:, :2], "track", TimeSyncError, ncols=2)
        if len(t) < 5:
            raise TimeSyncError(f"track: only {len(t)} prism fixes; need at least 5")
        self.t0 = float(t[0])
        self.step = step
        self.min_speed = min_speed
        n = int(math.floor((t[-1] - t[0]) / step)) + 1
        grid = self.t0 + step * np.arange(n)
        h = heading_from_track(t, xy2, grid, smooth=smooth, min_speed=min_speed)
        self.max_speed = float(np.max(h.speed, initial=0.0))
        # The fit returns the Gaussian-smoothed velocity G*(v·e^{iψ}), whose direction is
        # ψ + σ²(v'ψ'/v + ψ''/2) + O(σ⁴). Where the speed changes in a turn (braking into a curve,
        # stopping mid-turn) that term is not time-symmetric and would bias τ: remove it, with the
        # derivatives taken from the smoothed speed and turn rate (smoothed once more: the
        # correction is slow, its noise is not).
        sig = smooth / step
        speed = _grid_smooth(h.speed, h.valid, sig)
        rate = _grid_smooth(h.turn_rate, h.valid, sig)
        with np.errstate(invalid="ignore", divide="ignore"):
            bias = smooth**2 * (np.gradient(speed, step) * rate / speed + 0.5 * np.gradient(rate, step))
        heading = np.where(h.valid & np.isfinite(bias), h.heading - bias, h.heading)
        if prism_in_base is not None:
            # The prism is not base_link: on a platform that drives along its x axis, a prism at
            # (r_x, r_y) moves with body velocity (v − ω r_y, ω r_x), i.e. along base_link's
            # heading turned by β = asin(ω r_x / s) (s its speed). Uncorrected, β ∝ ω mimics a
            # time offset of −r_x / v (−0.3 s for a prism 25 cm behind the axle at 0.8 m/s).
            with np.errstate(invalid="ignore", divide="ignore"):
                beta = np.arcsin(np.clip(rate * float(prism_in_base[0]) / speed, -1.0, 1.0))
            heading = np.where(h.valid & np.isfinite(beta), heading - beta, heading)
        self.ux = np.where(h.valid, np.cos(heading), 0.0)
        self.uy = np.where(h.valid, np.sin(heading), 0.0)
        self.weight = np.where(h.valid, h.speed**2, 0.0)
        self.turn_rate = np.where(h.valid, h.turn_rate, 0.0)
        self.valid = h.valid
        self.span = (float(t[0]), float(t[-1]))

    def at(self, tq: np.ndarray):
        """Unit heading vector (cos, sin), weight and turn rate at track times ``tq`` (any shape);
        weight 0 outside the track or next to an invalid grid point."""
        x = (np.asarray(tq, dtype=float) - self.t0) / self.step
        i = np.floor(x).astype(np.int64)
        inside = (i >= 0) & (i < len(self.ux) - 1)
        i = np.clip(i, 0, max(0, len(self.ux) - 2))
        f = np.clip(x - i, 0.0, 1.0)
        j = np.minimum(i + 1, len(self.ux) - 1)
        ok = inside & self.valid[i] & self.valid[j]
        ux = (1 - f) * self.ux[i] + f * self.ux[j]
        uy = (1 - f) * self.uy[i] + f * self.uy[j]
        norm = np.hypot(ux, uy)
        ok &= norm > 1e-6
        norm = np.where(ok, norm, 1.0)
        w = np.where(ok, (1 - f) * self.weight[i] + f * self.weight[j], 0.0)
        rate = (1 - f) * self.turn_rate[i] + f * self.turn_rate[j]
        return ux / norm, uy / norm, w, rate


# --------------------------------------------------------------------------- coherence


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


def _check_search(search) -> Tuple[float, float]:
    lo, hi = (float(search[0]), float(search[1]))
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise TimeSyncError(f"search interval must be (low, high) seconds with low < high, got {search}")
    return lo, hi


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


def _estimate(channels: List[_Channel], grid: _HeadingGrid, search, step: float, max_drift: float,
              min_duration: float, min_turn_rate: float, sigma_ref: float, corr_time: float) -> OffsetEstimate:
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
                    smooth: float = 0.5, min_speed: float = 0.05, window: Optional[float] = 60.0,
                    max_drift: float = math.radians(20.0) / 60.0, step: float = 0.02,
                    min_duration: float = 10.0, min_turn_rate: float = math.radians(2.0),
                    sigma_ref: float = 0.01, prism_in_base=None) -> OffsetEstimate:
    """Time offset τ (s) with camera/VO stamp = total-station time + τ, by phase coherence.

    ``t_vo`` (N,) s and ``yaw_vo`` (N,) rad: VO yaw of base_link on the camera clock (any constant
    offset, slow drift allowed); ``t_track`` (M,) s and ``xy_track`` (M, 2|3) m: prism fixes on the
    total-station clock; ``weights`` (N,) optional VO sample weights (≥ 0). ``search`` (s): the
    interval of τ searched on a grid of ``step`` s then refined by golden section. ``smooth`` (s):
    σ of the track's local-quadratic fit; ``min_speed`` (m/s): below it the track heading is not
    used; ``window`` (s): each window has its own yaw offset and drift (≤ ``max_drift`` rad/s;
    None: one window). Raises TimeSyncError when the offset is not observable: fewer than
    ``min_duration`` s of moving overlap, a platform that never moves, a heading whose turn rate
    varies by less than ``min_turn_rate`` rad/s RMS, or a peak at the search edge.

    ``prism_in_base`` (x, y[, z]) m: the prism's lever arm in base_link; the track heading is turned
    from the prism's direction of travel to base_link's (a platform driving along its x axis).

    ``confidence`` = peak coherence × uniqueness (1 when every rival peak is ≥ 10 % lower)
    × 1/(1 + (σ/``sigma_ref``)²).
    """
    grid = _HeadingGrid(t_track, xy_track, smooth, min_speed, prism_in_base=prism_in_base)
    ch = _make_channel(t_vo, yaw_vo, weights, "VO yaw", window, drift=True)
    if len(ch.t) < 3:
        raise TimeSyncError(f"too short: only {len(ch.t)} VO samples")
    return _estimate([ch], grid, search, step, max_drift, min_duration, min_turn_rate, sigma_ref, 4.0 * smooth)


def estimate_offset_from_marker_yaws(t_marker, yaw_marker, t_track, xy_track, marker_ids=None,
                                     t_vo=None, yaw_vo=None, search=(-1.0, 1.0), *, smooth: float = 0.5,
                                     min_speed: float = 0.05, window: Optional[float] = 60.0,
                                     max_drift: float = math.radians(20.0) / 60.0, step: float = 0.02,
                                     min_duration: float = 10.0, min_turn_rate: float = math.radians(2.0),
                                     sigma_ref: float = 0.01, prism_in_base=None) -> OffsetEstimate:
    """Time offset τ (s, camera stamp = total-station time + τ) from absolute marker yaws.

    ``t_marker`` (K,) s on the camera clock and ``yaw_marker`` (K,) rad: per-frame absolute yaws of
    base_link derived from markers (no drift: each marker, if ``marker_ids`` is given, or all of
    them together get one constant phase, which absorbs a per-marker bias); optionally the VO yaw
    (``t_vo``, ``yaw_vo``) as a second channel with its own offset and drift. The other parameters
    and the errors are those of ``estimate_offset``.
    """
    grid = _HeadingGrid(t_track, xy_track, smooth, min_speed, prism_in_base=prism_in_base)
    t_m, yaw_m = np.asarray(t_marker, dtype=float).ravel(), np.asarray(yaw_marker, dtype=float).ravel()
    if len(t_m) != len(yaw_m):
        raise TimeSyncError(f"marker yaws: {len(t_m)} stamps but {len(yaw_m)} yaws")
    if len(t_m) < 3:
        raise TimeSyncError(f"too short: only {len(t_m)} marker yaws (no markers seen?)")
    channels = []
    if marker_ids is None:
        channels.append(_make_channel(t_m, yaw_m, None, "marker yaws", window, drift=False))
    else:
        ids = np.asarray(marker_ids).ravel()
        if len(ids) != len(t_m):
            raise TimeSyncError(f"marker yaws: {len(t_m)} stamps but {len(ids)} marker ids")
        for mid in np.unique(ids):
            sel = ids == mid
            if np.sum(sel) >= 3:
                channels.append(_make_channel(t_m[sel], yaw_m[sel], None, f"marker {mid} yaws", window, drift=False))
    if t_vo is not None and yaw_vo is not None:
        channels.append(_make_channel(t_vo, yaw_vo, None, "VO yaw", window, drift=True))
    return _estimate(channels, grid, search, step, max_drift, min_duration, min_turn_rate, sigma_ref, 4.0 * smooth)


# --------------------------------------------------------------------------- baseline


def _detrend(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x`` minus its least-squares straight line in ``t``."""
    tc = t - t.mean()
    den = float(tc @ tc)
    slope = float(tc @ (x - x.mean())) / den if den > 0 else 0.0
    return x - x.mean() - slope * tc


def cross_correlation_offset(t_vo, yaw_vo, t_track, xy_track, search=(-1.0, 1.0), *,
                             min_speed: float = 0.05, track_heading: str = "paper",
                             smooth: float = 0.5) -> OffsetEstimate:
    """The paper's baseline: τ (s, camera stamp = total-station time + τ) at whole-frame resolution.

    Track heading at each prism fix (``track_heading="paper"``) = circular mean of the headings
    towards the previous and the next fix, as in the paper — noisy at low speed, where a single
    wrong 2π unwrap spoils the correlation; ``"smoothed"`` uses ``heading_from_track`` (σ =
    ``smooth`` s) instead, to show the method's own limit. Fixes where the prism moves slower than
    ``min_speed`` m/s are dropped; the heading is unwrapped and interpolated linearly to the VO
    stamps shifted by k frames; τ = k·(median VO frame period) maximises the normalised correlation
    of the unwrapped headings, each linearly detrended over the overlap (the paper does not say;
    without it the 2π-per-lap trend swamps the correlation). ``sigma`` is half a frame;
    ``confidence`` the peak correlation.
    """
    if track_heading not in ("paper", "smoothed"):
        raise TimeSyncError(f"track_heading must be 'paper' or 'smoothed', got {track_heading!r}")
    lo, hi = _check_search(search)
    t_vo, yaw_vo = sorted_series(t_vo, yaw_vo, "VO yaw", TimeSyncError)
    xy = np.asarray(xy_track, dtype=float)
    if xy.ndim != 2 or xy.shape[1] < 2:
        raise TimeSyncError(f"track positions: expected an (N, 2) or (N, 3) array, got shape {xy.shape}")
    t_tr, xy = sorted_series(t_track, xy[:, :2], "track", TimeSyncError, ncols=2)
    if len(t_vo) < 3 or len(t_tr) < 5:
        raise TimeSyncError(f"too short: {len(t_vo)} VO samples and {len(t_tr)} prism fixes")
    if track_heading == "paper":
        d = np.diff(xy, axis=0)
        seg_dt = np.diff(t_tr)
        seg_speed = np.hypot(d[:, 0], d[:, 1]) / np.where(seg_dt > 0, seg_dt, np.inf)
        u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
        mean_u = u[:-1] + u[1:]
        heading = np.arctan2(mean_u[:, 1], mean_u[:, 0])  # at fixes 1 … M−2
        moving = (seg_speed[:-1] >= min_speed) & (seg_speed[1:] >= min_speed)
        t_fix, top_speed = t_tr[1:-1], float(seg_speed.max(initial=0.0))
    else:
        h = heading_from_track(t_tr, xy, smooth=smooth, min_speed=min_speed)
        heading, moving, t_fix, top_speed = h.heading, h.valid, t_tr, float(h.speed.max(initial=0.0))
    if not np.any(moving):
        raise TimeSyncError(f"the prism never moves (top speed {top_speed:.3f} m/s): the track has no heading")
    t_h = t_fix[moving]
    psi_track = np.unwrap(heading[moving])
    period = float(np.median(np.diff(t_vo)))
    if not period > 0:
        raise TimeSyncError("VO stamps are not increasing")
    psi_vo = np.unwrap(yaw_vo)
    ks = np.arange(int(math.ceil(lo / period)), int(math.floor(hi / period)) + 1)
    corr = np.full(len(ks), np.nan)
    for n, k in enumerate(ks):
        tq = t_vo - k * period
        ok = (tq >= t_h[0]) & (tq <= t_h[-1])
        if np.sum(ok) < 10:
            continue
        a = _detrend(t_vo[ok], psi_vo[ok])
        b = _detrend(t_vo[ok], np.interp(tq[ok], t_h, psi_track))
        den = math.sqrt(float(np.sum(a * a) * np.sum(b * b)))
        corr[n] = float(np.sum(a * b) / den) if den > 0 else np.nan
    if not np.any(np.isfinite(corr)):
        raise TimeSyncError(
            f"no overlap: VO [{t_vo[0]:.3f}, {t_vo[-1]:.3f}] s and moving track [{t_h[0]:.3f}, {t_h[-1]:.3f}] s "
            f"do not overlap for any offset in [{lo}, {hi}] s")
    best = int(np.nanargmax(corr))
    peak = float(corr[best])
    return OffsetEstimate(offset=float(ks[best] * period), sigma=period / 2.0, confidence=max(0.0, peak),
                          coherence=peak, taus=ks * period, curve=np.nan_to_num(corr, nan=0.0), method="xcorr",
                          n_samples=len(t_vo), overlap=float(t_vo[-1] - t_vo[0]))


# --------------------------------------------------------------------------- online


class OnlineOffsetEstimator:
    """Incremental time-offset estimation for the live node, over a sliding ``horizon`` (s).

    Feed samples as they come (``add_vo`` yaw on the camera clock, ``add_track`` prism fixes on the
    total-station clock, ``add_marker_yaw`` absolute yaws on the camera clock) and call ``update``;
    every ``update_period`` s of camera time it re-estimates over the buffered data (memory is
    bounded by ``horizon`` and ``max_samples`` per stream). ``latest`` is the last estimate (or
    None), ``last_error`` why the last attempt failed (or None); ``applied`` is the offset in use,
    changed only by an estimate with ``confidence ≥ min_confidence`` and ``sigma ≤ max_sigma``.

    Confident estimates are fused (a scalar Kalman filter, ``applied_sigma`` its σ in s): the first
    counts fully; each later one shares all but ``update_period`` s of its data with the previous,
    so it enters with its variance × ``horizon / update_period``; the offset may wander as a random
    walk of ``offset_walk`` s/√s (clock drift).

    Thread-safe: the ``add_*`` calls may come from one thread while ``update_in_background`` runs the
    estimate (0.1–0.5 s of numpy) in another, so a live node's image loop never waits for it.
    """

    def __init__(self, horizon: float = 90.0, search=(-1.0, 1.0), update_period: float = 5.0,
                 min_confidence: float = 0.5, max_sigma: float = 0.01, max_samples: int = 20000,
                 offset_walk: float = 1e-4, **kwargs):
        if horizon <= 0 or update_period <= 0:
            raise TimeSyncError("horizon and update_period must be > 0 s")
        self.horizon = float(horizon)
        self.search = _check_search(search)
        self.update_period = float(update_period)
        self.min_confidence = float(min_confidence)
        self.max_sigma = float(max_sigma)
        self.kwargs = kwargs
        self._vo: Deque[Tuple[float, float]] = collections.deque(maxlen=max_samples)
        self._track: Deque[Tuple[float, float, float]] = collections.deque(maxlen=max_samples)
        self._marker: Deque[Tuple[float, float]] = collections.deque(maxlen=max_samples)
        self._last_update: Optional[float] = None
        self.latest: Optional[OffsetEstimate] = None
        self.last_error: Optional[str] = None
        self.offset_walk = float(offset_walk)
        self.applied: Optional[float] = None
        self.applied_sigma: Optional[float] = None
        self._applied_at: Optional[float] = None
        self._lock = threading.Lock()
        self._worker: Optional[threading.Thread] = None

    def add_vo(self, t: float, yaw: float) -> None:
        """A VO yaw (rad) of base_link stamped ``t`` (s, camera clock)."""
        with self._lock:
            self._vo.append((float(t), float(yaw)))
            self._trim(self._vo, float(t))

    def add_track(self, t: float, x: float, y: float) -> None:
        """A prism fix (m, map) stamped ``t`` (s, total-station clock)."""
        with self._lock:
            self._track.append((float(t), float(x), float(y)))
            self._trim(self._track, float(t))

    def add_marker_yaw(self, t: float, yaw: float) -> None:
        """An absolute yaw (rad) of base_link from a marker, stamped ``t`` (s, camera clock)."""
        with self._lock:
            self._marker.append((float(t), float(yaw)))
            self._trim(self._marker, float(t))

    def clear(self) -> None:
        """Forget the buffered samples (a time jump: a looped bag); the applied offset is kept."""
        with self._lock:
            self._vo.clear()
            self._track.clear()
            self._marker.clear()
            self._last_update = None

    def _trim(self, buf: Deque, newest: float) -> None:
        while buf and buf[0][0] < newest - self.horizon:
            buf.popleft()

    @property
    def buffered(self) -> Tuple[int, int, int]:
        """Numbers of buffered (VO, track, marker) samples."""
        return len(self._vo), len(self._track), len(self._marker)

    def _due(self, now: Optional[float], force: bool):
        """(now, VO, track, marker arrays) to estimate from when an update is due, else None."""
        with self._lock:
            if not self._vo and not self._marker:
                return None
            if now is None:
                now = max(self._vo[-1][0] if self._vo else -math.inf,
                          self._marker[-1][0] if self._marker else -math.inf)
            if not force and self._last_update is not None and now - self._last_update < self.update_period:
                return None
            self._last_update = now
            return (now, np.array(self._vo, dtype=float).reshape(-1, 2),
                    np.array(self._track, dtype=float).reshape(-1, 3),
                    np.array(self._marker, dtype=float).reshape(-1, 2))

    def update(self, now: Optional[float] = None, force: bool = False) -> Optional[OffsetEstimate]:
        """Re-estimate if ``update_period`` s (camera clock ``now``, default the newest VO stamp)
        passed since the last attempt, or if ``force``; returns the new estimate or None."""
        data = self._due(now, force)
        return None if data is None else self._estimate_from(*data)

    def update_in_background(self, now: Optional[float] = None) -> bool:
        """Like ``update`` but in a daemon thread (at most one at a time); True if one was started.
        ``latest``, ``applied`` and ``last_error`` change when it ends."""
        if self._worker is not None and self._worker.is_alive():
            return False
        data = self._due(now, False)
        if data is None:
            return False
        self._worker = threading.Thread(target=self._estimate_from, args=data, name="time offset", daemon=True)
        self._worker.start()
        return True

    def suggestion(self, in_use: float, min_difference: float = 0.02, n_sigma: float = 5.0) -> Optional[float]:
        """The applied (confident, fused) offset when it contradicts the offset ``in_use`` (s): differs
        by more than ``n_sigma`` ``applied_sigma`` and ``min_difference`` s (a forgotten or wrong offset);
        else None (keep ``in_use``: a good offset from ``timesync --markers`` is not replaced by a coarser
        live one, nor by one whose σ is optimistic)."""
        with self._lock:  # a consistent pair: the worker thread fuses both
            applied, sigma = self.applied, self.applied_sigma
        if applied is None or sigma is None:
            return None
        return applied if abs(applied - in_use) > max(n_sigma * sigma, min_difference) else None

    def _estimate_from(self, now: float, vo: np.ndarray, track: np.ndarray, mk: np.ndarray) -> Optional[OffsetEstimate]:
        try:
            if len(mk) >= 3:
                est = estimate_offset_from_marker_yaws(
                    mk[:, 0], mk[:, 1], track[:, 0], track[:, 1:], t_vo=vo[:, 0] if len(vo) else None,
                    yaw_vo=vo[:, 1] if len(vo) else None, search=self.search, **self.kwargs)
            else:
                est = estimate_offset(vo[:, 0], vo[:, 1], track[:, 0], track[:, 1:], search=self.search,
                                      **self.kwargs)
        except TimeSyncError as e:
            self.last_error = str(e)
            return None
        with self._lock:
            self.last_error = None
            self.latest = est
            if est.confidence >= self.min_confidence and est.sigma <= self.max_sigma:
                self._fuse(est, now)
        return est

    def _fuse(self, est: OffsetEstimate, now: float) -> None:
        if self.applied is None or self.applied_sigma is None or self._applied_at is None:
            self.applied, self.applied_sigma, self._applied_at = est.offset, est.sigma, now
            return
        prior_var = self.applied_sigma**2 + self.offset_walk**2 * max(0.0, now - self._applied_at)
        new_var = est.sigma**2 * max(1.0, self.horizon / self.update_period)
        gain = prior_var / (prior_var + new_var)
        self.applied += gain * (est.offset - self.applied)
        self.applied_sigma = math.sqrt((1.0 - gain) * prior_var)
        self._applied_at = now

    def correct_stamp(self, t_camera: float) -> float:
        """Camera stamp (s) moved to the total-station clock with the applied offset (unchanged
        while none is applied)."""
        return t_camera - self.applied if self.applied is not None else t_camera

"""The paper's method, kept as the baseline: normalised cross-correlation of unwrapped headings
at whole-frame lags.

In: VO yaws (camera clock) and prism fixes (total-station clock). Out: an
:class:`~.estimate.OffsetEstimate` at one-frame resolution (:func:`cross_correlation_offset`).
"""

from __future__ import annotations

import math

import numpy as np

from ..tum import sorted_series
from .estimate import OffsetEstimate, TimeSyncError, _check_search
from .heading import heading_from_track

__all__ = ["cross_correlation_offset"]


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

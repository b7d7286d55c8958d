"""The prism track's direction of travel.

In: prism fixes (times on the total-station clock, (N, 2) or (N, 3) map positions). Out: the
heading, speed and turn rate at query times (:func:`heading_from_track`: a zero-lag local
quadratic fit, :class:`TrackHeading`), and for :mod:`.coherence` the same on a regular grid,
interpolated on the unit circle with weights speed² (:class:`_HeadingGrid`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..tum import sorted_series
from .estimate import TimeSyncError

__all__ = ["TrackHeading", "heading_from_track"]


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

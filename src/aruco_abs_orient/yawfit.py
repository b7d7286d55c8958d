"""Robust least-squares fits of marker yaws, for the run's self-checks and the marker map's check.

In: marker yaws (times s, marker ids, yaws and σ rad, where each marker is in the image) and the prism track.
Out: the bearing rate of a marker from the prism (how a time offset moves its yaw), hat functions for a smooth
common part (the odometry's drift), Huber-weighted least squares with its covariance, and the self-check's fit
of time offset + camera tilt + a yaw offset per marker, with the markers off the others taken out one by one.
``p`` is the caller's parameters: ``knot_spacing`` (s), ``common_drift_sigma`` (rad), ``sigma_floor`` (rad),
``min_samples``, ``min_marker_bias`` (rad) and ``significance`` (σ). ROS-free; angles in radians, times in seconds.
"""

from __future__ import annotations

import math
from typing import List, NamedTuple, Optional, Tuple

import numpy as np

from .transforms import wrap_angle

__all__ = ["bearing_rate", "hat_basis", "robust_lsq", "FitData", "offsets_fit", "moved_markers", "tilt_fit"]


def bearing_rate(t, marker_xyz, prism_t, prism_xyz, h: float = 0.1) -> np.ndarray:
    """k = d/dt az(M − P(t)) (rad/s) at times ``t`` (s) for markers at ``marker_xyz`` (N×3, m), the
    prism track (``prism_t`` sorted s, ``prism_xyz`` M×3 m) differenced over ±``h`` s; NaN outside it."""
    t = np.asarray(t, dtype=float)
    m = np.asarray(marker_xyz, dtype=float).reshape(-1, 3)
    pt = np.asarray(prism_t, dtype=float)
    pp = np.asarray(prism_xyz, dtype=float).reshape(-1, 3)
    if len(pt) < 2:
        return np.full(len(t), np.nan)

    def az(tq):
        x = np.interp(tq, pt, pp[:, 0])
        y = np.interp(tq, pt, pp[:, 1])
        return np.arctan2(m[:, 1] - y, m[:, 0] - x)

    k = wrap_angle(az(t + h) - az(t - h)) / (2 * h)
    k[(t - h < pt[0]) | (t + h > pt[-1])] = np.nan
    return k


def hat_basis(t: np.ndarray, spacing: float) -> np.ndarray:
    """Piecewise-linear hat functions on knots every ``spacing`` s over the span of ``t`` (N×K)."""
    lo, hi = float(t.min()), float(t.max())
    n = max(int(math.ceil((hi - lo) / spacing)), 1) + 1
    knots = np.linspace(lo, hi if hi > lo else lo + 1.0, n)
    step = knots[1] - knots[0]
    return np.clip(1.0 - np.abs(t[:, None] - knots[None, :]) / step, 0.0, None)


def robust_lsq(A: np.ndarray, y: np.ndarray, w: np.ndarray, iterations: int = 5,
               prior: Optional[Tuple[np.ndarray, float]] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Huber-weighted least squares of y ≈ A x with prior weights ``w`` (1/σ²): x and its covariance
    (scaled by the robust scale of the normalised residuals). ``prior`` (B, w_b): pseudo-observations B x ≈ 0
    of weight w_b (1/σ²), never down-weighted."""
    wr = np.ones(len(y))
    sw = np.sqrt(w)
    B, wb = prior if prior is not None else (np.zeros((0, A.shape[1])), 0.0)
    x = np.zeros(A.shape[1])
    scale = 1.0
    for _ in range(iterations):
        ww = np.sqrt(wr) * sw
        x, *_ = np.linalg.lstsq(np.vstack([A * ww[:, None], B * math.sqrt(wb)]),
                                np.concatenate([y * ww, np.zeros(len(B))]), rcond=None)
        z = (y - A @ x) * sw
        scale = max(1.4826 * float(np.median(np.abs(z))), 1e-9)
        a = np.abs(z) / (1.345 * scale)
        wr = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
    ww = wr * w
    cov = np.linalg.pinv(A.T @ (A * ww[:, None]) / scale ** 2 + wb * B.T @ B)
    return x, cov


class FitData(NamedTuple):
    """The arrays of the robust fits, one entry per marker yaw: times, marker ids, the fitted yaws (rad), their
    σ, the markers' bearing rates (rad/s) and where each marker is in the image (azimuth, elevation)."""

    t: np.ndarray
    ids: np.ndarray
    y: np.ndarray
    sig: np.ndarray
    k: np.ndarray
    az: np.ndarray
    el: np.ndarray


def offsets_fit(d: FitData, mask: np.ndarray, p):
    """(x, cov, {marker: (offset from the middle one of those seen with it rad, yaws, its σ)}) of the fit over
    ``mask``: time offset, tilt, the common part's hat functions and a yaw offset per marker (the most seen one's
    is the common part's)."""
    seen, counts = np.unique(d.ids[mask], return_counts=True)
    te = np.tan(d.el[mask])
    hats = hat_basis(d.t[mask], p.knot_spacing)
    ref = seen[int(np.argmax(counts))]
    others = [m for m in seen if m != ref]
    A = np.column_stack([d.k[mask], -te * np.cos(d.az[mask]), -te * np.sin(d.az[mask]), hats]
                        + [(d.ids[mask] == m).astype(float) for m in others])
    n0 = 3 + hats.shape[1]
    # the common part drifts smoothly: its knots' second differences tied to 0 by common_drift_sigma. Markers
    # seen only in stretches of the run apart (no marker between them) are then compared through its drift
    # carried across the gap, with that σ, instead of through a singular fit
    curvature = np.zeros((max(hats.shape[1] - 2, 0), A.shape[1]))
    curvature[:, 3:n0] = np.diff(np.eye(hats.shape[1]), n=2, axis=0)
    xs, cs = robust_lsq(A, wrap_angle(d.y[mask]), 1.0 / (d.sig[mask] ** 2 + p.sigma_floor ** 2),
                        prior=(curvature, 1.0 / p.common_drift_sigma ** 2))
    order = [ref] + others
    value = np.concatenate([[0.0], xs[n0:]])
    cov = np.zeros((len(order), len(order)))
    cov[1:, 1:] = cs[n0:, n0:]
    offsets = {}
    for group in _seen_together(d.t[mask], d.ids[mask], order):
        # against the middle of the markers seen in the same stretch of the run: the median of theirs, σ that
        # of its offset minus their mean; fewer than 3 have no majority to be off (σ infinite)
        contrast = np.eye(len(group)) - 1.0 / len(group)
        sigma = np.sqrt(np.maximum(np.diag(contrast @ cov[np.ix_(group, group)] @ contrast.T), 0.0))
        middle = float(np.median(value[group]))
        for j, sd in zip(group, sigma if len(group) >= 3 else np.full(len(group), np.inf)):
            offsets[int(order[j])] = (float(value[j]) - middle, float(sd))
    count = dict(zip(seen.tolist(), counts.tolist()))
    return xs, cs, {m: (v, int(count[m]), sd) for m, (v, sd) in offsets.items()}


def _seen_together(t: np.ndarray, ids: np.ndarray, order) -> List[List[int]]:
    """The markers (indices into ``order``) in groups whose spans of time (first to last yaw) overlap: markers
    seen in stretches of the run apart, with none seen across the gap, are compared only through the common
    part's drift across it, not with each other."""
    spans = sorted((float(t[ids == m].min()), float(t[ids == m].max()), j) for j, m in enumerate(order))
    groups: List[List[int]] = []
    end = -math.inf
    for lo, hi, j in spans:
        if lo > end:
            groups.append([])
        groups[-1].append(j)
        end = max(end, hi)
    return groups


def moved_markers(d: FitData, base: np.ndarray, p):
    """(x, cov, per marker (offset, yaws, σ), the moved markers) of the fit with a yaw offset per marker: a moved
    marker shows in its own offset, while the time offset and the tilt come from how each marker's yaw varies.
    The worst marker off the others is taken out and the rest fitted again (a moved marker's error varies
    along the track and would otherwise leak into the others'), until the rest agree."""
    x, cov, per_marker = offsets_fit(d, base, p)
    moved: List[int] = []
    current = dict(per_marker)
    while len(current) >= 3:  # "off the others" needs a majority to agree
        off = {m: dv for m, (dv, n, sd) in current.items()
               if n >= 5 and abs(dv) > max(p.min_marker_bias, p.significance * sd)}
        if not off:
            break
        worst = max(off, key=lambda m: abs(off[m]))
        moved.append(worst)
        per_marker[worst] = current[worst]
        rest = base & ~np.isin(d.ids, moved)
        if rest.sum() < p.min_samples:
            break
        _, _, current = offsets_fit(d, rest, p)
        per_marker.update(current)
    return x, cov, per_marker, moved


def tilt_fit(d: FitData, keep: np.ndarray, p):
    """The tilt from all markers together: a marker's own offset would absorb it (each marker is seen from a
    narrow range of directions), so this fit has none (``keep`` leaves out the markers off the others)."""
    te = np.tan(d.el[keep])
    B = np.column_stack([d.k[keep], -te * np.cos(d.az[keep]), -te * np.sin(d.az[keep]),
                         hat_basis(d.t[keep], p.knot_spacing)])
    return robust_lsq(B, wrap_angle(d.y[keep]), 1.0 / (d.sig[keep] ** 2 + p.sigma_floor ** 2))

"""Start-up of the map→odom filter, anywhere (doc/design.md §8): from buffered marker yaws and prisms.

In: the marker yaws and prism positions of the last ``standstill_duration`` s (:class:`Startup` buffers them,
the filter's ``add_*`` feed it while waiting). Out: the :class:`.filter_core.KalmanCore` anchored — δψ the
consensus of ``init_min_yaws`` yaws that agree (:func:`consensus`, :func:`solver.yaw_consensus`) carried to the
start time with a fitted drift rate (:func:`drift_fit`), the translation tied to the latest prism (averaged at
a standstill) — or ``stats.waiting_reason`` saying why not yet. While moving the yaws must come from
``init_min_markers`` markers, or from one marker that the prism track confirms; at a standstill one marker
suffices. :func:`reset_yaw` sets δψ and ω from a consensus keeping the robot's map position (re-initialisation
and lock-out recovery use it). numpy only, no ROS.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Tuple

import numpy as np

from .filter_core import KalmanCore, Prism, UpdateResult, Yaw, ez_cross, result
from .solver import yaw_consensus
from .transforms import rot_z, wrap_angle

__all__ = ["Consensus", "consensus", "drift_fit", "reset_yaw", "Startup"]

Consensus = Tuple[float, float, List[Yaw]]   # (δψ rad, variance rad², the yaws that agree)


def consensus(yaws: List[Yaw], floor: float, min_yaws: int, min_markers: int = 1
              ) -> Tuple[Optional[Consensus], str]:
    """((δψ rad, variance rad², members), '') from buffered yaws, or (None, why not): fewer than
    ``min_yaws`` agree (within the tolerance ``floor`` rad at least), or they come from fewer than
    ``min_markers`` markers."""
    if not yaws:
        return None, "no marker yaws (no map marker seen with a prism position)"
    if len(yaws) < min_yaws:
        return None, f"{len(yaws)} marker yaw(s), {min_yaws} consistent ones needed"
    off = np.array([y.offset for y in yaws])
    sig = np.array([y.sigma for y in yaws])
    mean, members = yaw_consensus(off, sig, floor)
    if int(members.sum()) < min_yaws:
        spread = math.degrees(float(np.ptp(wrap_angle(off - mean))))
        return None, (f"marker yaws disagree: {int(members.sum())} of {len(yaws)} consistent "
                      f"(spread {spread:.2f}°), {min_yaws} needed")
    used = [y for y, m in zip(yaws, members) if m]
    markers = {i for y in used for i in y.sources}
    if min_markers > 1 and len(markers) < min_markers:
        return None, (f"{len(used)} consistent marker yaws but from {len(markers)} marker(s): "
                      f"{min_markers} different markers needed to start while moving")
    # One marker's yaws share its bias: per marker, its σ (not σ/√n); markers are independent.
    by_marker: Dict[object, List[float]] = {}
    for i, y in enumerate(used):
        by_marker.setdefault(y.marker_id if y.marker_id is not None else ("sample", i), []).append(y.sigma)
    info = sum(1.0 / (float(np.mean(s)) ** 2) for s in by_marker.values())
    return (mean, 1.0 / info, used), ""


def drift_fit(used: List[Yaw], dpsi: float, t: float, prior: float) -> Tuple[float, float, float]:
    """(δψ at ``t``, drift rate ω rad/s, its variance) from consensus yaws: a weighted line through
    their offsets over time, its slope shrunk towards 0 by the drift-rate prior (variance ``prior``: a short
    window says little about the drift); δψ is the line at ``t``."""
    ts = np.array([y.t for y in used])
    w = 1.0 / np.array([y.sigma for y in used]) ** 2
    tm = float(np.sum(w * ts) / np.sum(w))
    r = wrap_angle(np.array([y.offset for y in used]) - dpsi)
    sxx = float(np.sum(w * (ts - tm) ** 2))
    if prior <= 0 or sxx <= 0:
        return float(wrap_angle(dpsi + np.sum(w * r) / np.sum(w))), 0.0, prior
    slope, var_slope = float(np.sum(w * (ts - tm) * r) / sxx), 1.0 / sxx
    omega = slope * prior / (prior + var_slope)
    at_mean = float(np.sum(w * r) / np.sum(w))
    return float(wrap_angle(dpsi + at_mean + omega * (t - tm))), omega, prior * var_slope / (prior + var_slope)


def reset_yaw(core: KalmanCore, t: float, cons: Consensus) -> None:
    """δψ and ω of ``core`` from a consensus of yaws at time ``t``; the robot's map position (and its
    covariance) is kept: the translation turns with δψ about the robot."""
    _, var, used = cons
    core.predict_to(t)
    dpsi, drift, drift_var = drift_fit(used, cons[0], max(t, core.t), core.params.initial_drift_rate_sigma ** 2)
    q = core.odom_pos
    g_old = ez_cross(rot_z(core.x[0]) @ q)
    A = np.eye(5)
    A[1:4, 0] = g_old                      # (δψ, t) → (δψ, m = Rz(δψ) q + t)
    Py = A @ core.P @ A.T
    m = rot_z(core.x[0]) @ q + core.x[1:4]
    Py[[0, 4], :] = Py[:, [0, 4]] = 0.0
    Py[0, 0] = var
    Py[4, 4] = drift_var
    g_new = ez_cross(rot_z(dpsi) @ q)
    Ainv = np.eye(5)
    Ainv[1:4, 0] = -g_new
    core.x = np.concatenate([[dpsi], m - rot_z(dpsi) @ q, [drift]])
    core.P = Ainv @ Py @ Ainv.T
    core.stats.state = "tracking"
    core.stats.waiting_reason = ""
    core.stats.last_update = max(core.stats.last_update, t)


class Startup:
    """The buffers of the start-up (``yaws``, ``prisms``) and the decision to start from them."""

    def __init__(self, core: KalmanCore):
        self.core = core
        self.yaws: List[Yaw] = []
        self.prisms: List[Prism] = []

    def consensus(self, yaws: List[Yaw], min_yaws: int, min_markers: int = 1) -> Tuple[Optional[Consensus], str]:
        """:func:`consensus` with the tuning's tolerance floor."""
        return consensus(yaws, self.core.params.init_yaw_floor, min_yaws, min_markers)

    def trim(self, t: float) -> None:
        """Drop the buffered measurements older than the start-up window (or ``max_delay``) before ``t``."""
        p = self.core.params
        horizon = t - max(p.standstill_duration, p.max_delay)
        self.yaws = [y for y in self.yaws if y.t >= horizon]
        self.prisms = [m for m in self.prisms if m.t >= horizon]

    def try_start(self, t: float) -> UpdateResult:
        """Start the filter at ``t`` from the buffers when they suffice ('initialised'), else 'buffered'."""
        core, p = self.core, self.core.params
        window_p = [m for m in self.prisms if m.t >= t - p.standstill_duration]
        window_y = [y for y in self.yaws if y.t >= t - p.standstill_duration]
        if not window_p:
            core.stats.waiting_reason = "no prism position (total station not tracking, or no prism topic)"
            return result("buffered")
        still = self.is_standstill(window_p, window_y, t)
        if not still and p.require_standstill:
            core.stats.waiting_reason = (f"waiting for a standstill of {p.standstill_duration:g} s "
                                         "(require_standstill is set)")
            return result("buffered")
        cons, why = self.consensus(window_y, p.init_min_yaws, 1 if still else p.init_min_markers)
        if cons is None and not still:
            cons, why = self.confirmed_by_track(window_y, window_p, why)
        if cons is None:
            core.stats.waiting_reason = why
            return result("buffered")
        used = cons[2]
        use_p = window_p if still else window_p[-1:]
        core.t = max(t, max(m.t for m in use_p))
        dpsi, drift, drift_var = drift_fit(used, cons[0], core.t, p.initial_drift_rate_sigma ** 2)
        n = len(use_p)
        core.anchor(dpsi, cons[1], np.mean([m.p for m in use_p], axis=0), np.mean([m.cov for m in use_p], axis=0) / n,
                    np.mean([m.q for m in use_p], axis=0), drift, drift_var)
        core.stats.state = "tracking"
        core.stats.waiting_reason = ""
        core.stats.prism_accepted += n
        core.stats.last_prism = max(m.t for m in use_p)
        for y in used:
            core.count_yaw(True, y.marker_id, y.t)
        core.stats.last_update = core.t
        self.yaws, self.prisms = [], []
        return result("initialised")

    def confirmed_by_track(self, window_y: List[Yaw], window_p: List[Prism], why: str
                           ) -> Tuple[Optional[Consensus], str]:
        """While moving with one marker in view: its consistent yaws, if the prism track agrees with them.
        The prism's displacement over the window, in map and in odom, gives δψ independently of any
        marker (Δp = Rz(δψ)·Δq), to about σ_prism / distance: a false id or a moved marker is degrees off."""
        cons, _ = self.consensus(window_y, self.core.params.init_min_yaws)
        if cons is None:
            return None, why
        first, last = window_p[0], window_p[-1]
        dp, dq = (last.p - first.p)[:2], (last.q - first.q)[:2]
        dist = float(np.linalg.norm(dq))
        if dist < 0.5:
            return None, why + " (or a prism track of 0.5 m to confirm one)"
        track = math.atan2(dp[1], dp[0]) - math.atan2(dq[1], dq[0])
        sigma = math.sqrt(float(np.trace(first.cov[:2, :2] + last.cov[:2, :2])) / 2.0) / dist
        diff = abs(float(wrap_angle(cons[0] - track)))
        if diff > max(3.0 * math.hypot(sigma, math.sqrt(cons[1])), math.radians(2.0)):
            return None, (f"the marker yaws disagree with the prism track by {math.degrees(diff):.1f}° "
                          "(a false id or a moved marker?)")
        return cons, ""

    def is_standstill(self, window_p: List[Prism], window_y: List[Yaw], t: float) -> bool:
        """Odometry and prism still over the window (within the standstill tolerances)."""
        p = self.core.params
        if t - min(m.t for m in window_p) < 0.9 * p.standstill_duration or len(window_p) < 3:
            return False
        q = np.array([m.q for m in window_p])
        pm = np.array([m.p for m in window_p])
        if np.linalg.norm(q - q.mean(axis=0), axis=1).max() > p.standstill_odom_tolerance:
            return False
        half = len(pm) // 2                   # halves' means: insensitive to the prism noise
        if np.linalg.norm(pm[:half].mean(axis=0) - pm[half:].mean(axis=0)) > p.standstill_prism_tolerance:
            return False
        oy = np.array([y.odom_yaw for y in window_y])
        return len(oy) == 0 or float(np.abs(wrap_angle(oy - oy[0])).max()) <= p.standstill_yaw_tolerance

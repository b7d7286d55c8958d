"""The Kalman core of the map→odom filter (doc/design.md §8): state, prediction, updates, restart.

State ``x = (δψ, tx, ty, tz, ω)`` with ``map_T_odom = [Rz(δψ), t]`` (rad, m) and ω = dδψ/dt (rad/s), its
covariance ``P`` (5×5) and time ``t`` (s). :class:`KalmanCore` predicts it (δψ turns about the robot's latest
odometry position), applies one prism, yaw or resection pose at a time with χ² gating (a measurement up to
``max_delay`` s late is applied with its noise inflated by the process noise over its delay; older ones are
counted as too old), sets it from an anchor (δψ and a position), and carries it through :meth:`snapshot` /
:meth:`restore`. It also holds the shared counters (:class:`FilterStats`) and the sample types the start-up
and recovery parts buffer. Contract: the filter never goes back in time; a gated measurement leaves the state
untouched. numpy only, no ROS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from .errors import ConfigurationError
from .transforms import make_T, rot_z, wrap_angle

__all__ = ["CorrectionError", "NotInitialisedError", "FilterStats", "UpdateResult", "KalmanCore"]


def ez_cross(v: np.ndarray) -> np.ndarray:
    """e_z × v: the derivative of Rz(δψ)·q w.r.t. δψ when v = Rz(δψ)·q."""
    return np.array([-v[1], v[0], 0.0])


class CorrectionError(ConfigurationError):
    """Malformed input to the map→odom filter (wrong shapes, bad parameters)."""


class NotInitialisedError(CorrectionError):
    """map→odom was asked for before the filter was initialised."""


@dataclass
class FilterStats:
    """Counters for diagnostics; times in seconds (NaN: never)."""

    state: str = "waiting"              # 'waiting' (start-up), 'tracking', 'reinitialising'
    waiting_reason: str = "no measurements yet"   # why it is not tracking yet ('' once tracking)
    yaw_accepted: int = 0
    yaw_rejected: int = 0
    prism_accepted: int = 0
    prism_rejected: int = 0
    too_old: int = 0
    invalid: int = 0
    reinitialisations: int = 0
    lockout_recoveries: int = 0         # resets to the consensus of consistently gated yaws
    noise_scale: float = 1.0            # current factor on the yaw random walk's variance (adaptive)
    restored_age: float = float("nan")  # s: age of the state it was restored from (NaN: not restored)
    last_update: float = float("nan")
    last_yaw: float = float("nan")
    last_prism: float = float("nan")
    prism_reanchors: int = 0
    pose_accepted: int = 0              # resection poses (markers only) used
    pose_rejected: int = 0              # resection poses gated out
    pose_reanchors: int = 0             # translation re-anchored to resection poses that agree (position off)
    accepted_by_marker: Dict[int, int] = field(default_factory=dict)
    rejected_by_marker: Dict[int, int] = field(default_factory=dict)


class UpdateResult(NamedTuple):
    """Outcome of one measurement: ``status`` is 'accepted', 'gated' (χ² test failed), 'buffered'
    (kept for (re)initialisation), 'initialised' (it completed the initialisation), 'too_old' or
    'invalid'; ``chi2`` the normalised innovation squared (NaN when not tested); ``innovation``
    (rad for yaw, m (3,) for the prism; NaN when not tested)."""

    status: str
    chi2: float
    innovation: object

    @property
    def accepted(self) -> bool:
        return self.status in ("accepted", "initialised")

    def __bool__(self) -> bool:
        """True when the measurement was used (``if filt.add_yaw(...):``)."""
        return self.accepted


def result(status: str, chi2: float = float("nan"), innovation: object = float("nan")) -> UpdateResult:
    """An :class:`UpdateResult`, untested (NaN) unless given."""
    return UpdateResult(status, chi2, innovation)


class Yaw(NamedTuple):
    """A marker yaw (or a resection's) as a measurement of δψ."""

    t: float
    offset: float            # ψ_abs − ψ_odom (rad)
    sigma: float
    marker_id: Optional[int]
    odom_yaw: float
    sources: Tuple[int, ...]  # ids of the markers behind it (empty: unknown)


class Pose(NamedTuple):
    """The position part of a resection."""

    t: float
    p: np.ndarray            # base_link in map (m)
    cov: np.ndarray          # 3×3 m²
    q: np.ndarray            # base_link in odom (m)


class Prism(NamedTuple):
    """A prism position."""

    t: float
    p: np.ndarray            # map (m)
    cov: np.ndarray
    q: np.ndarray            # prism in odom (m)


def checked_pose(odom_T_base) -> Optional[np.ndarray]:
    """``odom_T_base`` as a 4×4 array, None when not finite; CorrectionError when not 4×4."""
    T = np.asarray(odom_T_base, dtype=float)
    if T.shape != (4, 4):
        raise CorrectionError(f"odom_T_base: expected a 4×4 transform, got shape {T.shape}")
    return T if np.all(np.isfinite(T)) else None


class KalmanCore:
    """The state (``x``, ``P``, ``t``), the latest odometry position, the tuning and the counters."""

    def __init__(self, params):
        self.params = params
        self.stats = FilterStats()
        self.x = np.zeros(5)
        self.P = np.zeros((5, 5))
        self.t = float("-inf")              # time of the state (s)
        self.odom_pos = np.zeros(3)         # latest base_link position in odom (for the process noise)
        self.odom_pos_t = float("-inf")

    @property
    def initialised(self) -> bool:
        return self.stats.state != "waiting"

    def predicted(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """map→odom (4×4) and its covariance (4×4 over δψ, x, y, z) predicted to ``t`` (never back)."""
        dt = max(0.0, float(t) - self.t)
        F = self.transition(dt, self.odom_pos)
        x = F @ self.x
        P = F @ self.P @ F.T + self.process_noise(dt, self.odom_pos)
        return make_T(rot_z(x[0]), x[1:4]), P[:4, :4]

    def snapshot(self) -> Dict[str, object]:
        """The state as plain numbers (JSON-ready): ``t``, ``x``, ``P``, ``odom_pos``, ``noise_scale``."""
        return {"t": self.t, "x": self.x.tolist(), "P": self.P.tolist(), "odom_pos": self.odom_pos.tolist(),
                "noise_scale": self.stats.noise_scale}

    def restore(self, snap: Dict[str, object], t: float, max_age: float) -> str:
        """Start from a :meth:`snapshot` at most ``max_age`` s before ``t``; '' when restored, else why not."""
        try:
            t0 = float(snap["t"])
            x, P = np.array(snap["x"], dtype=float), np.array(snap["P"], dtype=float)
            odom_pos = np.array(snap["odom_pos"], dtype=float)
            scale = float(snap.get("noise_scale", 1.0))
        except (KeyError, TypeError, ValueError) as e:
            return f"not a filter state ({e})"
        if x.shape != (5,) or P.shape != (5, 5) or odom_pos.shape != (3,) or not (
                np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.isfinite(odom_pos))
                and math.isfinite(t0) and math.isfinite(scale) and scale >= 1.0):
            return "not a filter state (wrong shapes or non-finite numbers)"
        age = float(t) - t0
        if not 0.0 <= age <= max_age:
            return f"the state is {age:.1f} s old (restored only from 0 to {max_age:g} s)"
        self.x, self.P, self.t = x, 0.5 * (P + P.T), t0
        self.odom_pos, self.odom_pos_t = odom_pos, t0
        self.stats.noise_scale = min(scale, self.params.adapt_max_scale)
        self.predict_to(float(t))
        self.stats.state, self.stats.waiting_reason, self.stats.restored_age = "tracking", "", age
        self.stats.last_update = self.stats.last_yaw = self.stats.last_prism = float(t)
        return ""

    # ------------------------------------------------------------------ measurements while tracking

    def update_prism(self, t: float, p: np.ndarray, C: np.ndarray, q: np.ndarray) -> UpdateResult:
        """A prism position ``p`` (map, cov ``C``) seen at ``q`` in odom."""
        late = self.late(t)
        if late is None:
            return result("too_old")
        Rq = rot_z(self.x[0]) @ q
        H = np.zeros((3, 5))       # a late prism: ω turns map→odom about the robot, hardly moving the prism
        H[:, 0] = ez_cross(Rq)
        H[:, 1:4] = np.eye(3)
        nu = p - (Rq + self.x[1:4])
        R = C + H @ self.process_noise(late, q) @ H.T
        res = self.update(H, nu, R, self.params.gate_chi2_prism, t)
        if res.accepted:
            self.stats.prism_accepted += 1
            self.stats.last_prism = max(t, self.stats.last_prism)
        else:
            self.stats.prism_rejected += 1
        return res

    def update_yaw(self, sample: Yaw) -> UpdateResult:
        """A marker yaw; its noise scales the yaw random walk (:meth:`adapt`), it is counted per marker."""
        t = sample.t
        late = self.late(t)
        if late is None:
            return result("too_old")
        H = np.array([[1.0, 0.0, 0.0, 0.0, -late]])   # δψ at t = δψ now − ω · delay
        nu = np.array([float(wrap_angle(sample.offset - self.x[0] + self.x[4] * late))])
        R = np.array([[sample.sigma * sample.sigma]]) + H @ self.process_noise(late, self.odom_pos) @ H.T
        res = self.update(H, nu, R, self.params.gate_chi2_yaw, t)
        res = UpdateResult(res.status, res.chi2, float(nu[0]))
        self.adapt(res.chi2)
        self.count_yaw(res.accepted, sample.marker_id, t)
        return res

    def update_pose(self, sample: Yaw, pose: Pose, C: np.ndarray) -> Tuple[UpdateResult, float]:
        """A resection pose (its yaw ``sample``, position ``pose``, 4×4 ``C``): the result and, when gated,
        the yaw part's own χ² (NaN otherwise)."""
        t, q = pose.t, pose.q
        late = self.late(t)
        if late is None:
            return result("too_old"), float("nan")
        Rq = rot_z(self.x[0]) @ q
        H = np.zeros((4, 5))
        H[0, 0], H[0, 4] = 1.0, -late
        H[1:, 0] = ez_cross(Rq)
        H[1:, 1:4] = np.eye(3)
        nu = np.concatenate([[wrap_angle(sample.offset - self.x[0] + self.x[4] * late)],
                             pose.p - (Rq + self.x[1:4])])
        R = C + H @ self.process_noise(late, q) @ H.T
        res = self.update(H, nu, R, self.params.gate_chi2_pose, t)
        self.adapt(float(nu[0] ** 2 / (C[0, 0] + self.P[0, 0])))
        if res.accepted:
            self.stats.pose_accepted += 1
            self.count_yaw(True, sample.marker_id, t)
            return res, float("nan")
        self.stats.pose_rejected += 1
        self.count_yaw(False, sample.marker_id, t)
        return res, float(nu[0] ** 2 / (H[0] @ self.P @ H[0] + R[0, 0]))

    # ------------------------------------------------------------------ internals

    def note_odom(self, t: float, T: np.ndarray) -> None:
        if t >= self.odom_pos_t:
            self.odom_pos, self.odom_pos_t = T[:3, 3].copy(), t

    def count_yaw(self, accepted: bool, marker_id: Optional[int], t: float) -> None:
        counts = self.stats.accepted_by_marker if accepted else self.stats.rejected_by_marker
        if marker_id is not None:
            counts[marker_id] = counts.get(marker_id, 0) + 1
        if accepted:
            self.stats.yaw_accepted += 1
            self.stats.last_yaw = max(t, self.stats.last_yaw) if math.isfinite(self.stats.last_yaw) else t
        else:
            self.stats.yaw_rejected += 1

    def transition(self, dt: float, q_odom: np.ndarray) -> np.ndarray:
        """F (5×5) over ``dt`` s: δψ += ω dt, turning map→odom about the robot at ``q_odom`` (odom, m)."""
        F = np.eye(5)
        F[0, 4] = dt
        F[1:4, 4] = -dt * ez_cross(rot_z(self.x[0]) @ q_odom)
        return F

    def process_noise(self, dt: float, q_odom: np.ndarray) -> np.ndarray:
        """Q (5×5) over ``dt`` s: yaw random walk and integrated drift-rate walk about the robot at
        ``q_odom`` (odom, m), drift-rate walk, translation walk."""
        if dt <= 0:
            return np.zeros((5, 5))
        G = np.zeros((5, 2))                   # (δψ, ω) → state: δψ turns about the robot
        G[0, 0] = 1.0
        G[1:4, 0] = -ez_cross(rot_z(self.x[0]) @ q_odom)
        G[4, 1] = 1.0
        a2, w2 = self.params.yaw_random_walk ** 2 * self.stats.noise_scale, self.params.drift_rate_walk ** 2
        Q2 = np.array([[a2 * dt + w2 * dt ** 3 / 3.0, w2 * dt ** 2 / 2.0],
                       [w2 * dt ** 2 / 2.0, w2 * dt]])
        Q = G @ Q2 @ G.T
        Q[1:4, 1:4] += self.params.translation_random_walk ** 2 * dt * np.eye(3)
        return Q

    def predict_to(self, t: float) -> None:
        if t > self.t:
            dt = t - self.t
            F = self.transition(dt, self.odom_pos)
            self.x = F @ self.x
            self.x[0] = float(wrap_angle(self.x[0]))
            self.P = F @ self.P @ F.T + self.process_noise(dt, self.odom_pos)
            self.t = t

    def late(self, t: float) -> Optional[float]:
        """Advance the state to ``t`` if newer; return the delay (s) of a late measurement, None if too old."""
        if t >= self.t:
            self.predict_to(t)
            return 0.0
        if self.t - t > self.params.max_delay:
            self.stats.too_old += 1
            return None
        return self.t - t

    def update(self, H: np.ndarray, nu: np.ndarray, R: np.ndarray, gate: float, t: float) -> UpdateResult:
        S = H @ self.P @ H.T + R
        Sinv = np.linalg.inv(S)
        chi2 = float(nu @ Sinv @ nu)
        innovation = nu.copy() if len(nu) > 1 else float(nu[0])
        if chi2 > gate:
            return UpdateResult("gated", chi2, innovation)
        K = self.P @ H.T @ Sinv
        IKH = np.eye(len(self.x)) - K @ H
        self.x = self.x + K @ nu
        self.x[0] = float(wrap_angle(self.x[0]))
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T          # Joseph form
        self.P = 0.5 * (self.P + self.P.T)
        self.stats.last_update = t if not math.isfinite(self.stats.last_update) else max(t, self.stats.last_update)
        return UpdateResult("accepted", chi2, innovation)

    def adapt(self, nis: float) -> None:
        """Scale the yaw random walk by the innovations: up when they are larger than the covariance
        says (NIS > 1), down towards 1 when smaller."""
        p = self.params
        if p.adapt_rate > 0 and math.isfinite(nis):
            scale = self.stats.noise_scale * math.exp(p.adapt_rate * (min(nis, 25.0) - 1.0))
            self.stats.noise_scale = min(max(scale, 1.0), p.adapt_max_scale)

    def anchor(self, dpsi: float, var: float, p: np.ndarray, C: np.ndarray, q: np.ndarray,
               drift: float = 0.0, drift_var: Optional[float] = None) -> None:
        """State from δψ (rad, variance rad²) and a position p (m, cov C m²) seen at q in odom (m); the drift
        rate ``drift`` (rad/s, variance ``drift_var``; default 0 ± initial_drift_rate_sigma)."""
        Rq = rot_z(dpsi) @ q
        g = ez_cross(Rq)
        self.x = np.concatenate([[dpsi], p - Rq, [drift]])
        self.P = np.zeros((5, 5))
        self.P[0, 0] = var
        self.P[0, 1:4] = self.P[1:4, 0] = -g * var
        self.P[1:4, 1:4] = C + var * np.outer(g, g)
        self.P[4, 4] = self.params.initial_drift_rate_sigma ** 2 if drift_var is None else drift_var

    def reanchor_translation(self, t: float, p: np.ndarray, C: np.ndarray, q: np.ndarray) -> None:
        """The translation anchored to ``p`` (cov ``C``) seen at ``q`` at ``t``, keeping δψ, ω and their
        variances."""
        self.predict_to(t)
        self.anchor(float(self.x[0]), float(self.P[0, 0]), p, C, q, float(self.x[4]), float(self.P[4, 4]))

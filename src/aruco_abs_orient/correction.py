"""The map→odom correction (doc/design.md §8): a small Kalman filter with gating and start-up anywhere.

In, all time-stamped (s), each with the odometry pose ``odom_T_base`` (4×4) at its time (the caller
interpolates odometry): prism positions in map (:meth:`MapOdomFilter.add_prism`), absolute yaws of base_link
from marker bearings (:meth:`~MapOdomFilter.add_yaw`), resection poses when there is no prism
(:meth:`~MapOdomFilter.add_pose`). Out: ``map_T_odom`` (4×4) with its covariance over (δψ, x, y, z) at any
time after the start (:meth:`~MapOdomFilter.map_T_odom`), an :class:`UpdateResult` per measurement, the
counters in ``stats`` and a restartable :meth:`~MapOdomFilter.snapshot`. Composed of the Kalman core
(:mod:`.filter_core`), the start-up (:mod:`.filter_startup`) and the recovery (:mod:`.filter_recovery`);
:class:`FilterParams` is its tuning. numpy only, Python 3.8 compatible, no ROS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from .filter_core import (
    CorrectionError,
    FilterStats,
    KalmanCore,
    NotInitialisedError,
    Pose,
    Prism,
    UpdateResult,
    Yaw,
    checked_pose,
    result,
)
from .filter_recovery import Recovery
from .filter_startup import Startup
from .paramspec import Params, param
from .transforms import transform_points, wrap_angle, yaw_of

__all__ = [
    "CorrectionError",
    "NotInitialisedError",
    "FilterParams",
    "FilterStats",
    "UpdateResult",
    "MapOdomFilter",
]


@dataclass
class FilterParams(Params):
    """Tuning of :class:`MapOdomFilter` (cfg/params.yaml's ``filter`` section; flat scalars, the live ones in
    cfg/AbsOrient.cfg). The gates are χ² at p = 0.001 of 1 (a yaw), 3 (a prism position) and 4 (a resection's
    yaw and position) degrees of freedom."""

    error = CorrectionError

    yaw_random_walk: float = param(math.radians(0.05), "VO yaw wander beyond its drift rate", "rad/√s", 0.0, 0.1)
    drift_rate_walk: float = param(math.radians(0.1) / 60.0, "how fast the VO's yaw drift rate changes",
                                   "rad/s/√s", 0.0, 0.01)
    initial_drift_rate_sigma: float = param(math.radians(10.0) / 60.0, "prior 1-σ of the VO's yaw drift rate",
                                            "rad/s", 0.0, 0.1)
    translation_random_walk: float = param(0.01, "VO position drift", "m/√s", 0.0, 1.0)
    gate_chi2_yaw: float = param(10.83, "gate of a marker yaw", "χ², 1 dof", 0.01, 1000.0)
    gate_chi2_prism: float = param(16.27, "gate of a prism position", "χ², 3 dof", 0.01, 1000.0)
    gate_chi2_pose: float = param(18.47, "gate of a resection's yaw and position", "χ², 4 dof", above=0.0)
    standstill_duration: float = param(2.0, "window of the start-up yaws (and of a standstill, when there is one)",
                                       "s", 0.01, 60.0)
    standstill_odom_tolerance: float = param(0.01, "odometry displacement within a standstill", "m", 0.0)
    standstill_yaw_tolerance: float = param(math.radians(0.5), "odometry yaw change within a standstill", "rad",
                                            0.0)
    standstill_prism_tolerance: float = param(0.01, "prism motion within a standstill (first vs second half mean)",
                                              "m", 0.0)
    require_standstill: bool = param(False, "start only at a standstill (default: start anywhere)")
    init_min_yaws: int = param(3, "consistent marker yaws needed to (re)initialise", "", 1, 100)
    init_min_markers: int = param(2, "different markers among them to start while moving", "", 1, 100)
    lockout_window: float = param(1.0, "gated yaws that agree with each other over this long reset the filter to "
                                  "their consensus", "s", 0.1, 60.0)
    lockout_min_yaws: int = param(3, "gated yaws that must agree for that", "", 1)
    adapt_rate: float = param(0.005, "log-scale step per yaw of the innovation-scaled yaw noise (0: off)", "", 0.0,
                              1.0)
    adapt_max_scale: float = param(1000.0, "largest factor on the yaw random walk's variance", "", 1.0)
    init_yaw_floor: float = param(math.radians(0.5), "consensus tolerance floor of the start-up yaws", "rad", 0.0)
    reinit_after: float = param(30.0, "without an accepted yaw for this long the filter re-initialises", "s", 0.1,
                                3600.0)
    max_delay: float = param(1.0, "oldest late measurement still applied", "s", 0.0, 10.0)


class MapOdomFilter:
    """map→odom from prism positions and absolute marker yaws (doc/design.md §8).

    Args:
        prism_in_base: prism position in base_link (3,), metres, or the static transform
            ``base_T_prism`` (4×4) whose translation it is (tf base_link→prism).
        params: tuning, :class:`FilterParams` (defaults documented there).
    """

    def __init__(self, prism_in_base, params: Optional[FilterParams] = None):
        params = params if params is not None else FilterParams()
        params.validate()
        t = np.asarray(prism_in_base, dtype=float)
        if t.shape == (4, 4):
            t = t[:3, 3]
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise CorrectionError(f"prism_in_base: expected 3 finite numbers (m), got {prism_in_base!r}")
        self.prism_in_base = t
        self._core = KalmanCore(params)
        self._startup = Startup(self._core)
        self._recovery = Recovery(self._core, self._startup)

    def update_params(self, params: FilterParams) -> None:
        """New tuning (dynamic_reconfigure), effective from the next measurement; the state is kept."""
        params.validate()
        self._core.params = params

    # ------------------------------------------------------------------ queries

    @property
    def params(self) -> FilterParams:
        return self._core.params

    @property
    def stats(self) -> FilterStats:
        return self._core.stats

    @property
    def x(self) -> np.ndarray:
        """The state (δψ rad, tx, ty, tz m, ω rad/s), not a copy."""
        return self._core.x

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self._core.x = value

    @property
    def P(self) -> np.ndarray:
        """The state's covariance (5×5), not a copy."""
        return self._core.P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._core.P = value

    @property
    def t(self) -> float:
        """Time of the state (s; −inf before the start)."""
        return self._core.t

    @property
    def initialised(self) -> bool:
        return self._core.initialised

    @property
    def state(self) -> Tuple[float, np.ndarray, np.ndarray]:
        """(time s, state (δψ rad, tx, ty, tz m, ω rad/s), covariance 5×5)."""
        return self.t, self.x.copy(), self.P.copy()

    def map_T_odom(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """map→odom (4×4) and its covariance (4×4 over δψ rad, x, y, z m) predicted to time ``t`` (s).

        Times before the state's time return the current estimate (the filter does not go back).
        Raises NotInitialisedError before initialisation.
        """
        if not self.initialised:
            raise NotInitialisedError(f"map→odom is not initialised yet: {self.stats.waiting_reason}")
        return self._core.predicted(t)

    def snapshot(self) -> Optional[Dict[str, object]]:
        """The state as plain numbers (JSON-ready), None before initialisation: time ``t`` (s), ``x``,
        ``P``, the odometry position it turns about and the yaw noise scale."""
        return self._core.snapshot() if self.initialised else None

    def restore(self, snap: Dict[str, object], t: float, max_age: float) -> str:
        """Start from a :meth:`snapshot` taken at most ``max_age`` s before ``t`` (s): the state predicted to
        ``t`` (its covariance grown by the process noise). Returns '' when restored, else why not. Markers that
        disagree with the restored state take over through the lock-out recovery."""
        if self.initialised:
            return "the filter is already running"
        return self._core.restore(snap, t, max_age)

    # ------------------------------------------------------------------ inputs

    def add_prism(self, t: float, p_map, cov, odom_T_base) -> UpdateResult:
        """Prism position ``p_map`` (3,) in map (m) with covariance ``cov`` (3×3 m² or a σ in m) at
        time ``t`` (s); ``odom_T_base`` the odometry pose (4×4) at ``t``."""
        p = np.asarray(p_map, dtype=float)
        if p.shape != (3,):
            raise CorrectionError(f"add_prism: p_map: expected 3 numbers (m), got shape {p.shape}")
        C = np.asarray(cov, dtype=float)
        C = C * C * np.eye(3) if C.ndim == 0 else C
        if C.shape != (3, 3):
            raise CorrectionError(f"add_prism: cov: expected a 3×3 covariance (m²) or a σ (m), got {C.shape}")
        T = checked_pose(odom_T_base)
        t = float(t)
        if (T is None or not math.isfinite(t) or not np.all(np.isfinite(p)) or not np.all(np.isfinite(C))
                or np.linalg.eigvalsh(C)[0] <= 0):
            return self._invalid()
        q = transform_points(T, self.prism_in_base)
        self._core.note_odom(t, T)
        if not self.initialised:
            self._startup.prisms.append(Prism(t, p, C, q))
            return self._try_initialise(t)
        if t - self.stats.last_prism > self.params.reinit_after:
            return self._recovery.reanchor_prism(t, p, C, q)
        return self._core.update_prism(t, p, C, q)

    def add_yaw(self, t: float, yaw_abs: float, sigma: float, odom_T_base,
                marker_id: Optional[int] = None, sources: Sequence[int] = ()) -> UpdateResult:
        """Absolute yaw of base_link ``yaw_abs`` (rad) with 1-σ ``sigma`` (rad) at time ``t`` (s), e.g.
        from :func:`solver.yaw_from_marker`; ``odom_T_base`` the odometry pose (4×4) at ``t``;
        ``marker_id`` for the per-marker statistics and the start-up consensus; ``sources``: the ids of
        the markers behind a yaw fused from several (how many different markers agree)."""
        T = checked_pose(odom_T_base)
        t, yaw_abs, sigma = float(t), float(yaw_abs), float(sigma)
        if T is None or not (math.isfinite(t) and math.isfinite(yaw_abs) and math.isfinite(sigma)) or sigma <= 0:
            return self._invalid()
        self._core.note_odom(t, T)
        odom_yaw = float(yaw_of(T[:3, :3]))
        ids = tuple(int(i) for i in sources) or ((int(marker_id),) if marker_id is not None else ())
        sample = Yaw(t, float(wrap_angle(yaw_abs - odom_yaw)), sigma, marker_id, odom_yaw, ids)
        if self._yaw_gap(t):
            self._startup.yaws = []
        if self.stats.state != "tracking":
            self._startup.yaws.append(sample)
            return self._try_initialise(t)
        res = self._core.update_yaw(sample)
        if res.status == "accepted":
            self._recovery.gated = []
        elif res.status == "gated" and self._recovery.from_lockout(sample):
            return result("initialised", res.chi2, res.innovation)
        return res

    def add_pose(self, t: float, position, yaw_abs: float, cov, odom_T_base, sources: Sequence[int] = ()
                 ) -> UpdateResult:
        """Position ``position`` (3,) of base_link in map (m) and its yaw ``yaw_abs`` (rad) from a resection on
        the markers, with ``cov`` (4×4 over yaw rad, x, y, z m; rad², m²) at time ``t`` (s); ``odom_T_base``
        the odometry pose (4×4) then; ``sources`` the ids of the markers behind it."""
        T = checked_pose(odom_T_base)
        p = np.asarray(position, dtype=float)
        C = np.asarray(cov, dtype=float)
        if p.shape != (3,) or C.shape != (4, 4):
            raise CorrectionError(f"add_pose: expected a position (3,) m and a 4×4 covariance, got {p.shape}, "
                                  f"{C.shape}")
        t, yaw_abs = float(t), float(yaw_abs)
        if (T is None or not (math.isfinite(t) and math.isfinite(yaw_abs)) or not np.all(np.isfinite(p))
                or not np.all(np.isfinite(C)) or np.linalg.eigvalsh(0.5 * (C + C.T))[0] <= 0):
            return self._invalid()
        self._core.note_odom(t, T)
        odom_yaw = float(yaw_of(T[:3, :3]))
        ids = tuple(int(i) for i in sources)
        sample = Yaw(t, float(wrap_angle(yaw_abs - odom_yaw)), math.sqrt(C[0, 0]), ids[0] if ids else None,
                     odom_yaw, ids)
        pose = Pose(t, p, C[1:, 1:], T[:3, 3].copy())
        if self._yaw_gap(t):
            self._recovery.poses = []
        if self.stats.state != "tracking":
            return self._recovery.initialise_from_poses(t, sample, pose)
        res, yaw_chi2 = self._core.update_pose(sample, pose, C)
        if res.status == "accepted":
            self._recovery.gated, self._recovery.gated_poses = [], []
        elif res.status == "gated":
            if yaw_chi2 > self.params.gate_chi2_yaw:      # the yaw is off: evidence of a filter that ran away
                recovered = self._recovery.from_lockout(sample)
            else:                                          # the position is off (no prism)
                recovered = self._recovery.reanchor_from_poses(pose)
            if recovered:
                return result("initialised", res.chi2, res.innovation)
        return res

    # ------------------------------------------------------------------ internals

    def _invalid(self) -> UpdateResult:
        self.stats.invalid += 1
        return result("invalid")

    def _yaw_gap(self, t: float) -> bool:
        """Tracking but no yaw accepted for ``reinit_after`` s before ``t``: the filter re-initialises."""
        if self.stats.state == "tracking" and t - self.stats.last_yaw > self.params.reinit_after:
            self.stats.state = "reinitialising"
            return True
        return False

    def _try_initialise(self, t: float) -> UpdateResult:
        self._startup.trim(t)
        if self.stats.state == "reinitialising":
            return self._recovery.reinitialise(t)
        res = self._startup.try_start(t)
        if res.status == "initialised":
            self._recovery.gated = []
        return res

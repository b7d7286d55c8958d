"""The map→odom correction (doc/design.md §8): a small Kalman filter with gating and initialisation.

State ``x = (δψ, tx, ty, tz, ω)`` with ``map_T_odom = [Rz(δψ), t]`` (radians, metres) and ω = dδψ/dt
(rad/s), the odometry's yaw drift rate: visual odometry is smooth but its yaw drifts, mostly at a
slowly changing rate (a gyro-like bias: the demo's 4°/min), so δψ is integrated from ω plus a random
walk, and between marker sightings map→odom keeps turning with the drift instead of freezing (a 2 s
gap at 4°/min would otherwise cost 0.13°); the translation follows from the total-station prism.
Inputs, all time-stamped in seconds, each with the odometry pose ``odom_T_base`` (4×4) at the
measurement time (the caller interpolates odometry):

* ``add_prism(t, p_map, cov, odom_T_base)`` — prism position in map (m, 3×3 m²):
  ``p = Rz(δψ)·q + t`` with ``q`` the prism in odom (``odom_T_base · prism_in_base``).
* ``add_yaw(t, yaw_abs, sigma, odom_T_base, marker_id)`` — absolute yaw of base_link (rad)
  from :mod:`solver`: a direct measurement of ``δψ = ψ_abs − ψ_odom`` (exact: map→odom is a
  rotation about z, so yaws add).
* ``add_pose(t, position, yaw_abs, cov, odom_T_base)`` — base_link position (m) and yaw (rad) in map from
  a resection on the markers (no prism: markers-only mode, or a prism dropout), covariance 4×4 over
  (yaw, x, y, z): ``δψ = ψ_abs − ψ_odom`` and ``p = Rz(δψ)·q_base + t``, gated with ``gate_chi2_pose``
  (4 dof). Without a prism the filter starts from ``init_min_yaws`` such poses that agree (their yaws by
  :func:`solver.yaw_consensus`, their translations within ``gate_chi2_pose``). A gated pose whose yaw is off
  counts towards the lock-out recovery below; one whose yaw agrees but whose position is off, towards
  re-anchoring the translation (poses of ``lockout_window`` s that agree with each other).

Model details:

* Process model: δψ changes by ω·dt plus a random walk (``yaw_random_walk`` rad/√s), ω by its own
  random walk (``drift_rate_walk`` rad/s/√s; it starts at 0 ± ``initial_drift_rate_sigma``); every
  change of δψ turns map→odom about the robot's **current** position (VO heading drift does not
  teleport the robot: the translation moves with it, ``dt = −dδψ · e_z × Rz(δψ) q``); the translation
  has its own random walk (``translation_random_walk`` m/√s) for VO position drift. The odometry
  itself is taken as exact over the short term. ``drift_rate_walk = initial_drift_rate_sigma = 0``
  is the plain random walk of δψ.
* Start-up, anywhere: measurements are buffered over the last ``standstill_duration`` s. The filter
  starts as soon as at least ``init_min_yaws`` of the buffered marker yaws agree with each other
  (:func:`solver.yaw_consensus`; false ids and outliers left out). While moving they must come from
  at least ``init_min_markers`` different markers (one false or moved marker cannot start it), and the
  translation is tied to the latest prism. A **standstill**, when there is one (odometry moved less
  than ``standstill_odom_tolerance`` m / ``standstill_yaw_tolerance`` rad and the means of the first
  and second half of the prism positions differ by less than ``standstill_prism_tolerance`` m), makes
  the start tighter: one marker suffices and the prism is averaged over it. While moving, one marker
  also suffices when the prism track confirms it: the prism's displacement in map and in odom gives
  δψ independently of the markers (to about σ_prism / distance over the window). ``require_standstill``
  restores the old behaviour (start only at a standstill). δψ is the consensus, carried to the start
  time with the drift rate fitted to the window's yaws (shrunk towards 0 by its prior); yaws of one
  marker share its bias, so each marker's mean counts with its own σ (not σ/√n): conservative.
  While the filter waits, ``stats.waiting_reason`` says why (no prism, no marker yaws, too few,
  too few markers, markers disagree, no standstill).
* Tracking: EKF updates with χ² innovation gating (``gate_chi2_yaw``, 1 dof; ``gate_chi2_prism``,
  3 dof); rejected measurements are counted (per marker id too) and leave the state untouched.
  Without markers the filter coasts: the covariance grows with the process noise.
* Honest covariance: an odometry whose yaw wanders more than ``yaw_random_walk`` says so through the
  yaw innovations. Their normalised squares (NIS, expected 1) scale the yaw random walk's variance:
  ``log scale += adapt_rate · (min(NIS, 25) − 1)`` per yaw, within [1, ``adapt_max_scale``]
  (``stats.noise_scale``), so σ grows with a bad odometry instead of the gate shutting markers out.
* No lock-out: a filter that ran away gates every marker. When the gated yaws of the last
  ``lockout_window`` s (at least ``lockout_min_yaws`` over half that window, from at least
  ``init_min_markers`` markers) agree with each other, they are evidence that the filter is wrong,
  not the markers: δψ and the drift rate are reset to their consensus (the map position is kept),
  counted in ``stats.lockout_recoveries``. A single marker that disagrees (moved, false id) cannot
  do this.
* Re-initialisation: when no yaw has been accepted for ``reinit_after`` s, yaws are collected
  again as at start-up (no standstill needed) and δψ is reset to their consensus while the robot's
  map position (tracked by the prism) is kept. Likewise, when no prism has been accepted for
  ``reinit_after`` s (a gap of minutes, a station re-set-up, a VO position jump), two consecutive
  prisms that agree re-anchor the translation, keeping δψ.
* Restart: :meth:`snapshot` gives the state (a small dict of numbers, for a state file) and
  :meth:`restore` starts a new filter from one that is at most ``max_age`` s old, its covariance grown
  by the process noise over that age (a node respawned while the robot drives publishes map→odom at
  once; markers that disagree with the restored state take over through the lock-out recovery).
* Out-of-order / late measurements: a measurement older than the filter time by at most
  ``max_delay`` s is applied to the current state with its noise inflated by the process noise
  accumulated over the delay (exact for a random walk up to the correlation with the updates in
  between); older ones are rejected and counted as ``too_old``. The filter never goes back in time.

numpy only, Python 3.8 compatible, no ROS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .errors import ConfigurationError
from .paramspec import Params, param
from .solver import yaw_consensus
from .transforms import make_T, rot_z, transform_points, wrap_angle, yaw_of

__all__ = [
    "CorrectionError",
    "NotInitialisedError",
    "FilterParams",
    "FilterStats",
    "UpdateResult",
    "MapOdomFilter",
]



def _ez_cross(v: np.ndarray) -> np.ndarray:
    """e_z × v: the derivative of Rz(δψ)·q w.r.t. δψ when v = Rz(δψ)·q."""
    return np.array([-v[1], v[0], 0.0])


class CorrectionError(ConfigurationError):
    """Malformed input to the map→odom filter (wrong shapes, bad parameters)."""


class NotInitialisedError(CorrectionError):
    """map→odom was asked for before the filter was initialised."""


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


class _Yaw(NamedTuple):
    t: float
    offset: float            # ψ_abs − ψ_odom (rad)
    sigma: float
    marker_id: Optional[int]
    odom_yaw: float
    sources: Tuple[int, ...]  # ids of the markers behind it (empty: unknown)


class _Pose(NamedTuple):
    t: float
    p: np.ndarray            # base_link in map (m)
    cov: np.ndarray          # 3×3 m²
    q: np.ndarray            # base_link in odom (m)


class _Prism(NamedTuple):
    t: float
    p: np.ndarray            # map (m)
    cov: np.ndarray
    q: np.ndarray            # prism in odom (m)


def _pose(odom_T_base) -> Optional[np.ndarray]:
    T = np.asarray(odom_T_base, dtype=float)
    if T.shape != (4, 4):
        raise CorrectionError(f"odom_T_base: expected a 4×4 transform, got shape {T.shape}")
    return T if np.all(np.isfinite(T)) else None


class MapOdomFilter:
    """map→odom from prism positions and absolute marker yaws (see the module docstring).

    Args:
        prism_in_base: prism position in base_link (3,), metres, or the static transform
            ``base_T_prism`` (4×4) whose translation it is (tf base_link→prism).
        params: tuning, :class:`FilterParams` (defaults documented there).
    """

    def __init__(self, prism_in_base, params: Optional[FilterParams] = None):
        self.params = params if params is not None else FilterParams()
        self.params.validate()
        t = np.asarray(prism_in_base, dtype=float)
        if t.shape == (4, 4):
            t = t[:3, 3]
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise CorrectionError(f"prism_in_base: expected 3 finite numbers (m), got {prism_in_base!r}")
        self.prism_in_base = t
        self.stats = FilterStats()
        self.x = np.zeros(5)
        self.P = np.zeros((5, 5))
        self.t = float("-inf")              # time of the state (s)
        self._odom_pos = np.zeros(3)        # latest base_link position in odom (for the process noise)
        self._odom_pos_t = float("-inf")
        self._yaws: List[_Yaw] = []
        self._prisms: List[_Prism] = []
        self._gated: List[_Yaw] = []        # recent gated yaws (lock-out detection)
        self._poses: List[Tuple[_Yaw, _Pose]] = []   # resection poses buffered for a start without prism
        self._gated_poses: List[_Pose] = []          # recent poses gated for their position (re-anchoring)

    def update_params(self, params: FilterParams) -> None:
        """New tuning (dynamic_reconfigure), effective from the next measurement; the state is kept."""
        params.validate()
        self.params = params

    # ------------------------------------------------------------------ queries

    @property
    def initialised(self) -> bool:
        return self.stats.state != "waiting"

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
        dt = max(0.0, float(t) - self.t)
        F = self._transition(dt, self._odom_pos)
        x = F @ self.x
        P = F @ self.P @ F.T + self._process_noise(dt, self._odom_pos)
        return make_T(rot_z(x[0]), x[1:4]), P[:4, :4]

    def snapshot(self) -> Optional[Dict[str, object]]:
        """The state as plain numbers (JSON-ready), None before initialisation: time ``t`` (s), ``x``,
        ``P``, the odometry position it turns about and the yaw noise scale."""
        if not self.initialised:
            return None
        return {"t": self.t, "x": self.x.tolist(), "P": self.P.tolist(), "odom_pos": self._odom_pos.tolist(),
                "noise_scale": self.stats.noise_scale}

    def restore(self, snap: Dict[str, object], t: float, max_age: float) -> str:
        """Start from a :meth:`snapshot` taken at most ``max_age`` s before ``t`` (s): the state predicted to
        ``t`` (its covariance grown by the process noise). Returns '' when restored, else why not."""
        if self.initialised:
            return "the filter is already running"
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
        self._odom_pos, self._odom_pos_t = odom_pos, t0
        self.stats.noise_scale = min(scale, self.params.adapt_max_scale)
        self._predict_to(float(t))
        self.stats.state, self.stats.waiting_reason, self.stats.restored_age = "tracking", "", age
        self.stats.last_update = self.stats.last_yaw = self.stats.last_prism = float(t)
        return ""

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
        T = _pose(odom_T_base)
        t = float(t)
        if (T is None or not math.isfinite(t) or not np.all(np.isfinite(p)) or not np.all(np.isfinite(C))
                or np.linalg.eigvalsh(C)[0] <= 0):
            self.stats.invalid += 1
            return UpdateResult("invalid", float("nan"), float("nan"))
        q = transform_points(T, self.prism_in_base)
        self._note_odom(t, T)
        if not self.initialised:
            self._prisms.append(_Prism(t, p, C, q))
            return self._try_initialise(t)
        if t - self.stats.last_prism > self.params.reinit_after:
            return self._reanchor(t, p, C, q)
        late = self._late(t)
        if late is None:
            return UpdateResult("too_old", float("nan"), float("nan"))
        Rq = rot_z(self.x[0]) @ q
        H = np.zeros((3, 5))       # a late prism: ω turns map→odom about the robot, hardly moving the prism
        H[:, 0] = _ez_cross(Rq)
        H[:, 1:4] = np.eye(3)
        nu = p - (Rq + self.x[1:4])
        R = C + H @ self._process_noise(late, q) @ H.T
        res = self._update(H, nu, R, self.params.gate_chi2_prism, t)
        if res.accepted:
            self.stats.prism_accepted += 1
            self.stats.last_prism = max(t, self.stats.last_prism)
        else:
            self.stats.prism_rejected += 1
        return res

    def add_yaw(self, t: float, yaw_abs: float, sigma: float, odom_T_base,
                marker_id: Optional[int] = None, sources: Sequence[int] = ()) -> UpdateResult:
        """Absolute yaw of base_link ``yaw_abs`` (rad) with 1-σ ``sigma`` (rad) at time ``t`` (s), e.g.
        from :func:`solver.yaw_from_marker`; ``odom_T_base`` the odometry pose (4×4) at ``t``;
        ``marker_id`` for the per-marker statistics and the start-up consensus; ``sources``: the ids of
        the markers behind a yaw fused from several (how many different markers agree)."""
        T = _pose(odom_T_base)
        t, yaw_abs, sigma = float(t), float(yaw_abs), float(sigma)
        if T is None or not (math.isfinite(t) and math.isfinite(yaw_abs) and math.isfinite(sigma)) or sigma <= 0:
            self.stats.invalid += 1
            return UpdateResult("invalid", float("nan"), float("nan"))
        self._note_odom(t, T)
        odom_yaw = float(yaw_of(T[:3, :3]))
        ids = tuple(int(i) for i in sources) or ((int(marker_id),) if marker_id is not None else ())
        sample = _Yaw(t, float(wrap_angle(yaw_abs - odom_yaw)), sigma, marker_id, odom_yaw, ids)
        if self.stats.state == "tracking" and t - self.stats.last_yaw > self.params.reinit_after:
            self.stats.state = "reinitialising"
            self._yaws = []
        if self.stats.state != "tracking":
            self._yaws.append(sample)
            return self._try_initialise(t)
        late = self._late(t)
        if late is None:
            return UpdateResult("too_old", float("nan"), float("nan"))
        H = np.array([[1.0, 0.0, 0.0, 0.0, -late]])   # δψ at t = δψ now − ω · delay
        nu = np.array([float(wrap_angle(sample.offset - self.x[0] + self.x[4] * late))])
        R = np.array([[sigma * sigma]]) + H @ self._process_noise(late, self._odom_pos) @ H.T
        res = self._update(H, nu, R, self.params.gate_chi2_yaw, t)
        res = UpdateResult(res.status, res.chi2, float(nu[0]))
        self._adapt(res.chi2)
        self._count_yaw(res.accepted, marker_id, t)
        if res.accepted:
            self._gated = []
        elif self._recover_from_lockout(sample):
            return UpdateResult("initialised", res.chi2, res.innovation)
        return res

    def add_pose(self, t: float, position, yaw_abs: float, cov, odom_T_base, sources: Sequence[int] = ()
                 ) -> UpdateResult:
        """Position ``position`` (3,) of base_link in map (m) and its yaw ``yaw_abs`` (rad) from a resection on
        the markers, with ``cov`` (4×4 over yaw rad, x, y, z m; rad², m²) at time ``t`` (s); ``odom_T_base``
        the odometry pose (4×4) then; ``sources`` the ids of the markers behind it."""
        T = _pose(odom_T_base)
        p = np.asarray(position, dtype=float)
        C = np.asarray(cov, dtype=float)
        if p.shape != (3,) or C.shape != (4, 4):
            raise CorrectionError(f"add_pose: expected a position (3,) m and a 4×4 covariance, got {p.shape}, "
                                  f"{C.shape}")
        t, yaw_abs = float(t), float(yaw_abs)
        if (T is None or not (math.isfinite(t) and math.isfinite(yaw_abs)) or not np.all(np.isfinite(p))
                or not np.all(np.isfinite(C)) or np.linalg.eigvalsh(0.5 * (C + C.T))[0] <= 0):
            self.stats.invalid += 1
            return UpdateResult("invalid", float("nan"), float("nan"))
        self._note_odom(t, T)
        q = T[:3, 3].copy()
        odom_yaw = float(yaw_of(T[:3, :3]))
        ids = tuple(int(i) for i in sources)
        sample = _Yaw(t, float(wrap_angle(yaw_abs - odom_yaw)), math.sqrt(C[0, 0]), ids[0] if ids else None,
                      odom_yaw, ids)
        if self.stats.state == "tracking" and t - self.stats.last_yaw > self.params.reinit_after:
            self.stats.state = "reinitialising"
            self._poses = []
        if self.stats.state != "tracking":
            return self._initialise_from_poses(t, sample, _Pose(t, p, C[1:, 1:], q))
        late = self._late(t)
        if late is None:
            return UpdateResult("too_old", float("nan"), float("nan"))
        Rq = rot_z(self.x[0]) @ q
        H = np.zeros((4, 5))
        H[0, 0], H[0, 4] = 1.0, -late
        H[1:, 0] = _ez_cross(Rq)
        H[1:, 1:4] = np.eye(3)
        nu = np.concatenate([[wrap_angle(sample.offset - self.x[0] + self.x[4] * late)], p - (Rq + self.x[1:4])])
        R = C + H @ self._process_noise(late, q) @ H.T
        res = self._update(H, nu, R, self.params.gate_chi2_pose, t)
        self._adapt(float(nu[0] ** 2 / (C[0, 0] + self.P[0, 0])))
        if res.accepted:
            self.stats.pose_accepted += 1
            self._count_yaw(True, sample.marker_id, t)
            self._gated, self._gated_poses = [], []
        else:
            self.stats.pose_rejected += 1
            self._count_yaw(False, sample.marker_id, t)
            yaw_chi2 = float(nu[0] ** 2 / (H[0] @ self.P @ H[0] + R[0, 0]))
            if yaw_chi2 > self.params.gate_chi2_yaw:      # the yaw is off: evidence of a filter that ran away
                if self._recover_from_lockout(sample):
                    return UpdateResult("initialised", res.chi2, res.innovation)
            elif self._reanchor_from_poses(_Pose(t, p, C[1:, 1:], q)):   # the position is off (no prism)
                return UpdateResult("initialised", res.chi2, res.innovation)
        return res

    def _reanchor_from_poses(self, pose: _Pose) -> bool:
        """Resection poses whose yaw agrees but whose position is gated: when those of the last
        ``lockout_window`` s (≥ ``lockout_min_yaws``, over half the window) agree with each other, the
        filter's position is what is wrong (a prism-less run that drifted or was moved): re-anchor the
        translation to the newest, keeping δψ and ω."""
        p = self.params
        self._gated_poses = [x for x in self._gated_poses if x.t >= pose.t - p.lockout_window] + [pose]
        first = self._gated_poses[0]
        if len(self._gated_poses) < p.lockout_min_yaws or pose.t - first.t < 0.5 * p.lockout_window:
            return False
        Rz = rot_z(self.x[0])
        trans = np.array([x.p - Rz @ x.q for x in self._gated_poses])
        d = trans - trans[-1]
        if any(float(di @ np.linalg.solve(x.cov + pose.cov, di)) > p.gate_chi2_prism
               for di, x in zip(d, self._gated_poses)):
            return False
        self._predict_to(pose.t)
        self._anchor(float(self.x[0]), float(self.P[0, 0]), pose.p, pose.cov, pose.q, float(self.x[4]),
                     float(self.P[4, 4]))
        self._gated_poses = []
        self.stats.pose_reanchors += 1
        return True

    def _initialise_from_poses(self, t: float, sample: _Yaw, pose: _Pose) -> UpdateResult:
        """Start (or re-start) without a prism: ``init_min_yaws`` buffered resection poses whose yaws agree and
        whose translations map→odom agree (χ² ``gate_chi2_pose`` on the position part)."""
        p = self.params
        self._poses = [x for x in self._poses if x[0].t >= t - max(p.standstill_duration, p.max_delay)]
        self._poses.append((sample, pose))
        cons, why = self._consensus([y for y, _ in self._poses], p.init_min_yaws, p.init_min_markers)
        if cons is None:
            self.stats.waiting_reason = "resection poses: " + why
            return UpdateResult("buffered", float("nan"), float("nan"))
        dpsi, var, used = cons
        members = [ps for y, ps in self._poses if any(y is u for u in used)]
        trans = np.array([m.p - rot_z(dpsi) @ m.q for m in members])
        mid = np.median(trans, axis=0)
        agree = [m for m, tr in zip(members, trans)
                 if float((tr - mid) @ np.linalg.solve(m.cov + 1e-6 * np.eye(3), tr - mid)) <= p.gate_chi2_pose]
        if len(agree) < p.init_min_yaws:
            self.stats.waiting_reason = (f"resection poses: {len(agree)} of {len(members)} agree in position, "
                                         f"{p.init_min_yaws} needed")
            return UpdateResult("buffered", float("nan"), float("nan"))
        last = max(agree, key=lambda m: m.t)
        keep_position = self.stats.state == "reinitialising"
        self.t = max(self.t, last.t)
        self._anchor(dpsi, var, last.p, last.cov, last.q)
        self.stats.state, self.stats.waiting_reason = "tracking", ""
        self.stats.last_update = self.t
        self.stats.pose_accepted += len(agree)
        for y in used:
            self._count_yaw(True, y.marker_id, y.t)
        if keep_position:
            self.stats.reinitialisations += 1
        self._poses, self._yaws, self._gated = [], [], []
        return UpdateResult("initialised", float("nan"), float("nan"))

    # ------------------------------------------------------------------ internals

    def _note_odom(self, t: float, T: np.ndarray) -> None:
        if t >= self._odom_pos_t:
            self._odom_pos, self._odom_pos_t = T[:3, 3].copy(), t

    def _count_yaw(self, accepted: bool, marker_id: Optional[int], t: float) -> None:
        counts = self.stats.accepted_by_marker if accepted else self.stats.rejected_by_marker
        if marker_id is not None:
            counts[marker_id] = counts.get(marker_id, 0) + 1
        if accepted:
            self.stats.yaw_accepted += 1
            self.stats.last_yaw = max(t, self.stats.last_yaw) if math.isfinite(self.stats.last_yaw) else t
        else:
            self.stats.yaw_rejected += 1

    def _transition(self, dt: float, q_odom: np.ndarray) -> np.ndarray:
        """F (5×5) over ``dt`` s: δψ += ω dt, turning map→odom about the robot at ``q_odom`` (odom, m)."""
        F = np.eye(5)
        F[0, 4] = dt
        F[1:4, 4] = -dt * _ez_cross(rot_z(self.x[0]) @ q_odom)
        return F

    def _process_noise(self, dt: float, q_odom: np.ndarray) -> np.ndarray:
        """Q (5×5) over ``dt`` s: yaw random walk and integrated drift-rate walk about the robot at
        ``q_odom`` (odom, m), drift-rate walk, translation walk."""
        if dt <= 0:
            return np.zeros((5, 5))
        G = np.zeros((5, 2))                   # (δψ, ω) → state: δψ turns about the robot
        G[0, 0] = 1.0
        G[1:4, 0] = -_ez_cross(rot_z(self.x[0]) @ q_odom)
        G[4, 1] = 1.0
        a2, w2 = self.params.yaw_random_walk ** 2 * self.stats.noise_scale, self.params.drift_rate_walk ** 2
        Q2 = np.array([[a2 * dt + w2 * dt ** 3 / 3.0, w2 * dt ** 2 / 2.0],
                       [w2 * dt ** 2 / 2.0, w2 * dt]])
        Q = G @ Q2 @ G.T
        Q[1:4, 1:4] += self.params.translation_random_walk ** 2 * dt * np.eye(3)
        return Q

    def _predict_to(self, t: float) -> None:
        if t > self.t:
            dt = t - self.t
            F = self._transition(dt, self._odom_pos)
            self.x = F @ self.x
            self.x[0] = float(wrap_angle(self.x[0]))
            self.P = F @ self.P @ F.T + self._process_noise(dt, self._odom_pos)
            self.t = t

    def _late(self, t: float) -> Optional[float]:
        """Advance the state to ``t`` if newer; return the delay (s) of a late measurement, None if too old."""
        if t >= self.t:
            self._predict_to(t)
            return 0.0
        if self.t - t > self.params.max_delay:
            self.stats.too_old += 1
            return None
        return self.t - t

    def _update(self, H: np.ndarray, nu: np.ndarray, R: np.ndarray, gate: float, t: float) -> UpdateResult:
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

    def _consensus(self, yaws: List[_Yaw], min_yaws: int, min_markers: int = 1
                   ) -> Tuple[Optional[Tuple[float, float, List[_Yaw]]], str]:
        """((δψ rad, variance rad², members), '') from buffered yaws, or (None, why not): fewer than
        ``min_yaws`` agree, or they come from fewer than ``min_markers`` markers."""
        if not yaws:
            return None, "no marker yaws (no map marker seen with a prism position)"
        if len(yaws) < min_yaws:
            return None, f"{len(yaws)} marker yaw(s), {min_yaws} consistent ones needed"
        off = np.array([y.offset for y in yaws])
        sig = np.array([y.sigma for y in yaws])
        mean, members = yaw_consensus(off, sig, self.params.init_yaw_floor)
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

    def _drift_fit(self, used: List[_Yaw], dpsi: float, t: float) -> Tuple[float, float, float]:
        """(δψ at ``t``, drift rate ω rad/s, its variance) from consensus yaws: a weighted line through
        their offsets over time, its slope shrunk towards 0 by the drift-rate prior (a short window says
        little about the drift); δψ is the line at ``t``."""
        prior = self.params.initial_drift_rate_sigma ** 2
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

    def _adapt(self, nis: float) -> None:
        """Scale the yaw random walk by the innovations: up when they are larger than the covariance
        says (NIS > 1), down towards 1 when smaller."""
        p = self.params
        if p.adapt_rate > 0 and math.isfinite(nis):
            scale = self.stats.noise_scale * math.exp(p.adapt_rate * (min(nis, 25.0) - 1.0))
            self.stats.noise_scale = min(max(scale, 1.0), p.adapt_max_scale)

    def _recover_from_lockout(self, sample: _Yaw) -> bool:
        """Note a gated yaw; when the gated yaws of the last ``lockout_window`` s agree with each other
        (from ≥ ``init_min_markers`` markers, over half the window at least), reset δψ and ω to them."""
        p = self.params
        self._gated = [y for y in self._gated if y.t >= sample.t - p.lockout_window] + [sample]
        if len(self._gated) < p.lockout_min_yaws or sample.t - self._gated[0].t < 0.5 * p.lockout_window:
            return False
        cons, _ = self._consensus(self._gated, p.lockout_min_yaws, p.init_min_markers)
        if cons is None or cons[2][-1].t - cons[2][0].t < 0.5 * p.lockout_window:
            return False
        self._reset_yaw(sample.t, cons)
        self.stats.lockout_recoveries += 1
        return True

    def _try_initialise(self, t: float) -> UpdateResult:
        p = self.params
        horizon = t - max(p.standstill_duration, p.max_delay)
        self._yaws = [y for y in self._yaws if y.t >= horizon]
        self._prisms = [m for m in self._prisms if m.t >= horizon]
        if self.stats.state == "reinitialising":
            return self._reinitialise(t)
        buffered = UpdateResult("buffered", float("nan"), float("nan"))
        window_p = [m for m in self._prisms if m.t >= t - p.standstill_duration]
        window_y = [y for y in self._yaws if y.t >= t - p.standstill_duration]
        if not window_p:
            self.stats.waiting_reason = "no prism position (total station not tracking, or no prism topic)"
            return buffered
        still = self._is_standstill(window_p, window_y, t)
        if not still and p.require_standstill:
            self.stats.waiting_reason = (f"waiting for a standstill of {p.standstill_duration:g} s "
                                         "(require_standstill is set)")
            return buffered
        cons, why = self._consensus(window_y, p.init_min_yaws, 1 if still else p.init_min_markers)
        if cons is None and not still:
            cons, why = self._confirmed_by_track(window_y, window_p, why)
        if cons is None:
            self.stats.waiting_reason = why
            return buffered
        used = cons[2]
        use_p = window_p if still else window_p[-1:]
        self.t = max(t, max(m.t for m in use_p))
        dpsi, drift, drift_var = self._drift_fit(used, cons[0], self.t)
        n = len(use_p)
        self._anchor(dpsi, cons[1], np.mean([m.p for m in use_p], axis=0), np.mean([m.cov for m in use_p], axis=0) / n,
                     np.mean([m.q for m in use_p], axis=0), drift, drift_var)
        self.stats.state = "tracking"
        self.stats.waiting_reason = ""
        self.stats.prism_accepted += n
        self.stats.last_prism = max(m.t for m in use_p)
        for y in used:
            self._count_yaw(True, y.marker_id, y.t)
        self.stats.last_update = self.t
        self._yaws, self._prisms, self._gated = [], [], []
        return UpdateResult("initialised", float("nan"), float("nan"))

    def _confirmed_by_track(self, window_y: List[_Yaw], window_p: List[_Prism], why: str
                            ) -> Tuple[Optional[Tuple[float, float, List[_Yaw]]], str]:
        """While moving with one marker in view: its consistent yaws, if the prism track agrees with them.
        The prism's displacement over the window, in map and in odom, gives δψ independently of any
        marker (Δp = Rz(δψ)·Δq), to about σ_prism / distance: a false id or a moved marker is degrees off."""
        cons, _ = self._consensus(window_y, self.params.init_min_yaws)
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

    def _anchor(self, dpsi: float, var: float, p: np.ndarray, C: np.ndarray, q: np.ndarray,
                drift: float = 0.0, drift_var: Optional[float] = None) -> None:
        """State from δψ (rad, variance rad²) and a prism position p (m, cov C m²) seen at q in odom (m);
        the drift rate ``drift`` (rad/s, variance ``drift_var``; default 0 ± initial_drift_rate_sigma)."""
        Rq = rot_z(dpsi) @ q
        g = _ez_cross(Rq)
        self.x = np.concatenate([[dpsi], p - Rq, [drift]])
        self.P = np.zeros((5, 5))
        self.P[0, 0] = var
        self.P[0, 1:4] = self.P[1:4, 0] = -g * var
        self.P[1:4, 1:4] = C + var * np.outer(g, g)
        self.P[4, 4] = self.params.initial_drift_rate_sigma ** 2 if drift_var is None else drift_var

    def _reanchor(self, t: float, p: np.ndarray, C: np.ndarray, q: np.ndarray) -> UpdateResult:
        """After ``reinit_after`` s without an accepted prism: two consecutive prisms that agree (χ² gate on
        the implied translations) re-anchor the translation, keeping δψ and its variance."""
        cand = _Prism(t, p, C, q)
        prev = self._prisms[-1] if self._prisms else None
        self._prisms = [cand]
        if prev is None or abs(t - prev.t) > max(self.params.max_delay, 1.0):
            return UpdateResult("buffered", float("nan"), float("nan"))
        Rz = rot_z(self.x[0])
        d = (prev.p - Rz @ prev.q) - (p - Rz @ q)
        chi2 = float(d @ np.linalg.solve(prev.cov + C, d))
        if chi2 > self.params.gate_chi2_prism:
            return UpdateResult("buffered", chi2, d)
        self._predict_to(t)
        self._anchor(float(self.x[0]), float(self.P[0, 0]), p, C, q, float(self.x[4]), float(self.P[4, 4]))
        self._prisms = []
        self.stats.prism_reanchors += 1
        self.stats.prism_accepted += 1
        self.stats.last_prism = max(t, self.stats.last_prism)
        self.stats.last_update = max(t, self.stats.last_update)
        return UpdateResult("initialised", chi2, d)

    def _is_standstill(self, window_p: List[_Prism], window_y: List[_Yaw], t: float) -> bool:
        p = self.params
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

    def _reinitialise(self, t: float) -> UpdateResult:
        """After ``reinit_after`` s without an accepted yaw: reset δψ (and ω) to the consensus of recent
        yaws, keeping the robot's map position and its covariance."""
        cons, why = self._consensus(self._yaws, self.params.init_min_yaws)
        if cons is None:
            self.stats.waiting_reason = why
            return UpdateResult("buffered", float("nan"), float("nan"))
        self._reset_yaw(t, cons)
        self.stats.reinitialisations += 1
        for y in cons[2]:
            self._count_yaw(True, y.marker_id, y.t)
        self._yaws, self._prisms = [], []
        return UpdateResult("initialised", float("nan"), float("nan"))

    def _reset_yaw(self, t: float, cons: Tuple[float, float, List[_Yaw]]) -> None:
        """δψ and ω from a consensus of yaws at time ``t``; the robot's map position (and its
        covariance) is kept: the translation turns with δψ about the robot."""
        _, var, used = cons
        self._predict_to(t)
        dpsi, drift, drift_var = self._drift_fit(used, cons[0], max(t, self.t))
        q = self._odom_pos
        g_old = _ez_cross(rot_z(self.x[0]) @ q)
        A = np.eye(5)
        A[1:4, 0] = g_old                      # (δψ, t) → (δψ, m = Rz(δψ) q + t)
        Py = A @ self.P @ A.T
        m = rot_z(self.x[0]) @ q + self.x[1:4]
        Py[[0, 4], :] = Py[:, [0, 4]] = 0.0
        Py[0, 0] = var
        Py[4, 4] = drift_var
        g_new = _ez_cross(rot_z(dpsi) @ q)
        Ainv = np.eye(5)
        Ainv[1:4, 0] = -g_new
        self.x = np.concatenate([[dpsi], m - rot_z(dpsi) @ q, [drift]])
        self.P = Ainv @ Py @ Ainv.T
        self.stats.state = "tracking"
        self.stats.waiting_reason = ""
        self.stats.last_update = max(self.stats.last_update, t)
        self._gated = []

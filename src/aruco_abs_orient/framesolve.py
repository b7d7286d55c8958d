"""The per-frame solve of :class:`pipeline.AbsOrientPipeline` and its gates, and the results it fills.

In: one frame's marker observations (ids of the map) at total-station time ``t``, the odometry pose and the tilt
in use, and either the prism position with its covariance or none. Out: a :class:`FrameResult` filled in place
(an :class:`ObservationResult` per marker: its yaw, σ, range, accepted or the reason why not) and the filter
and tilt updates: with the prism, each marker's closed-form yaw (``solver.yaw_from_marker``) gated by its
visibility, its elevation and the tracking gate, the frame's yaws fused (``solver.fuse_yaws``) and one yaw
update; without it, a resection (``posefit.resection``) and one pose update; and roll and pitch from the
markers (``posefit.attitude_from_markers``, or the resection's) as a gated tilt update. :class:`FrameSolver`
is a mixin: the pipeline owns the state it reads (map, lenses, mounting, params, filter, tilt, counters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from .detection import MarkerObservation
from .posefit import attitude_from_markers, resection
from .solver import Mounting, NoiseModel, SolverError, fuse_yaws, yaw_from_marker
from .tilt import Tilt
from .tracking import TrackingStats
from .transforms import matrix_to_rpy, wrap_angle

__all__ = ["ObservationResult", "FrameResult", "FrameSolver"]

_MIN_TILT_SIGMA = math.radians(0.001)  # rad: a tilt σ of 0 (tilt_sigma_deg 0) taken as this in a resection


@dataclass
class ObservationResult:
    """One marker in one frame, and what it said about the absolute yaw."""

    observation: MarkerObservation
    yaw: float = float("nan")            # rad, absolute yaw of base_link from this marker alone
    yaw_sigma: float = float("nan")      # rad
    range: float = float("nan")          # m, camera → marker
    residual: float = float("nan")       # rad, yaw − filtered yaw (wrapped)
    accepted: bool = False
    reason: str = ""                     # why rejected (empty when accepted)

    @property
    def id(self) -> int:
        return self.observation.id


@dataclass
class FrameResult:
    """Everything one image gave. Times in s (total-station time); angles in rad."""

    stamp: float
    observations: List[ObservationResult] = field(default_factory=list)
    fused_yaw: Optional[float] = None               # this frame's markers fused (before the filter)
    fused_yaw_sigma: Optional[float] = None
    yaw: Optional[float] = None                     # filtered absolute yaw of base_link
    yaw_sigma: Optional[float] = None
    map_T_base: Optional[np.ndarray] = None         # 4×4 corrected pose
    base_position_cov: Optional[np.ndarray] = None  # 3×3 m² (prism, lever arm removed)
    prism_cov: Optional[np.ndarray] = None          # 3×3 m²: the instrument's covariance of the prism position
    prism_position: Optional[np.ndarray] = None     # (3,) m, prism interpolated at the image time
    map_T_odom: Optional[np.ndarray] = None
    map_T_odom_cov: Optional[np.ndarray] = None     # 4×4 over (yaw, x, y, z)
    marker_pose: Optional[np.ndarray] = None        # 4×4 map_T_base from a resection on the markers (no prism)
    marker_pose_cov: Optional[np.ndarray] = None    # 6×6 over (x, y, z, roll, pitch, yaw), m², rad²
    marker_pose_accepted: bool = False              # the filter took it
    tilt_source: str = ""                           # roll/pitch used: 'imu', 'markers' or 'odometry'
    initialised: bool = False
    error: Optional[str] = None
    timings: Dict[str, float] = field(default_factory=dict)   # ms per stage
    tracking: Optional[TrackingStats] = None        # how the markers were searched


class FrameSolver:
    """The per-frame solve, mixed into :class:`pipeline.AbsOrientPipeline`, whose state it reads: ``marker_map``,
    ``lenses``, ``_lens_excess`` (rad, front and back), ``base_T_camera``, ``base_T_prism``, ``params``
    (``PipelineParams``), ``fit_settings``, ``filter`` (``MapOdomFilter``), ``tilt`` (``TiltEstimator``),
    ``tilt_from_markers`` and ``_count``."""

    def _rays(self, observations, from_point=None) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The observations' rays in the camera frame (origins (N, 3) m, unit directions (N, 3): each from the
        lens that saw it, a marker across a seam from both, by their share of its corners) and their σ (N,) rad,
        widened for the lens whose yaw the calibration knew less well, and in the lenses' blend band by the ray's
        possible error there for markers at their range from ``from_point`` (map, m; None: not widened)."""
        bearings = np.array([o.centre for o in observations]).reshape(-1, 3)
        origins, directions = self.lenses.marker_rays(bearings, np.array([o.corners for o in observations]))
        sigma = np.array([o.sigma for o in observations], dtype=float)
        if np.any(self._lens_excess) and len(observations):
            sigma = np.hypot(sigma, np.where(self.lenses.front_weight(bearings) >= 0.5, *self._lens_excess))
        if from_point is not None and len(observations):
            ranges = np.linalg.norm(np.array([self.marker_map[o.id].position for o in observations]) - from_point,
                                    axis=1)
            sigma = np.hypot(sigma, self.lenses.blend_error(bearings, ranges))
        return origins, directions, sigma

    def _mounting(self) -> Mounting:
        """The camera's and the prism's place on base_link, as the solvers take it."""
        return Mounting(self.base_T_camera, self.base_T_prism[:3, 3])

    def _tilt_from_markers(self, t, observations, prism_p, prism_cov, tilt: Tilt, odom_roll, odom_pitch,
                           odom_yaw) -> bool:
        """Roll and pitch from a frame's ≥ 2 well-spread markers and the prism (:func:`attitude_from_markers`)
        as a gated update of the tilt; True when it was taken."""
        if len(observations) < 2:
            return False
        M = np.array([self.marker_map[o.id].position for o in observations])
        origins, directions, sigma = self._rays(observations, prism_p)
        try:
            across = [self.marker_map[o.id].sigma_across(prism_p) for o in observations]
            noise = NoiseModel(bearing=sigma, prism_cov=prism_cov, marker=np.array(across))
            est = attitude_from_markers(
                directions, M, prism_p, self._mounting(), noise=noise, tilt=(tilt.roll, tilt.pitch),
                settings=self.fit_settings, min_spread=math.radians(self.params.attitude_min_spread_deg),
                origins=origins)
        except SolverError:
            self._count("tilt_from_markers_refused")
            return False
        taken = self.tilt.update(t, est.roll, est.pitch, est.cov[:2, :2], odom_roll, odom_pitch, odom_yaw=odom_yaw)
        self._count("tilt_from_markers" if taken else "tilt_from_markers_gated")
        return taken

    def _resect_frame(self, t, res: FrameResult, observations, tilt: Tilt, odom_T_base, gated=()) -> None:
        """No prism: the pose of base_link from the frame's ≥ 2 markers (:func:`resection` with the frame's tilt as
        a measurement of its σ), one filter update with its position and yaw; with ≥ 3 markers, what they say
        about roll and pitch beyond that tilt (the posterior's information minus the tilt's) updates the tilt."""
        res.observations = [ObservationResult(o, reason="tracking gate: far from its predicted bearing")
                            for o in gated]
        obs = list(observations)
        rows = [ObservationResult(o) for o in obs]
        res.observations = rows + res.observations
        if len(obs) < 2:
            self._count("too_few_for_resection")
            for r in rows:
                r.reason = "no prism position, and a resection needs ≥ 2 markers (≥ 3 without a known tilt)"
            return
        start = None
        if len(obs) == 2 and self.filter.initialised:      # two solutions possible: the one near the prediction
            start = self.filter.map_T_odom(t)[0] @ odom_T_base
        origins, directions, sigma = self._rays(obs, None if start is None else start[:3, 3])
        try:
            near = None if start is None else start[:3, 3]  # None: the sight lines unknown, the worst axis
            noise = NoiseModel(bearing=sigma, marker=np.array([self.marker_map[o.id].sigma_across(near)
                                                               for o in obs]))
            est = resection(directions, np.array([self.marker_map[o.id].position for o in obs]),
                            self.base_T_camera, noise=noise, tilt=(tilt.roll, tilt.pitch),
                            tilt_sigma=max(tilt.sigma, _MIN_TILT_SIGMA), initial_pose=start,
                            settings=self.fit_settings, min_cone=math.radians(self.params.resection_min_cone_deg),
                            origins=origins)
        except SolverError as e:
            self._count("resection_degenerate")
            for r in rows:
                r.reason = f"resection: {e}"
            return
        inlier = est.weights > 0.5
        used = [r.id for r, ok in zip(rows, inlier) if ok]
        cov4 = est.cov[np.ix_([5, 0, 1, 2], [5, 0, 1, 2])]
        update = self.filter.add_pose(t, est.position, est.yaw, cov4, odom_T_base, sources=used)
        res.marker_pose, res.marker_pose_cov, res.marker_pose_accepted = est.map_T_base, est.cov, update.accepted
        if update.accepted and len(obs) >= 3 and tilt.source != "imu" and self.tilt_from_markers:
            self._tilt_from_resection(t, est, tilt, odom_T_base)
        for r, ok in zip(rows, inlier):
            r.yaw = est.yaw
            r.accepted = bool(ok and update.accepted)
            r.reason = ("" if r.accepted else "disagrees with the other markers of the frame (resection)" if not ok
                        else f"filter: {update.status}")
        self._count("resection_" + update.status)

    def _tilt_from_resection(self, t, est, tilt: Tilt, odom_T_base) -> None:
        """The markers' own roll and pitch from a resection that had ``tilt`` as a measurement: information of
        the posterior (roll, pitch) minus the tilt's (exact for the linearised problem: that prior acts on
        roll and pitch only), as a tilt update when the markers determine them (σ < 1°)."""
        info_prior = np.eye(2) / max(tilt.sigma, _MIN_TILT_SIGMA) ** 2
        info_post = np.linalg.inv(est.cov[3:5, 3:5])
        info_markers = info_post - info_prior
        if np.linalg.eigvalsh(info_markers)[0] < 1.0 / math.radians(1.0) ** 2:
            return
        C = np.linalg.inv(info_markers)
        prior = np.array([tilt.roll, tilt.pitch])
        post = prior + wrap_angle(np.array([est.roll, est.pitch]) - prior)
        x = C @ (info_post @ post - info_prior @ prior)
        odom_roll, odom_pitch, odom_yaw = matrix_to_rpy(odom_T_base[:3, :3])
        taken = self.tilt.update(t, float(x[0]), float(x[1]), C, float(odom_roll), float(odom_pitch),
                                 odom_yaw=float(odom_yaw))
        self._count("tilt_from_markers" if taken else "tilt_from_markers_gated")

    def _solve_frame(self, t, res: FrameResult, observations, prism, tilt: Tilt, odom_T_base, gated=(),
                     rows=None) -> None:
        """Yaw from each marker (closed form), their fusion (shared prism/tilt errors, false ids
        dropped), and one filter update with the fused yaw. ``prism``: (position (3,) m, its 3×3 covariance
        m²) at ``t``. ``rows``: :meth:`_row_times` per observation (observations, then gated): each marker's
        yaw at its row time, referred back to ``t``."""
        prism_p, prism_cov = prism
        q = self.params
        estimates = []
        tracker_gated = {id(o) for o in gated}
        everything = list(observations) + list(gated)
        origins, directions, sigma = self._rays(everything, prism_p)
        for k, (o, row) in enumerate(zip(everything, rows or [None] * len(everything))):
            m = self.marker_map[o.id]  # the tracker only returns ids of the map
            p_o, roll_o, pitch_o, dyaw = prism_p, tilt.roll, tilt.pitch, 0.0
            if row is not None:
                _, p_o, droll, dpitch, dyaw = row
                roll_o, pitch_o = tilt.roll + droll, tilt.pitch + dpitch
                if p_o is None:
                    self._count("no_prism_at_row_time")
                    res.observations.append(ObservationResult(o, reason="no prism position at its row's time"))
                    continue
            if not m.visible_from(p_o, margin=float(np.linalg.norm(self.base_T_camera[:3, 3]
                                                                       - self.base_T_prism[:3, 3]))):
                self._count("rejected_behind")
                res.observations.append(ObservationResult(o, reason="seen from behind its surveyed face (wrong id)"))
                continue
            try:
                est = yaw_from_marker(
                    directions[k], m.position, p_o, (roll_o, pitch_o), self._mounting(),
                    NoiseModel(bearing=float(sigma[k]), prism_cov=prism_cov, marker=m.sigma_across(p_o),
                               tilt=tilt.sigma, lever=q.lever_sigma), min_range=q.min_range, origin=origins[k])
            except SolverError as e:
                self._count("degenerate")
                res.observations.append(ObservationResult(o, reason=f"geometry: {e}"))
                continue
            if dyaw:
                est = est._replace(yaw=float(wrap_angle(est.yaw - dyaw)))
            r = ObservationResult(o, yaw=est.yaw, yaw_sigma=est.sigma, range=est.range)
            res.observations.append(r)
            if id(o) in tracker_gated:
                r.reason = "tracking gate: far from its predicted bearing (moved marker, or the filter is off)"
                continue
            if abs(est.elevation_residual) > q.elevation_gate * est.elevation_sigma:
                r.reason = "elevation disagrees with the map (wrong id or moved marker)"
                self._count("rejected_elevation")
                continue
            estimates.append((r, est))
        if not estimates:
            return
        fused = fuse_yaws([e for _, e in estimates], gate=q.fusion_gate)
        for (r, _), used in zip(estimates, fused.used):
            if not used:
                r.reason = "disagrees with the other markers of the frame"
                self._count("rejected_fusion")
        update = self.filter.add_yaw(t, fused.yaw, fused.sigma, odom_T_base,
                                     sources=[r.id for (r, _), used in zip(estimates, fused.used) if used])
        res.fused_yaw, res.fused_yaw_sigma = fused.yaw, fused.sigma
        for (r, _), used in zip(estimates, fused.used):
            if used:
                r.accepted = bool(update.accepted)
                r.reason = "" if r.accepted else f"filter: {update.status}"
        self._count("filter_" + update.status)

"""Boresight and lever-arm calibration of the 360° camera from a recording (DESIGN §4.8).

The static transform ``base_T_camera`` (rotation ``R_bc``, camera origin ``t_cam`` in base_link) is
refined from ALL marker observations of a recording by robust weighted least squares:

* boresight: a rotation ``B = rpy_to_matrix(roll, pitch, yaw)`` in base_link applied on top of the
  nominal mounting, ``R_bc = B · R_bc_nominal`` (three small angles, radians);
* lever arm (optional): ``t_cam = t_cam_nominal + Δl`` (base_link, metres);
* time offset (optional): a residual ``Δτ`` (s) of the camera ↔ total-station offset given, so that the
  prism at camera time t is ``P(t − Δτ) ≈ P(t) − V(t)·Δτ`` (V the prism velocity from the track).

Observation model of one marker bearing ``u`` (camera frame) at time t, as in ``solver``: with the
prism P(t) (map), the odometry attitude ``odom_R_base(t)`` (tilt and relative yaw from VO) and the
map→odom yaw offset δ(t)::

    map_R_base = Rz(δ(t)) · odom_R_base(t)
    camera C   = P + map_R_base · (t_cam − t_prism)
    u_pred     = (B R_bc)ᵀ map_R_baseᵀ (M − C) / |·|

The residual is ``u_obs × u_pred`` (its norm is the sine of the angle between the bearings), with
the 1-σ ``sqrt(σ_u² + (σ_M² + σ_P²) / range²)`` per axis (detection, survey, prism). δ(t) is a
nuisance: the VO drifts, so it is piecewise-linear in time with knots every ``knot_spacing`` seconds,
tied by a weak random-walk prior so that knots without data stay determined.

Observability: ``δ(t)`` and the boresight YAW both turn the camera about the vertical, so markers alone
determine only their sum. What separates them is the prism track: for a non-holonomic platform
base_link x is the direction of travel, so while the platform drives, the heading of the velocity of
the base_link origin (prism velocity minus ω × lever arm, ``timesync.heading_from_track``) measures
``δ(t) + yaw(odom_R_base(t))`` directly. These heading constraints are weighted by speed (σ = noise /
speed), left out at standstill (speed < ``min_speed``) and in fast turns/turns in place (|yaw rate| >
``max_turn_rate_deg``). The boresight roll and pitch are observable from the markers with the VO tilt
(map→odom has no tilt); the lever arm from markers in different directions and at different ranges.
Δτ moves the camera along its direction of travel by V·Δτ: the bearing of a marker at range r turns
by up to |V|Δτ/r, differently for each marker, while a boresight turns all of them alike — markers at
several ranges and in several directions separate the two, and a camera lever arm along x is told apart
from Δτ by the standstill and the speed changes (|V|Δτ scales with speed, a lever arm does not). The
heading constraints carry Δτ too (the track heading at t − Δτ: ∂/∂Δτ = −turn rate). A 5 ms offset at
0.8 m/s is 4 mm: over a recording's thousands of bearings to markers 2–12 m away it is determined to
a fraction of a millisecond, where the heading alone (``timesync``) is limited by the VO drift.

A recording that lacks what a parameter needs (no motion, no markers, too few) raises
:class:`CalibrationError` saying so; a parameter whose σ exceeds its limit is reported as not
determined, never as a number.

Weights: after a robust stage (Cauchy IRLS with an annealed scale) markers beyond ``outlier_gate`` σ and
heading samples beyond it are dropped, the rest solved by least squares and the two groups' variance
factors estimated (variance component estimation) so the reported σ reflect the actual scatter.

Units: metres, radians (degrees only in ``report_dict`` and in the YAML, as documented). numpy only,
Python 3.8 compatible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

import numpy as np

from .errors import GeometryError
from .markers import MarkerMap
from .solver import yaw_consensus
from .timesync import TimeSyncError, heading_from_track
from .transforms import make_T, matrix_to_rpy, quat_to_matrix, rot_z, rpy_to_matrix, wrap_angle, yaw_of
from .tum import Trajectory, atomic_write_text, read_yaml

__all__ = [
    "CalibrationError",
    "CalibrationParams",
    "Calibration",
    "calibrate",
    "static_tf_yaml",
    "write_static_tf_yaml",
    "launch_snippet",
    "load_calibration",
]


class CalibrationError(GeometryError, ValueError):
    """The recording cannot determine the calibration, or the inputs are malformed; the message says why."""


@dataclass
class CalibrationParams:
    """Knobs of :func:`calibrate`.

    - ``knot_spacing``: spacing (s) of the knots of the piecewise-linear map→odom yaw δ(t).
    - ``drift_sigma_deg``: 1-σ (degrees) of the change of δ between adjacent knots (weak prior).
    - ``heading_smooth``: σ (s) of the local quadratic fit of the prism track (``heading_from_track``).
    - ``heading_step``: spacing (s) of the heading constraints.
    - ``min_speed``: slowest speed (m/s) whose track heading is used.
    - ``max_turn_rate_deg``: fastest yaw rate (degrees/s) whose track heading is used.
    - ``velocity_sigma``: a-priori velocity noise (m/s) of the track; heading σ = it / speed (rad),
      rescaled by the estimated variance factor.
    - ``min_moving_time``: least usable driving time (s) to separate the boresight yaw.
    - ``prism_max_gap``: largest gap (s) between the prism fixes around an observation.
    - ``prism_sigma``: 1-σ per axis of a prism position (m); enters each bearing as σ / range.
    - ``min_observations``, ``min_markers``: least usable observations and distinct marker ids.
    - ``loss_scale``: Cauchy scale (in σ) of the robust stage; ``outlier_gate``: normalised residual
      beyond which an observation is dropped before the least-squares stage.
    - ``max_boresight_sigma_deg``, ``max_lever_sigma``, ``max_time_offset_sigma``: a boresight angle
      (degrees) / lever-arm axis (m) / time offset (s) with a larger 1-σ is not determined:
      :class:`CalibrationError`.
    - ``max_iterations``: Gauss-Newton iterations per stage.
    """

    knot_spacing: float = 5.0
    drift_sigma_deg: float = 1.0
    heading_smooth: float = 0.25
    heading_step: float = 0.25
    min_speed: float = 0.2
    max_turn_rate_deg: float = 30.0
    velocity_sigma: float = 0.01
    min_moving_time: float = 5.0
    prism_max_gap: float = 0.5
    prism_sigma: float = 0.005
    min_observations: int = 20
    min_markers: int = 2
    loss_scale: float = 2.0
    outlier_gate: float = 4.0
    max_boresight_sigma_deg: float = 0.1
    max_lever_sigma: float = 0.02
    max_time_offset_sigma: float = 0.005
    max_iterations: int = 30

    def validate(self) -> None:
        for name, value in self.__dict__.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise CalibrationError(f"CalibrationParams.{name}: expected a positive number, got {value!r}")


@dataclass
class Calibration:
    """A boresight / lever-arm calibration and how well the recording determined it.

    - ``boresight_rpy`` (3,) rad: roll, pitch, yaw of B (``R_bc = B · R_bc_nominal``, in base_link);
      ``boresight_sigma`` (3,) rad, 1-σ.
    - ``lever_arm_delta`` (3,) m: correction of the camera origin in base_link (zero when not estimated);
      ``lever_arm_sigma`` (3,) m (NaN when not estimated); ``lever_arm_estimated``.
    - ``cov``: covariance of (roll, pitch, yaw[, Δx, Δy, Δz][, Δτ]) in rad², m², s² (the ones estimated).
    - ``residual_rms_before`` / ``residual_rms_after`` (rad): RMS angle between observed and predicted
      bearings with the nominal and with the calibrated transform (δ(t) fitted in both), over the
      observations kept; ``residual_median_before`` / ``_after`` likewise (rad).
    - ``heading_rms`` (rad): RMS of the track-heading residuals kept.
    - ``variance_factors``: a-posteriori variance factors of the groups ('markers', 'heading').
    - counts: ``n_observations`` given, ``n_used`` kept, ``n_markers`` distinct ids kept, ``n_heading``
      heading constraints kept, ``moving_time`` (s) they cover, ``skipped`` reason → count.
    - ``used`` (N,) bool over the input observations; ``residuals_before`` / ``residuals_after`` (N,)
      rad (NaN where unusable).
    - ``time_offset_delta`` (s): the residual time offset found (0 when not estimated): the camera
      stamps are total-station time + (the offset given + it); ``time_offset_sigma`` (s, NaN when not
      estimated); ``time_offset_estimated``.
    """

    boresight_rpy: np.ndarray
    boresight_sigma: np.ndarray
    lever_arm_delta: np.ndarray
    lever_arm_sigma: np.ndarray
    lever_arm_estimated: bool
    cov: np.ndarray
    residual_rms_before: float
    residual_rms_after: float
    residual_median_before: float
    residual_median_after: float
    heading_rms: float
    variance_factors: Dict[str, float]
    n_observations: int
    n_used: int
    n_markers: int
    n_heading: int
    moving_time: float
    iterations: int
    used: np.ndarray
    residuals_before: np.ndarray
    residuals_after: np.ndarray
    skipped: Dict[str, int] = field(default_factory=dict)
    time_offset_delta: float = 0.0
    time_offset_sigma: float = float("nan")
    time_offset_estimated: bool = False

    @property
    def boresight_matrix(self) -> np.ndarray:
        """B (3×3), the rotation in base_link applied on top of the nominal camera mounting."""
        return rpy_to_matrix(*self.boresight_rpy)

    def apply(self, base_T_camera_nominal) -> np.ndarray:
        """The calibrated base_T_camera (4×4) from the nominal one."""
        T = np.asarray(base_T_camera_nominal, dtype=float)
        return make_T(self.boresight_matrix @ T[:3, :3], T[:3, 3] + self.lever_arm_delta)

    def report_dict(self) -> dict:
        """The calibration for a report: degrees, millimetres, counts."""
        deg = [round(math.degrees(float(x)), 5) for x in self.boresight_rpy]
        out = {
            "boresight_rpy_deg": deg,
            "boresight_sigma_deg": [round(math.degrees(float(x)), 5) for x in self.boresight_sigma],
            "lever_arm_estimated": self.lever_arm_estimated,
            "residual_rms_before_deg": math.degrees(self.residual_rms_before),
            "residual_rms_after_deg": math.degrees(self.residual_rms_after),
            "residual_median_before_deg": math.degrees(self.residual_median_before),
            "residual_median_after_deg": math.degrees(self.residual_median_after),
            "heading_rms_deg": math.degrees(self.heading_rms),
            "variance_factors": dict(self.variance_factors),
            "observations": self.n_observations,
            "observations_used": self.n_used,
            "markers": self.n_markers,
            "heading_constraints": self.n_heading,
            "moving_time_s": self.moving_time,
            "iterations": self.iterations,
            "skipped": dict(self.skipped),
        }
        if self.time_offset_estimated:
            out["time_offset_delta_ms"] = round(1e3 * self.time_offset_delta, 3)
            out["time_offset_sigma_ms"] = round(1e3 * self.time_offset_sigma, 3)
        if self.lever_arm_estimated:
            out["lever_arm_delta_mm"] = [round(1e3 * float(x), 3) for x in self.lever_arm_delta]
            out["lever_arm_sigma_mm"] = [round(1e3 * float(x), 3) for x in self.lever_arm_sigma]
        return out


# ----------------------------------------------------------------------------- the problem


class _Problem:
    """Marker observations and heading constraints with everything interpolated to their times.

    The global unknowns are the 7-vector x = (roll, pitch, yaw, Δl_x, Δl_y, Δl_z, Δτ) (rad, m, s), of
    which ``_solve`` frees a subset; the knot values d of δ(t) are always free."""

    def __init__(self, u, M, P, V, R_odom, sigma, t_obs, heading, knots, R_bc, t_cam, t_prism, drift_sigma):
        self.u, self.M, self.P, self.V, self.R_odom, self.sigma = u, M, P, V, R_odom, sigma
        self.R_bc, self.t_cam, self.t_prism = R_bc, t_cam, t_prism
        self.knots = knots
        self.i_obs, self.a_obs = _knot_weights(knots, t_obs)
        self.set_heading(*heading)
        self.drift_sigma = drift_sigma      # rad per knot interval

    def set_heading(self, t_head, yaw_head, sigma_head, rate_head) -> None:
        self.i_head, self.a_head = _knot_weights(self.knots, t_head)
        self.yaw_head = yaw_head            # heading of travel − yaw(odom_R_base): measures δ (rad)
        self.sigma_head = sigma_head        # rad
        self.rate_head = rate_head          # turn rate of the travel heading (rad/s): ∂(residual)/∂Δτ

    def delta_rate(self, d: np.ndarray, t: np.ndarray) -> np.ndarray:
        """dδ/dt (rad/s) of the piecewise-linear δ with knot values ``d`` at times ``t``."""
        i, _ = _knot_weights(self.knots, t)
        return (d[i + 1] - d[i]) / (self.knots[i + 1] - self.knots[i])

    def delta_at(self, d: np.ndarray, i: np.ndarray, a: np.ndarray) -> np.ndarray:
        return (1.0 - a) * d[i] + a * d[i + 1]

    def camera_to_marker(self, x, delta) -> np.ndarray:
        """Vectors (N, 3) camera → marker in base_link axes (m): map_R_baseᵀ (M − P + V Δτ) − (t_cam + Δl − t_prism)."""
        R = rot_z(delta) @ self.R_odom                                   # map_R_base (N, 3, 3)
        return np.einsum("nji,nj->ni", R, self.M - self.P + self.V * x[6]) - (self.t_cam + x[3:6] - self.t_prism)

    def predict(self, x, delta) -> np.ndarray:
        """Predicted unit bearings (N, 3) in the camera frame."""
        q = self.camera_to_marker(x, delta) @ (rpy_to_matrix(*x[:3]) @ self.R_bc)   # (B R_bc)ᵀ g
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    def residuals(self, x, delta) -> np.ndarray:
        return np.cross(self.u, self.predict(x, delta))

    def heading_residuals(self, x, d) -> np.ndarray:
        """δ(t) − (travel heading at t − Δτ − odometry yaw), linearised in Δτ (rad)."""
        return wrap_angle(self.delta_at(d, self.i_head, self.a_head) - self.yaw_head + self.rate_head * x[6])


def _knot_weights(knots: np.ndarray, t: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    i = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    a = (t - knots[i]) / (knots[i + 1] - knots[i])
    return i, a


def _cauchy(e: np.ndarray, k: float) -> np.ndarray:
    return 1.0 / (1.0 + (e / k) ** 2)


class _Solution:
    """Globals x (7,) = (roll, pitch, yaw, Δl (3), Δτ) and the knot values d of δ(t)."""

    def __init__(self, x, d):
        self.x, self.d = x, d


def _solve(pb: _Problem, sol: _Solution, free: Tuple[int, ...], mask_o, mask_h, robust: bool, scale_o: float,
           scale_h: float, params: CalibrationParams) -> Tuple[_Solution, np.ndarray, int]:
    """Gauss-Newton over the globals ``free`` (indices into x; () for the knots only) and the knots.

    ``scale_o``/``scale_h`` multiply the a-priori σ of the groups. Returns the solution, the
    inverse normal matrix (covariance of the free globals then the knots, same σ scaling) and the
    iterations."""
    K = len(pb.knots)
    n_glob = len(free)
    n = n_glob + K
    x, d = sol.x.copy(), sol.d.copy()
    h = 1e-6
    Hinv = np.zeros((n, n))
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007  (reported)
        delta = pb.delta_at(d, pb.i_obs, pb.a_obs)
        r = pb.residuals(x, delta)                                        # (N, 3)
        sig = pb.sigma * scale_o
        e = np.linalg.norm(r, axis=1) / sig
        rh = pb.heading_residuals(x, d)
        sigh = pb.sigma_head * scale_h
        eh = np.abs(rh) / sigh
        w = mask_o / sig ** 2
        wh = mask_h / sigh ** 2
        if robust:
            k_o = max(params.loss_scale, 2.0 * float(np.median(e[mask_o > 0]))) if np.any(mask_o > 0) else 1.0
            k_h = max(params.loss_scale, 2.0 * float(np.median(eh[mask_h > 0]))) if np.any(mask_h > 0) else 1.0
            w = w * _cauchy(e, k_o)
            wh = wh * _cauchy(eh, k_h)
        # Jacobians: globals and δ by central differences (the model is cheap and vectorised)
        Jg = np.empty(r.shape + (n_glob,))
        for j, g in enumerate(free):
            step = np.zeros(7)
            step[g] = h
            Jg[:, :, j] = (pb.residuals(x + step, delta) - pb.residuals(x - step, delta)) / (2 * h)
        c = (pb.residuals(x, delta + h) - pb.residuals(x, delta - h)) / (2 * h)   # ∂r/∂δ
        i, a = pb.i_obs, pb.a_obs
        H = np.zeros((n, n))
        gvec = np.zeros(n)
        H[:n_glob, :n_glob] = np.einsum("n,nki,nkj->ij", w, Jg, Jg)
        gvec[:n_glob] = np.einsum("n,nki,nk->i", w, Jg, r)
        cc = w * np.sum(c * c, axis=1)
        cr = w * np.sum(c * r, axis=1)
        Jc = np.einsum("n,nki,nk->ni", w, Jg, c)                          # (N, G)
        for wi, idx in (((1.0 - a), i), (a, i + 1)):
            gvec[n_glob:] += np.bincount(idx, cr * wi, minlength=K)
            for j in range(n_glob):
                col = np.bincount(idx, Jc[:, j] * wi, minlength=K)
                H[j, n_glob:] += col
                H[n_glob:, j] += col
        for wa, wb, ia, ib in (((1 - a), (1 - a), i, i), ((1 - a), a, i, i + 1), (a, (1 - a), i + 1, i),
                               (a, a, i + 1, i + 1)):
            np.add.at(H, (n_glob + ia, n_glob + ib), cc * wa * wb)
        ih, ah = pb.i_head, pb.a_head
        for wa, ia in (((1 - ah), ih), (ah, ih + 1)):
            gvec[n_glob:] += np.bincount(ia, wh * rh * wa, minlength=K)
            for wb, ib in (((1 - ah), ih), (ah, ih + 1)):
                np.add.at(H, (n_glob + ia, n_glob + ib), wh * wa * wb)
        if 6 in free:  # the heading residuals depend on Δτ too (∂/∂Δτ = turn rate)
            jt = free.index(6)
            H[jt, jt] += np.sum(wh * pb.rate_head ** 2)
            gvec[jt] += np.sum(wh * pb.rate_head * rh)
            for wa, ia in (((1 - ah), ih), (ah, ih + 1)):
                col = np.bincount(ia, wh * pb.rate_head * wa, minlength=K)
                H[jt, n_glob:] += col
                H[n_glob:, jt] += col
        # random-walk prior between adjacent knots
        wp = 1.0 / pb.drift_sigma ** 2
        dd = np.diff(d)
        kk = np.arange(K - 1) + n_glob
        np.add.at(H, (kk, kk), wp)
        np.add.at(H, (kk + 1, kk + 1), wp)
        np.add.at(H, (kk, kk + 1), -wp)
        np.add.at(H, (kk + 1, kk), -wp)
        gvec[n_glob:-1] -= wp * dd
        gvec[n_glob + 1:] += wp * dd
        try:
            Hinv = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)") from None
        if not np.all(np.isfinite(Hinv)):
            raise CalibrationError("the normal equations are singular: the recording does not determine "
                                   "the calibration (too few markers or no motion)")
        dx = -Hinv @ gvec
        x[list(free)] += dx[:n_glob]
        d = d + dx[n_glob:]
        if float(np.max(np.abs(dx))) < 1e-10:
            break
    return _Solution(x, d), Hinv, iterations


def _angles(pb: _Problem, sol: _Solution) -> np.ndarray:
    """Angle (rad) between observed and predicted bearings."""
    delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
    r = pb.residuals(sol.x, delta)
    dot = np.sum(pb.u * pb.predict(sol.x, delta), axis=1)
    return np.arctan2(np.linalg.norm(r, axis=1), dot)


def _fit(pb: _Problem, sol: _Solution, free: Tuple[int, ...], params: CalibrationParams):
    """Robust stage, gate, least squares with variance component estimation.

    Returns (solution, covariance, mask_o, mask_h, variance factors, iterations)."""
    n_o, n_h = len(pb.u), len(pb.yaw_head)
    mask_o, mask_h = np.ones(n_o), np.ones(n_h)
    sol, _, it = _solve(pb, sol, free, mask_o, mask_h, True, 1.0, 1.0, params)
    scale_o = scale_h = 1.0
    vf = {"markers": float("nan"), "heading": float("nan")}
    Hinv = None
    for _ in range(4):
        delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
        e = np.linalg.norm(pb.residuals(sol.x, delta), axis=1) / (pb.sigma * scale_o)
        eh = np.abs(pb.heading_residuals(sol.x, sol.d)) / (pb.sigma_head * scale_h)
        # a 2-D residual: gate on its norm; heading: on its absolute value
        mask_o = (e <= params.outlier_gate).astype(float)
        mask_h = (eh <= params.outlier_gate).astype(float)
        sol, Hinv, it2 = _solve(pb, sol, free, mask_o, mask_h, False, scale_o, scale_h, params)
        it += it2
        delta = pb.delta_at(sol.d, pb.i_obs, pb.a_obs)
        e = np.linalg.norm(pb.residuals(sol.x, delta), axis=1) / (pb.sigma * scale_o)
        eh = np.abs(pb.heading_residuals(sol.x, sol.d)) / (pb.sigma_head * scale_h)
        f_o = float(np.sum(mask_o * e ** 2) / max(2.0 * mask_o.sum(), 1.0))
        f_h = float(np.sum(mask_h * eh ** 2) / max(mask_h.sum(), 1.0)) if n_h else 1.0
        vf = {"markers": f_o * scale_o ** 2, "heading": f_h * scale_h ** 2 if n_h else float("nan")}
        done = abs(f_o - 1.0) < 0.05 and abs(f_h - 1.0) < 0.05
        scale_o *= math.sqrt(max(f_o, 1e-6))
        scale_h *= math.sqrt(max(f_h, 1e-6))
        if done:
            break
    return sol, Hinv, mask_o.astype(bool), mask_h.astype(bool), vf, it


# ----------------------------------------------------------------------------- the entry point


def _as_array(x, shape_tail, name: str, n: Optional[int] = None) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1 + len(shape_tail) or tuple(a.shape[1:]) != tuple(shape_tail) or (n is not None and len(a) != n):
        want = f"({n if n is not None else 'N'}{''.join(f', {s}' for s in shape_tail)})"
        raise CalibrationError(f"{name}: expected an array of shape {want}, got {a.shape}")
    return a


def _interp_prism(t_prism: np.ndarray, p_prism: np.ndarray, t: np.ndarray, max_gap: float):
    """Prism positions (N, 3) at times ``t`` by linear interpolation, and validity (fixes on both
    sides no more than ``max_gap`` s apart)."""
    j = np.searchsorted(t_prism, t, side="right")
    inside = (j > 0) & (j < len(t_prism))
    jj = np.clip(j, 1, len(t_prism) - 1)
    gap = t_prism[jj] - t_prism[jj - 1]
    exact = (j == len(t_prism)) & (t == t_prism[-1])
    valid = (inside & (gap <= max_gap)) | exact
    P = np.stack([np.interp(t, t_prism, p_prism[:, k]) for k in range(3)], axis=1)
    return P, valid


def _heading_constraints(odom: Trajectory, t_prism, p_prism, t_prism_lever, params: CalibrationParams,
                         delta_rate=None):
    """Times (s), δ-measurements (rad: heading of travel − odometry yaw), σ (rad) and the yaw rate
    (rad/s) while driving.

    ``delta_rate``: None or a function of time (s) → dδ/dt (rad/s), the map→odom yaw drift rate of a
    previous fit: the platform's true yaw rate is the VO's plus it (a 4°/min VO drift turns a 0.25 m
    horizontal prism lever arm's velocity by 0.02° of heading at 0.8 m/s)."""
    t0 = max(float(t_prism[0]), float(odom.stamps[0])) + params.heading_smooth
    t1 = min(float(t_prism[-1]), float(odom.stamps[-1])) - params.heading_smooth
    tq = np.arange(t0, t1, params.heading_step)
    if len(tq) == 0:
        return tq, tq.copy(), tq.copy()
    dt = 0.2
    try:
        trk = heading_from_track(t_prism, p_prism, query_t=np.concatenate([tq - dt, tq, tq + dt]),
                                 smooth=params.heading_smooth, min_speed=params.min_speed)
    except TimeSyncError as e:
        raise CalibrationError(f"prism track: {e}") from None
    n = len(tq)
    speed, track_heading = trk.speed[n:2 * n], trk.heading[n:2 * n]
    valid = trk.valid[:n] & trk.valid[n:2 * n] & trk.valid[2 * n:]
    _, q0, v0 = odom.interpolate(tq - dt)
    _, q1, v1 = odom.interpolate(tq + dt)
    _, qc, vc = odom.interpolate(tq)
    R0, R1 = quat_to_matrix(q0), quat_to_matrix(q1)
    y0, yc, y1 = yaw_of(R0), yaw_of(quat_to_matrix(qc)), yaw_of(R1)
    drift = np.zeros(len(tq)) if delta_rate is None else delta_rate(tq)
    yaw_rate = wrap_angle(y1 - y0) / (2 * dt) + drift
    yaw_accel = (wrap_angle(y1 - yc) - wrap_angle(yc - y0)) / dt ** 2
    yaw_odom = yc
    # the Gaussian-smoothed velocity's direction is ψ + s²(v'ψ'/v + ψ''/2) (timesync.heading_from_track):
    # remove it, with ψ', ψ'' from the VO (base_link x is the direction of travel) and v' from the track
    accel = (trk.speed[2 * n:] - trk.speed[:n]) / (2 * dt)
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = params.heading_smooth ** 2 * (accel * yaw_rate / speed + 0.5 * yaw_accel)
    track_heading = track_heading - np.where(np.isfinite(bias), bias, 0.0)
    # velocity of the base_link origin = prism velocity − d/dt(map_R_base · t_prism): the lever arm
    # swings with yaw rate AND with roll/pitch rates (a 0.6 m high prism on a rocking platform).
    # Its rate in odom comes from the VO; it is turned into map by δ ≈ travel heading − VO yaw.
    lever_rate = (R1 @ t_prism_lever - R0 @ t_prism_lever) / (2 * dt)             # (n, 3), odom
    lever = quat_to_matrix(qc) @ t_prism_lever                                     # (n, 3), odom
    lever_rate[:, 0] -= drift * lever[:, 1]                                        # + δ' ẑ × lever
    lever_rate[:, 1] += drift * lever[:, 0]
    v = speed[:, None] * np.stack([np.cos(track_heading), np.sin(track_heading)], axis=1)
    heading = track_heading
    vb = v
    for _ in range(2):
        lev = np.einsum("nij,nj->ni", rot_z(heading - yaw_odom), lever_rate)[:, :2]
        vb = v - lev
        heading = np.arctan2(vb[:, 1], vb[:, 0])
    speed_b = np.hypot(vb[:, 0], vb[:, 1])
    ok = (valid & v0 & v1 & vc & np.isfinite(bias) & (speed_b >= params.min_speed)
          & (np.abs(yaw_rate) <= math.radians(params.max_turn_rate_deg)))
    sigma = params.velocity_sigma / np.maximum(speed_b, 1e-9)
    return tq[ok], wrap_angle(heading - yaw_odom)[ok], sigma[ok], yaw_rate[ok]


def calibrate(obs_times, obs_ids, bearings, sigmas, odom: Trajectory, prism_times, prism_positions,
              marker_map: MarkerMap, base_T_camera, base_T_prism, *, estimate_lever_arm: bool = False,
              estimate_time_offset: bool = False, params: Optional[CalibrationParams] = None) -> Calibration:
    """Boresight (and optionally lever arm) of the camera from all marker observations of a recording.

    Args:
        obs_times: (N,) s, time of each observation (one clock for everything: the camera/VO clock).
        obs_ids: (N,) marker ids; ids not in ``marker_map`` are skipped (counted).
        bearings: (N, 3) marker-centre bearings in the camera frame (normalised here).
        sigmas: (N,) 1-σ bearing noise (rad) per perpendicular axis.
        odom: odom_T_base_link over time (``tum.Trajectory``, same clock): tilt and relative yaw.
        prism_times: (K,) s, prism fixes on the same clock (total-station stamps + the time offset).
        prism_positions: (K, 3) m, prism positions in map.
        marker_map: the surveyed markers (positions m, survey σ m).
        base_T_camera: nominal static transform base_link ← camera (4×4).
        base_T_prism: static transform base_link ← prism (4×4; its translation is used).
        estimate_lever_arm: also estimate the camera origin in base_link (3 more unknowns).
        estimate_time_offset: also estimate the residual time offset Δτ (s) of the prism stamps given
            (one more unknown; linearised, so the offset given should be within ~0.1 s, as
            ``timesync.estimate_offset`` gives it).
        params: :class:`CalibrationParams`.

    Raises:
        CalibrationError: malformed inputs, or a recording that cannot determine the calibration (no
            markers, too few observations, no driving for the boresight yaw, parameters whose σ exceed
            the limits) — the message says which and why.
    """
    params = params or CalibrationParams()
    params.validate()
    args = (obs_times, obs_ids, bearings, sigmas, odom, prism_times, prism_positions, marker_map, base_T_camera,
            base_T_prism, estimate_lever_arm, estimate_time_offset, params)
    cal = _calibrate_once(*args, 0.0)
    shift = cal.time_offset_delta
    for _ in range(4):  # Δτ is linearised: move the prism clock by it and solve again until it is ≪ 1 ms
        if abs(cal.time_offset_delta) < 2e-4:
            break
        cal = _calibrate_once(*args, shift)
        shift += cal.time_offset_delta
    cal.time_offset_delta = shift
    return cal


def _calibrate_once(obs_times, obs_ids, bearings, sigmas, odom: Trajectory, prism_times, prism_positions,
                    marker_map: MarkerMap, base_T_camera, base_T_prism, estimate_lever_arm: bool,
                    estimate_time_offset: bool, params: CalibrationParams, time_shift: float) -> Calibration:
    """One linearised solve of :func:`calibrate` with the prism stamps moved by ``time_shift`` (s)."""
    t = _as_array(obs_times, (), "obs_times")
    n = len(t)
    ids = np.asarray(obs_ids).ravel()
    if len(ids) != n:
        raise CalibrationError(f"obs_ids: expected {n} ids, got {len(ids)}")
    u = _as_array(bearings, (3,), "bearings", n)
    sig = _as_array(sigmas, (), "sigmas", n)
    tp = _as_array(prism_times, (), "prism_times")
    pp = _as_array(prism_positions, (3,), "prism_positions", len(tp))
    Tc = _as_array(base_T_camera, (4,), "base_T_camera", 4)
    Tp = _as_array(base_T_prism, (4,), "base_T_prism", 4)
    if not (np.all(np.isfinite(Tc)) and np.all(np.isfinite(Tp))):
        raise CalibrationError("base_T_camera/base_T_prism: NaN or inf")
    if n == 0:
        raise CalibrationError("no marker observations in the recording: the calibration needs markers in view")
    if len(tp) < 2:
        raise CalibrationError(f"only {len(tp)} prism positions: the calibration needs the prism track")
    if len(odom.stamps) < 2:
        raise CalibrationError("fewer than 2 odometry poses: the calibration needs odom→base_link")
    order = np.argsort(tp, kind="stable")
    tp, pp = tp[order] + time_shift, pp[order]

    skipped: Dict[str, int] = {}

    def skip(mask: np.ndarray, reason: str) -> None:
        k = int(np.count_nonzero(mask))
        if k:
            skipped[reason] = skipped.get(reason, 0) + k

    known = np.array([int(i) in marker_map for i in ids], dtype=bool)
    finite = np.isfinite(t) & np.all(np.isfinite(u), axis=1) & np.isfinite(sig) & (sig > 0)
    norm = np.linalg.norm(u, axis=1)
    finite &= norm > 0
    skip(~known, "id not in the marker map")
    skip(known & ~finite, "non-finite bearing, time or sigma")
    keep = known & finite
    P, p_ok = _interp_prism(tp, pp, np.where(keep, t, tp[0]), params.prism_max_gap)
    skip(keep & ~p_ok, "no prism position at the time")
    keep &= p_ok
    _, q_odom, o_ok = odom.interpolate(np.where(keep, t, odom.stamps[0]))
    skip(keep & ~o_ok, "no odometry at the time")
    keep &= o_ok
    idx = np.flatnonzero(keep)
    used_ids = {int(i) for i in ids[idx]}
    t_cam, t_prism = Tc[:3, 3].copy(), Tp[:3, 3].copy()
    heading = _heading_constraints(odom, tp, pp, t_prism, params)
    th, yh, sh = heading[:3]
    moving = len(th) * params.heading_step
    problems = []
    if len(idx) < params.min_observations or len(used_ids) < params.min_markers:
        problems.append(
            f"only {len(idx)} usable marker observations of {len(used_ids)} distinct markers (need ≥ "
            f"{params.min_observations} of ≥ {params.min_markers}; {n} given, skipped: {skipped or 'none'}): "
            "record with more markers in view")
    if moving < params.min_moving_time:
        problems.append(
            f"the platform drives (≥ {params.min_speed} m/s, no turn in place) for only {moving:.1f} s of the "
            f"recording (need ≥ {params.min_moving_time} s): without the track heading the boresight yaw "
            "cannot be told apart from the map→odom yaw; record the platform driving with markers in view")
    if problems:
        raise CalibrationError("; ".join(problems))

    M = np.array([marker_map[int(i)].position for i in ids[idx]])
    sM = np.array([marker_map[int(i)].sigma for i in ids[idx]])
    t_all = np.concatenate([t[idx], th])
    k0, k1 = float(t_all.min()), float(t_all.max())
    K = max(2, int(math.ceil((k1 - k0) / params.knot_spacing)) + 1)
    knots = k0 + params.knot_spacing * np.arange(K)
    R_odom = quat_to_matrix(q_odom[idx])
    try:
        trk = heading_from_track(tp, pp, t[idx], smooth=params.heading_smooth, min_speed=0.0)
    except TimeSyncError as e:
        raise CalibrationError(f"prism track: {e}") from None
    V = np.zeros((len(idx), 3))
    V[:, 0] = np.where(trk.valid, trk.speed * np.cos(trk.heading), 0.0)
    V[:, 1] = np.where(trk.valid, trk.speed * np.sin(trk.heading), 0.0)
    pb = _Problem(u[idx] / norm[idx, None], M, P[idx], V, R_odom, sig[idx], t[idx], heading, knots,
                  Tc[:3, :3].copy(), t_cam, t_prism, math.radians(params.drift_sigma_deg))
    rng = np.maximum(np.linalg.norm(pb.camera_to_marker(np.zeros(7), np.zeros(len(idx))), axis=1), 1e-3)
    pb.sigma = np.sqrt(pb.sigma ** 2 + (sM ** 2 + params.prism_sigma ** 2) / rng ** 2)

    # start: δ constant, the robust mean of the heading constraints
    sub = np.linspace(0, len(yh) - 1, min(len(yh), 2000)).astype(int)
    d0 = yaw_consensus(yh[sub], sh[sub], floor=math.radians(2.0))[0]
    start = _Solution(np.zeros(7), np.full(K, d0))
    # before: the nominal transform, δ(t) fitted
    before, _, _, _, _, _ = _fit(pb, start, (), params)
    # the heading constraints again, with the drift rate of δ(t) (a second-order term)
    pb.set_heading(*_heading_constraints(odom, tp, pp, t_prism, params,
                                         delta_rate=lambda tt: pb.delta_rate(before.d, tt)))
    free = (0, 1, 2) + ((3, 4, 5) if estimate_lever_arm else ()) + ((6,) if estimate_time_offset else ())
    sol, Hinv, mask_o, mask_h, vf, iterations = _fit(pb, before, free, params)

    n_glob = len(free)
    cov = Hinv[:n_glob, :n_glob]
    sd = np.full(7, np.nan)
    sd[list(free)] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    bad = [name for name, s in zip(("roll", "pitch", "yaw"), sd[:3])
           if not s <= math.radians(params.max_boresight_sigma_deg)]
    if estimate_lever_arm:
        bad += [f"lever arm {name}" for name, s in zip("xyz", sd[3:6]) if not s <= params.max_lever_sigma]
    if estimate_time_offset and not sd[6] <= params.max_time_offset_sigma:
        bad.append("time offset")
    if bad:
        raise CalibrationError(
            "the recording does not determine the boresight " + ", ".join(bad) + " (1-σ "
            + ", ".join(f"{math.degrees(s):.3f}°" for s in sd[:3])
            + (", " + ", ".join(f"{1e3 * s:.1f} mm" for s in sd[3:6]) if estimate_lever_arm else "")
            + (f", {1e3 * sd[6]:.1f} ms" if estimate_time_offset else "")
            + f"; limits {params.max_boresight_sigma_deg}°, {1e3 * params.max_lever_sigma:.0f} mm and "
            f"{1e3 * params.max_time_offset_sigma:.0f} ms): record markers in more directions and at several "
            "ranges while driving")

    a_before = _angles(pb, before)
    a_after = _angles(pb, sol)
    res_b = np.full(n, np.nan)
    res_a = np.full(n, np.nan)
    res_b[idx] = a_before
    res_a[idx] = a_after
    used = np.zeros(n, dtype=bool)
    used[idx[mask_o]] = True
    skip(keep & ~used, "outlier (beyond the gate)")
    rh = pb.heading_residuals(sol.x, sol.d)[mask_h]
    return Calibration(
        boresight_rpy=sol.x[:3].copy(),
        boresight_sigma=sd[:3].copy(),
        lever_arm_delta=sol.x[3:6].copy(),
        lever_arm_sigma=sd[3:6].copy(),
        lever_arm_estimated=bool(estimate_lever_arm),
        cov=cov.copy(),
        residual_rms_before=float(np.sqrt(np.mean(a_before[mask_o] ** 2))),
        residual_rms_after=float(np.sqrt(np.mean(a_after[mask_o] ** 2))),
        residual_median_before=float(np.median(a_before[mask_o])),
        residual_median_after=float(np.median(a_after[mask_o])),
        heading_rms=float(np.sqrt(np.mean(rh ** 2))) if len(rh) else float("nan"),
        variance_factors=vf,
        n_observations=n,
        n_used=int(used.sum()),
        n_markers=len({int(i) for i in ids[used]}),
        n_heading=int(mask_h.sum()),
        moving_time=float(mask_h.sum() * params.heading_step),
        iterations=iterations,
        used=used,
        residuals_before=res_b,
        residuals_after=res_a,
        skipped=skipped,
        time_offset_delta=float(sol.x[6]),
        time_offset_sigma=float(sd[6]),
        time_offset_estimated=bool(estimate_time_offset),
    )


# ----------------------------------------------------------------------------- outputs


def _camera_tf(calib: Calibration, base_T_camera_nominal) -> Tuple[np.ndarray, np.ndarray]:
    T = calib.apply(base_T_camera_nominal)
    return T[:3, 3], np.array(matrix_to_rpy(T[:3, :3]), dtype=float)


def static_tf_yaml(calib: Calibration, base_T_camera_nominal, base_T_prism) -> str:
    """The calibration YAML read by ``live.launch``/``postprocess.launch`` (``ros/static_tfs``):
    ``xyz`` in metres, ``rpy_deg`` in degrees with R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    xyz, rpy = _camera_tf(calib, base_T_camera_nominal)
    Tp = np.asarray(base_T_prism, dtype=float)
    rpy_p = np.array(matrix_to_rpy(Tp[:3, :3]), dtype=float)

    def vec(v, digits: int) -> str:
        return "[" + ", ".join(f"{float(x):.{digits}f}" for x in v) + "]"

    lines = [
        "# written by aruco-abs-orient calibrate",
        "# boresight (deg, in base_link, on top of the nominal mounting): "
        + ", ".join(f"{math.degrees(a):.4f} ± {math.degrees(s):.4f}"
                    for a, s in zip(calib.boresight_rpy, calib.boresight_sigma)),
        f"# bearing residual RMS: {math.degrees(calib.residual_rms_before):.4f} deg before, "
        f"{math.degrees(calib.residual_rms_after):.4f} deg after ({calib.n_used} observations, "
        f"{calib.n_markers} markers)",
        f"base_link_to_camera: {{xyz: {vec(xyz, 5)}, rpy_deg: {vec(np.degrees(rpy), 5)}}}",
    ]
    if np.any(np.abs(rpy_p) > 0):
        lines.append(f"base_link_to_prism: {{xyz: {vec(Tp[:3, 3], 5)}, rpy_deg: {vec(np.degrees(rpy_p), 5)}}}")
    else:
        lines.append(f"base_link_to_prism: {{xyz: {vec(Tp[:3, 3], 5)}}}")
    return "\n".join(lines) + "\n"


def write_static_tf_yaml(path: str, calib: Calibration, base_T_camera_nominal, base_T_prism) -> None:
    """Write :func:`static_tf_yaml` to ``path`` atomically."""
    atomic_write_text(path, static_tf_yaml(calib, base_T_camera_nominal, base_T_prism))


def launch_snippet(calib: Calibration, base_T_camera_nominal, base_T_prism, base_frame: str = "base_link",
                   camera_frame: str = "camera", prism_frame: str = "prism") -> str:
    """``static_transform_publisher`` lines for a launch file (tf2 argument order: x y z yaw pitch roll,
    metres and radians)."""
    xyz, rpy = _camera_tf(calib, base_T_camera_nominal)
    Tp = np.asarray(base_T_prism, dtype=float)
    rpy_p = np.array(matrix_to_rpy(Tp[:3, :3]), dtype=float)
    out = ["<!-- written by aruco-abs-orient calibrate -->"]
    for name, child, p, a in (("camera_tf", camera_frame, xyz, rpy), ("prism_tf", prism_frame, Tp[:3, 3], rpy_p)):
        args = " ".join(f"{float(x):.6f}" for x in (p[0], p[1], p[2], a[2], a[1], a[0]))
        out.append(f'<node pkg="tf2_ros" type="static_transform_publisher" name="{name}" '
                   f'args="{args} {base_frame} {child}"/>')
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------- reading it back

#: keys of the calibration YAML → the child frame each one places on base_link
CALIBRATION_KEYS = {"base_link_to_camera": "camera", "base_link_to_prism": "prism"}


def _vector(entry: dict, key: str, where: str, default=None) -> np.ndarray:
    value = entry.get(key, default)
    if (not isinstance(value, (list, tuple)) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise CalibrationError(f"{where}.{key}: expected [a, b, c] of finite numbers, got {value!r}")
    return np.array(value, dtype=float)


def load_calibration(path: str) -> Dict[str, np.ndarray]:
    """Read a calibration YAML → ``{"camera": base_T_camera, "prism": base_T_prism}`` (4×4, metres).
    Raises CalibrationError naming the file and the key."""
    data = read_yaml(path, CalibrationError)
    if not isinstance(data, dict):
        raise CalibrationError(f"{path}: expected a mapping with {' and '.join(CALIBRATION_KEYS)}")
    out = {}
    for key, child in CALIBRATION_KEYS.items():
        entry = data.get(key)
        where = f"{path}: {key}"
        if not isinstance(entry, dict):
            raise CalibrationError(f"{where}: missing; expected {{xyz: [x, y, z], rpy_deg: [r, p, y]}}")
        xyz = _vector(entry, "xyz", where)
        rpy = np.radians(_vector(entry, "rpy_deg", where, default=[0.0, 0.0, 0.0]))
        out[child] = make_T(rpy_to_matrix(*rpy), xyz)
    return out

"""The calibration problem set up from a recording: the observation model and what it is fitted to.

In: a :class:`~.model.Recording`, :class:`~.model.CalibrationParams` and the prism clock shift of this pass.
Out: a :class:`Setup` that ``solve`` fits: the usable observations with everything interpolated to their times,
the track-heading constraints (against the VO's yaw or its own direction of travel, by ``heading_model``,
weighted by speed, none at standstill or in fast turns), the knots of the map→odom yaw δ(t) and of the
odometry's tilt error θ(t), the markers, and what was skipped and why; :class:`CalibrationError` when the
recording lacks what it needs. The observation model, its unknowns and what separates them are doc/design.md
§11. Metres, radians, seconds; numpy only, Python 3.8.
"""

from __future__ import annotations

import math
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from ..camera import DualFisheye
from ..markers import square_corners
from ..timesync import TimeSyncError, heading_from_track
from ..transforms import quat_to_matrix, rot_z, rotvec_to_matrix, rpy_to_matrix, wrap_angle, yaw_of
from ..tum import Trajectory
from .bias import pattern_bias_sigma
from .model import N_GLOBALS, CalibrationError, CalibrationParams, Recording

__all__ = ["Problem", "Setup", "setup_problem"]

_ALL_GLOBALS = tuple(range(N_GLOBALS))


class _Observed(NamedTuple):
    """The usable observations, interpolated to their (row) times: unit bearings u (N, 3), marker
    positions M (N, 3) m, prism P (N, 3) m and its velocity V (N, 3) m/s in map, odom_R_base (N, 3, 3),
    1-σ (N,) rad, times t (N,) s, image rows (v/H − ½) (N,), the odometry's body rotation rate
    ω (N, 3) rad/s and the marker's corners K (N, 4, 3) m from its centre in map (upright squares facing their
    surveyed normal, or the prism where none was surveyed: a two-lens camera sees a marker across a seam
    through both lenses, corner by corner)."""

    u: np.ndarray
    M: np.ndarray
    P: np.ndarray
    V: np.ndarray
    R_odom: np.ndarray
    sigma: np.ndarray
    t: np.ndarray
    rows: np.ndarray
    omega: np.ndarray
    K: np.ndarray


class _Mounting(NamedTuple):
    """Nominal camera rotation R_bc (3×3), camera origin t_cam and prism t_prism in base_link (m)."""

    R_bc: np.ndarray
    t_cam: np.ndarray
    t_prism: np.ndarray


class _Markers(NamedTuple):
    """The markers of the usable observations: ``ids`` (Nm,), their survey 1-σ ``sigma`` (Nm,) m, and each
    observation's ``index`` (N,) into them."""

    ids: np.ndarray
    sigma: np.ndarray
    index: np.ndarray


class _Track(NamedTuple):
    """The odometry and the sorted, shifted prism track the heading constraints come from."""

    odom: Trajectory
    times: np.ndarray
    positions: np.ndarray


class Problem:
    """Marker observations and heading constraints with everything interpolated to their times.

    The unknowns: the named globals x (``N_GLOBALS``: boresight, lever arm, Δτ, Δρ, lens offset, lens rotation;
    rad, m, s, s, m, rad), of which ``solve`` frees a subset; the knot values d (K,) of δ(t); the odometry's
    tilt error θ at the tilt knots (Kt, 2) rad about map x, y (one knot, a constant, without ``vo_tilt``); and
    each marker's offset from its surveyed position (Nm, 3) m. Δρ changes the rolling-shutter readout the
    observations were interpolated with: an observation on row fraction f moves in time by f·Δρ (its
    odometry rotation by ω f Δρ, its prism by V f Δρ). Per observation the local unknowns are δ, θ and its
    marker's offset (:meth:`local`); :meth:`residuals` takes them at the observations."""

    def __init__(self, obs: _Observed, mounting: _Mounting, track: _Track, heading, knots: np.ndarray,
                 params: CalibrationParams, markers: _Markers, lenses: DualFisheye):
        self.u, self.M, self.P, self.V, self.R_odom, self.sigma = obs.u, obs.M, obs.P, obs.V, obs.R_odom, obs.sigma
        self.rows, self.omega, self.t, self.K = obs.rows, obs.omega, obs.t, obs.K
        self.R_bc, self.t_cam, self.t_prism = mounting
        self.track, self.params = track, params
        self.knots = knots
        self.i_obs, self.a_obs = _knot_weights(knots, obs.t)
        # the odometry's tilt error θ(t) (rad about map x, y), piecewise linear over the tilt knots
        if params.vo_tilt:
            span = max(float(obs.t.max() - obs.t.min()), 1e-3)
            kt = max(2, int(math.ceil(span / params.tilt_knot_spacing)) + 1)
            self.tilt_knots = float(obs.t.min()) + np.linspace(0.0, span, kt)
            self.i_tilt, self.a_tilt = _knot_weights(self.tilt_knots, obs.t)
        else:                                    # one constant tilt error: both slots on knot 0
            self.tilt_knots = np.array([float(obs.t.min())])
            self.i_tilt, self.a_tilt = np.zeros(len(obs.t), dtype=int), np.zeros(len(obs.t))
        self.tilt_sigma = math.radians(params.tilt_sigma_deg)               # rad, prior of each knot
        self.tilt_drift_sigma = math.radians(params.tilt_drift_sigma_deg)   # rad per tilt-knot interval
        self.markers = markers
        self.lenses = lenses
        self.bias = np.zeros((len(obs.t), 2))   # rad, 1-σ of each observation's pattern bias (setup_problem)
        self.set_heading(*heading)
        self.drift_sigma = math.radians(params.drift_sigma_deg)      # rad per knot interval

    def refine_heading(self, d: np.ndarray) -> None:
        """The heading constraints again, with the drift rate of δ(t) of knot values ``d`` (a
        second-order term, see :func:`_heading_constraints`)."""
        tr = self.track
        self.set_heading(*_heading_constraints(tr.odom, tr.times, tr.positions, self.t_prism, self.params,
                                               delta_rate=lambda tt: self.delta_rate(d, tt)))

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

    def local(self, d: np.ndarray, theta: np.ndarray, offsets: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """δ (N,), θ (N, 2) and the marker offset (N, 3) at the observations from the knot values ``d`` (K,),
        the tilt knots ``theta`` (Kt, 2) and the markers' offsets (Nm, 3)."""
        i, a = self.i_tilt, self.a_tilt[:, None]
        j = np.minimum(i + 1, len(self.tilt_knots) - 1)
        return (self.delta_at(d, self.i_obs, self.a_obs), (1.0 - a) * theta[i] + a * theta[j],
                offsets[self.markers.index])

    def lenses_at(self, x) -> DualFisheye:
        """The camera's lenses with the lens offset and rotation changed by x[8], x[9:12]."""
        if x[8] == 0.0 and not np.any(x[9:12]):
            return self.lenses
        return self.lenses.replace(lens_offset=self.lenses.lens_offset + float(x[8]),
                                   lens_rotation=self.lenses.lens_rotation + x[9:12])

    def camera_to_marker(self, x, delta, theta, offsets) -> np.ndarray:
        """Vectors (N, 3) camera → marker in base_link axes (m): map_R_baseᵀ (M + ΔM − P + V Δτ − V f Δρ) −
        (t_cam + Δl − t_prism), map_R_base = Rz(δ) exp([θ]×) odom_R_base exp([ω f Δρ]×)."""
        return self._chain(x, delta, theta, offsets)[1]

    def _chain(self, x, delta, theta, offsets) -> Tuple[np.ndarray, np.ndarray]:
        """map_R_base (N, 3, 3) and the vectors camera → marker (N, 3) of :meth:`camera_to_marker`."""
        w = np.zeros((len(delta), 3))
        w[:, :2] = theta
        R = rot_z(delta) @ rotvec_to_matrix(w) @ self.R_odom                  # map_R_base (N, 3, 3)
        g = self.M + offsets - self.P + self.V * x[6]
        if x[7] != 0.0:
            R = R @ rotvec_to_matrix(self.omega * (self.rows * x[7])[:, None])
            g = g - self.V * (self.rows * x[7])[:, None]
        return R, np.einsum("nji,nj->ni", R, g) - (self.t_cam + x[3:6] - self.t_prism)

    def corner_offsets(self, map_R_base: np.ndarray, Cb: np.ndarray) -> np.ndarray:
        """The markers' corners (N, 4, 3) from their centres in the camera frame (m), for map_R_base (N, 3, 3)
        and the camera's rotation in base_link ``Cb``."""
        return np.einsum("nji,nkj->nki", map_R_base, self.K) @ Cb

    @staticmethod
    def project(lenses: DualFisheye, q: np.ndarray, corners: Optional[np.ndarray]) -> np.ndarray:
        """Stitched bearings (N, 3) of the markers at camera-frame centres ``q`` (N, 3) with ``corners`` (N, 4,
        3) from them (None for a single centre): the diagonals of the corners' images where the lenses have two
        centres."""
        return lenses.project(q) if lenses.single_centre else lenses.project_marker(q, q[:, None, :] + corners)

    def predict(self, x, delta, theta, offsets) -> np.ndarray:
        """Predicted unit bearings (N, 3) in the camera frame: where the camera's stitched image shows the
        markers."""
        R, w = self._chain(x, delta, theta, offsets)
        Cb = rpy_to_matrix(*x[:3]) @ self.R_bc
        lenses = self.lenses_at(x)
        return self.project(lenses, w @ Cb, None if lenses.single_centre else self.corner_offsets(R, Cb))

    def residuals(self, x, delta, theta, offsets) -> np.ndarray:
        return np.cross(self.u, self.predict(x, delta, theta, offsets))

    def linearise(self, x, delta, theta, offsets, free=_ALL_GLOBALS, h: float = 1e-6):
        """The residuals (N, 3) and their derivatives: by the named globals ``free`` (N, 3, N_GLOBALS; the others
        0), by δ (N, 3), by θ about map x and y (N, 3, 2) and by the marker's offset (N, 3, 3) — analytic through
        the rotation chain, by central differences (step ``h``) through the boresight angles and the lenses, by
        forward differences through the two-lens projection."""
        n = len(delta)
        w3 = np.zeros((n, 3))
        w3[:, :2] = theta
        Rz = rot_z(delta)
        A = Rz @ rotvec_to_matrix(w3) @ self.R_odom                          # map_R_base (N, 3, 3)
        G = self.M + offsets - self.P + self.V * x[6]
        fV = self.V * self.rows[:, None]
        if x[7] != 0.0:
            A = A @ rotvec_to_matrix(self.omega * (self.rows * x[7])[:, None])
            G = G - fV * x[7]
        At = np.swapaxes(A, 1, 2)
        AtG = np.einsum("nij,nj->ni", At, G)
        w = AtG - (self.t_cam + x[3:6] - self.t_prism)                        # camera → marker, base_link
        Cb = rpy_to_matrix(*x[:3]) @ self.R_bc
        q = w @ Cb                                                            # in the camera frame
        lenses = self.lenses_at(x)
        lenses_free = [k for k in range(4) if 8 + k in free]               # the lenses: offset, rotation
        corners = None if lenses.single_centre and not lenses_free else self.corner_offsets(A, Cb)
        d = self.project(lenses, q, corners)
        r = np.cross(self.u, d)
        # ∂d/∂q (N, 3, 3)
        if lenses.single_centre:
            Dq = (np.eye(3) - d[:, :, None] * d[:, None, :]) / np.linalg.norm(q, axis=1)[:, None, None]
        else:
            Dq = np.empty((n, 3, 3))
            step = h * np.maximum(np.linalg.norm(q, axis=1), 1e-3)[:, None]
            for k in range(3):    # forward: their O(h) error (1e-6 relative) is far below any σ, at half the cost
                e = np.zeros(3)
                e[k] = 1.0
                Dq[:, :, k] = (self.project(lenses, q + step * e, corners) - d) / step

        def through(dw):      # ∂r for a change dw (N, 3) of the base_link vector w
            return np.cross(self.u, np.einsum("nij,nj->ni", Dq, dw @ Cb))

        Jg = np.zeros((n, 3, len(x)))
        for k in (k for k in range(3) if k in free):    # the boresight: q = (B R_bc)ᵀ w
            e = np.zeros(len(x))
            e[k] = h
            dq = (w @ (rpy_to_matrix(*(x[:3] + e[:3])) @ self.R_bc) - w @ (rpy_to_matrix(*(x[:3] - e[:3])) @ self.R_bc))
            Jg[:, :, k] = np.cross(self.u, np.einsum("nij,nj->ni", Dq, dq / (2 * h)))
        for k in range(3):    # the lever arm: w − Δl
            dw = np.zeros((n, 3))
            dw[:, k] = -1.0
            Jg[:, :, 3 + k] = through(dw)
        Jg[:, :, 6] = through(np.einsum("nij,nj->ni", At, self.V))                          # Δτ: G + V Δτ
        Jg[:, :, 7] = through(-np.cross(self.omega * self.rows[:, None], AtG)
                              - np.einsum("nij,nj->ni", At, fV))                               # Δρ
        for k in lenses_free:
            e = np.zeros(len(x))
            e[8 + k] = h
            plus, minus = self.lenses_at(x + e), self.lenses_at(x - e)
            Jg[:, :, 8 + k] = np.cross(self.u, self.project(plus, q, corners) - self.project(minus, q, corners)) \
                / (2 * h)
        c_delta = through(-np.einsum("nij,nj->ni", At, np.cross(np.array([0.0, 0.0, 1.0]), G)))
        c_theta = np.empty((n, 3, 2))
        for k in range(2):    # θ about map x, y: map_R_base ≈ (I + [Rz(δ) e_k]×) map_R_base
            axis = Rz[:, :, k]
            c_theta[:, :, k] = through(-np.einsum("nij,nj->ni", At, np.cross(axis, G)))
        c_M = np.empty((n, 3, 3))
        for k in range(3):    # the marker's offset: G + ΔM
            c_M[:, :, k] = through(At[:, :, k])
        return r, Jg, c_delta, c_theta, c_M

    def heading_residuals(self, x, d) -> np.ndarray:
        """δ(t) − (travel heading at t − Δτ − odometry yaw), linearised in Δτ (rad)."""
        return wrap_angle(self.delta_at(d, self.i_head, self.a_head) - self.yaw_head + self.rate_head * x[6])


def _body_rates(odom: Trajectory, t: np.ndarray, h: float = 0.02) -> np.ndarray:
    """The odometry's body rotation rate ω (N, 3) rad/s at times ``t``: odom_R_base(t + s) ≈
    odom_R_base(t) exp([ω s]×), from the poses h s either side (zero where they are missing)."""
    _, q0, ok0 = odom.interpolate(t - h)
    _, q1, ok1 = odom.interpolate(t + h)
    A = np.einsum("nji,njk->nik", quat_to_matrix(q0), quat_to_matrix(q1))   # R0ᵀ R1
    w = 0.5 * np.stack([A[:, 2, 1] - A[:, 1, 2], A[:, 0, 2] - A[:, 2, 0], A[:, 1, 0] - A[:, 0, 1]], axis=1)
    return np.where((ok0 & ok1)[:, None], w / (2 * h), 0.0)


def _knot_weights(knots: np.ndarray, t: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    i = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, len(knots) - 2)
    a = (t - knots[i]) / (knots[i + 1] - knots[i])
    return i, a


def _as_array(x, shape_tail, name: str, n: Optional[int] = None) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1 + len(shape_tail) or tuple(a.shape[1:]) != tuple(shape_tail) or (n is not None and len(a) != n):
        want = f"({n if n is not None else 'N'}{''.join(f', {s}' for s in shape_tail)})"
        raise CalibrationError(f"{name}: expected an array of shape {want}, got {a.shape}")
    return a


def _pattern_bias(rec: Recording, params: CalibrationParams, n: int) -> np.ndarray:
    """The 1-σ (rad, (N, 2)) of each observation's pattern bias along the azimuth and the elevation from the
    recording's cell widths and pixel pitch (0 when it has none)."""
    if rec.cell_px is None:
        return np.zeros((n, 2))
    cell = np.asarray(rec.cell_px, dtype=float)
    cell = _as_array(cell, (2,) if cell.ndim == 2 else (), "cell_px", n)
    if not (np.all(cell > 0) and rec.pixel_pitch > 0):      # NaN fails too
        raise CalibrationError("cell_px, pixel_pitch: expected cell widths (px) and a pixel pitch (rad/px) > 0")
    return pattern_bias_sigma(params, rec.pixel_pitch, cell)


def _corners(marker_map, ids: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    """The corners (N, 4, 3) of the markers ``ids`` (N,) from their centres in map (m): upright squares of their
    size facing their surveyed normal, or where none was surveyed the viewpoint (N, 3) they were seen from."""
    markers = [marker_map[int(i)] for i in ids]
    normals = np.array([m.normal if m.normal is not None else v - m.position
                        for m, v in zip(markers, viewpoints)], dtype=float).reshape(-1, 3)
    return square_corners(1.0, normals) * np.array([m.size for m in markers])[:, None, None]


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


def _heading_against_vo_track(odom: Trajectory, t_prism, p_prism, t_prism_lever, params: CalibrationParams, tq):
    """:func:`_heading_constraints` measured against the VO's own direction of travel: the prism track in
    map and the prism track the VO predicts in odom (its positions + its attitude · the lever arm), both
    through the same smoothing (``heading_from_track``), so the smoothing's lag in turns and weaving,
    the lever arm's swing and a crabbing platform cancel; δ = the difference of their directions."""
    vo_prism = odom.positions + np.einsum("nij,j->ni", odom.rotations, t_prism_lever)
    try:
        trk = heading_from_track(t_prism, p_prism, query_t=tq, smooth=params.heading_smooth,
                                 min_speed=params.min_speed)
        vo = heading_from_track(odom.stamps, vo_prism, query_t=tq, smooth=params.heading_smooth,
                                min_speed=params.min_speed)
    except TimeSyncError as e:
        raise CalibrationError(f"prism or odometry track: {e}") from None
    ok = (trk.valid & vo.valid & (np.abs(trk.turn_rate) <= math.radians(params.max_turn_rate_deg)))
    sigma = math.sqrt(2.0) * params.velocity_sigma / np.maximum(trk.speed, 1e-9)
    return tq[ok], wrap_angle(trk.heading - vo.heading)[ok], sigma[ok], trk.turn_rate[ok]


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
        return tq, tq.copy(), tq.copy(), tq.copy()
    if params.heading_model == "vo_track":
        return _heading_against_vo_track(odom, t_prism, p_prism, t_prism_lever, params, tq)
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


class Setup(NamedTuple):
    """:func:`setup_problem`'s result: the ``problem`` over the usable observations ``index`` (into the
    N given), ``usable`` (N,) bool, the ids (N,), and ``skipped`` (reason → count)."""

    problem: Problem
    index: np.ndarray
    usable: np.ndarray
    ids: np.ndarray
    skipped: Dict[str, int]


class _Checked(NamedTuple):
    t: np.ndarray
    ids: np.ndarray
    u: np.ndarray
    sigma: np.ndarray
    prism_times: np.ndarray
    prism_positions: np.ndarray
    base_T_camera: np.ndarray
    base_T_prism: np.ndarray
    rows: np.ndarray


def _checked(rec: Recording) -> _Checked:
    """The recording's arrays, shapes and finiteness checked (CalibrationError naming the field)."""
    t = _as_array(rec.obs_times, (), "obs_times")
    n = len(t)
    ids = np.asarray(rec.obs_ids).ravel()
    if len(ids) != n:
        raise CalibrationError(f"obs_ids: expected {n} ids, got {len(ids)}")
    u = _as_array(rec.bearings, (3,), "bearings", n)
    sig = _as_array(rec.sigmas, (), "sigmas", n)
    tp = _as_array(rec.prism_times, (), "prism_times")
    pp = _as_array(rec.prism_positions, (3,), "prism_positions", len(tp))
    Tc = _as_array(rec.base_T_camera, (4,), "base_T_camera", 4)
    Tp = _as_array(rec.base_T_prism, (4,), "base_T_prism", 4)
    if not (np.all(np.isfinite(Tc)) and np.all(np.isfinite(Tp))):
        raise CalibrationError("base_T_camera/base_T_prism: NaN or inf")
    if n == 0:
        raise CalibrationError("no marker observations in the recording: the calibration needs markers in view")
    if len(tp) < 2:
        raise CalibrationError(f"only {len(tp)} prism positions: the calibration needs the prism track")
    if len(rec.odom.stamps) < 2:
        raise CalibrationError("fewer than 2 odometry poses: the calibration needs odom→base_link")
    rows = np.zeros(n) if rec.obs_rows is None else _as_array(rec.obs_rows, (), "obs_rows", n)
    if not np.all(np.abs(rows) <= 0.5):
        raise CalibrationError("obs_rows: expected image row fractions v/H − ½ in [−0.5, 0.5]")
    return _Checked(t, ids, u, sig, tp, pp, Tc, Tp, rows)


def setup_problem(rec: Recording, params: CalibrationParams, time_shift: float, readout: float = 0.0) -> Setup:
    """The problem of ``rec`` with the prism stamps moved by ``time_shift`` (s) and each observation at its
    row's capture time with the rolling-shutter ``readout`` (s): the usable observations (id in the map,
    finite, prism and odometry at the time), the heading constraints and the knots. Raises
    CalibrationError when too few observations or too little driving remain (saying which)."""
    c = _checked(rec)
    ids, u, sig, rows = c.ids, c.u, c.sigma, c.rows
    t = c.t + rows * readout
    n = len(t)
    order = np.argsort(c.prism_times, kind="stable")
    tp, pp = c.prism_times[order] + time_shift, c.prism_positions[order]

    skipped: Dict[str, int] = {}

    def skip(mask: np.ndarray, reason: str) -> None:
        k = int(np.count_nonzero(mask))
        if k:
            skipped[reason] = skipped.get(reason, 0) + k

    known = np.array([int(i) in rec.marker_map for i in ids], dtype=bool)
    finite = np.isfinite(t) & np.all(np.isfinite(u), axis=1) & np.isfinite(sig) & (sig > 0)
    norm = np.linalg.norm(u, axis=1)
    finite &= norm > 0
    skip(~known, "id not in the marker map")
    skip(known & ~finite, "non-finite bearing, time or sigma")
    keep = known & finite
    P, p_ok = _interp_prism(tp, pp, np.where(keep, t, tp[0]), params.prism_max_gap)
    skip(keep & ~p_ok, "no prism position at the time")
    keep &= p_ok
    _, q_odom, o_ok = rec.odom.interpolate(np.where(keep, t, rec.odom.stamps[0]))
    skip(keep & ~o_ok, "no odometry at the time")
    keep &= o_ok
    idx = np.flatnonzero(keep)
    used_ids = {int(i) for i in ids[idx]}
    mounting = _Mounting(c.base_T_camera[:3, :3].copy(), c.base_T_camera[:3, 3].copy(), c.base_T_prism[:3, 3].copy())
    track = _Track(rec.odom, tp, pp)
    heading = _heading_constraints(rec.odom, tp, pp, mounting.t_prism, params)
    th = heading[0]
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

    M = np.array([rec.marker_map[int(i)].position for i in ids[idx]])
    marker_ids, marker_index = np.unique(ids[idx].astype(int), return_inverse=True)
    markers = _Markers(marker_ids, np.array([rec.marker_map[int(i)].sigma for i in marker_ids]), marker_index)
    t_all = np.concatenate([t[idx], th])
    k0, k1 = float(t_all.min()), float(t_all.max())
    K = max(2, int(math.ceil((k1 - k0) / params.knot_spacing)) + 1)
    knots = k0 + params.knot_spacing * np.arange(K)
    try:
        trk = heading_from_track(tp, pp, t[idx], smooth=params.heading_smooth, min_speed=0.0)
    except TimeSyncError as e:
        raise CalibrationError(f"prism track: {e}") from None
    V = np.zeros((len(idx), 3))
    V[:, 0] = np.where(trk.valid, trk.speed * np.cos(trk.heading), 0.0)
    V[:, 1] = np.where(trk.valid, trk.speed * np.sin(trk.heading), 0.0)
    omega = _body_rates(rec.odom, t[idx]) if np.any(rows[idx]) else np.zeros((len(idx), 3))
    obs = _Observed(u[idx] / norm[idx, None], M, P[idx], V, quat_to_matrix(q_odom[idx]), sig[idx], t[idx],
                    rows[idx], omega, _corners(rec.marker_map, ids[idx], P[idx]))
    pb = Problem(obs, mounting, track, heading, knots, params, markers, rec.lenses)
    zero = np.zeros(len(idx))
    rng = np.maximum(np.linalg.norm(pb.camera_to_marker(np.zeros(N_GLOBALS), zero, np.zeros((len(idx), 2)),
                                                        np.zeros((len(idx), 3))), axis=1), 1e-3)
    pb.sigma = np.sqrt(pb.sigma ** 2 + params.prism_sigma ** 2 / rng ** 2)   # the survey's error: the offsets
    pb.bias = _pattern_bias(rec, params, n)[idx]
    return Setup(pb, idx, keep, ids, skipped)

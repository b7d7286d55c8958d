"""The calibration problem set up from a recording: the observation model and what it is fitted to.

In: a :class:`~.model.Recording`, :class:`~.model.CalibrationParams` and the prism clock shift of this
pass. Out: a :class:`Setup` (the usable observations with everything interpolated to their times, the
track-heading constraints, the knots of δ(t), and what was skipped and why) that ``solve`` fits;
:class:`CalibrationError` when the recording lacks what a parameter needs.

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
tied by a weak random-walk prior so that knots without data stay determined. The VO drifts in tilt
too (its odom frame tilts against gravity, fixed in odom while the platform turns under it): with
``vo_tilt`` (default) ``map_R_base = Rz(δ(t)) · exp([θ(t)]×) · odom_R_base(t)``, θ about map's x and y,
the drift since the first observation: piecewise linear over knots every ``tilt_knot_spacing`` s
(x[N_GLOBALS:]), the first 0, the others tied to 0 by ``tilt_sigma_deg`` and to their neighbour by
``tilt_drift_sigma_deg``. The platform's turning separates θ (fixed in map) from the boresight roll and
pitch (fixed in base_link). Without θ the realistic demo's
0.5°/min tilt drift made the boresight roll 0.21° and yaw 0.35° wrong (σ 0.09°) and the time offset
(σ 8 ms) and readout (σ 156 ms) undetermined; with it 0.002°, 0.020° (σ 0.019°), 0.6 ± 0.2 ms, 33 ± 2 ms.

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
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from ..timesync import TimeSyncError, heading_from_track
from ..transforms import quat_to_matrix, rot_z, rpy_to_matrix, wrap_angle, yaw_of
from ..tum import Trajectory
from .model import N_GLOBALS, CalibrationError, CalibrationParams, Recording

__all__ = ["Problem", "Setup", "setup_problem"]


class _Observed(NamedTuple):
    """The usable observations, interpolated to their (row) times: unit bearings u (N, 3), marker
    positions M (N, 3) m, prism P (N, 3) m and its velocity V (N, 3) m/s in map, odom_R_base (N, 3, 3),
    1-σ (N,) rad, times t (N,) s, image rows (v/H − ½) (N,) and the odometry's body rotation rate
    ω (N, 3) rad/s."""

    u: np.ndarray
    M: np.ndarray
    P: np.ndarray
    V: np.ndarray
    R_odom: np.ndarray
    sigma: np.ndarray
    t: np.ndarray
    rows: np.ndarray
    omega: np.ndarray


class _Mounting(NamedTuple):
    """Nominal camera rotation R_bc (3×3), camera origin t_cam and prism t_prism in base_link (m)."""

    R_bc: np.ndarray
    t_cam: np.ndarray
    t_prism: np.ndarray


class _Track(NamedTuple):
    """The odometry and the sorted, shifted prism track the heading constraints come from."""

    odom: Trajectory
    times: np.ndarray
    positions: np.ndarray


class Problem:
    """Marker observations and heading constraints with everything interpolated to their times.

    The global unknowns are the vector x = (roll, pitch, yaw, Δl_x, Δl_y, Δl_z, Δτ, Δρ) (rad, m, s, s),
    of which ``_solve`` frees a subset; the knot values d of δ(t) are always free. Δρ changes the
    rolling-shutter readout the observations were interpolated with: an observation on row fraction f
    moves in time by f·Δρ (its odometry rotation by ω f Δρ, its prism by V f Δρ)."""

    def __init__(self, obs: _Observed, mounting: _Mounting, track: _Track, heading, knots: np.ndarray,
                 params: CalibrationParams):
        self.u, self.M, self.P, self.V, self.R_odom, self.sigma = obs.u, obs.M, obs.P, obs.V, obs.R_odom, obs.sigma
        self.rows, self.omega, self.t = obs.rows, obs.omega, obs.t
        self.R_bc, self.t_cam, self.t_prism = mounting
        self.track, self.params = track, params
        self.knots = knots
        self.i_obs, self.a_obs = _knot_weights(knots, obs.t)
        # the odometry's tilt error θ(t) (rad about map x, y), piecewise linear over the tilt knots; its knot
        # values follow the named globals in x (x[N_GLOBALS:] = θx, θy of knot 0, knot 1, ...)
        if params.vo_tilt:
            span = max(float(obs.t.max() - obs.t.min()), 1e-3)
            kt = max(2, int(math.ceil(span / params.tilt_knot_spacing)) + 1)
            self.tilt_knots = float(obs.t.min()) + np.linspace(0.0, span, kt)
            self.i_tilt, self.a_tilt = _knot_weights(self.tilt_knots, obs.t)
        else:
            self.tilt_knots = np.zeros(0)
        self.n_x = N_GLOBALS + 2 * len(self.tilt_knots)
        self.tilt_sigma = math.radians(params.tilt_sigma_deg)               # rad, prior of each knot
        self.tilt_drift_sigma = math.radians(params.tilt_drift_sigma_deg)   # rad per tilt-knot interval
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

    def camera_to_marker(self, x, delta) -> np.ndarray:
        """Vectors (N, 3) camera → marker in base_link axes (m): map_R_baseᵀ (M − P + V Δτ − V f Δρ) − (t_cam +
        Δl − t_prism), map_R_base = Rz(δ) odom_R_base exp([ω f Δρ]×)."""
        Rz = rot_z(delta)
        if len(self.tilt_knots):                                         # map_R_base (N, 3, 3)
            R = Rz @ _rotations(self.tilt_at(x)) @ self.R_odom
        else:
            R = Rz @ self.R_odom
        g = self.M - self.P + self.V * x[6]
        if x[7] != 0.0:
            R = R @ _rotations(self.omega * (self.rows * x[7])[:, None])
            g = g - self.V * (self.rows * x[7])[:, None]
        return np.einsum("nji,nj->ni", R, g) - (self.t_cam + x[3:6] - self.t_prism)

    def tilt_at(self, x) -> np.ndarray:
        """The odometry's tilt error θ (N, 3) rad at the observations, a rotation vector about map x, y:
        map_R_base = Rz(δ) · exp([θ]×) · odom_R_base."""
        th = x[N_GLOBALS:].reshape(-1, 2)
        a = self.a_tilt[:, None]
        w = np.zeros((len(self.t), 3))
        w[:, :2] = (1.0 - a) * th[self.i_tilt] + a * th[self.i_tilt + 1]
        return w

    def tilt_indices(self) -> Tuple[int, ...]:
        """Indices in x of the free tilt knots' values (() without ``vo_tilt``): all but the first, which stays
        0 (θ is the drift since the recording's first observation; a constant tilt of odom is what the
        boresight roll and pitch took before, and without turns nothing tells them apart)."""
        return tuple(range(N_GLOBALS + 2, self.n_x))

    def predict(self, x, delta) -> np.ndarray:
        """Predicted unit bearings (N, 3) in the camera frame."""
        q = self.camera_to_marker(x, delta) @ (rpy_to_matrix(*x[:3]) @ self.R_bc)   # (B R_bc)ᵀ g
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    def residuals(self, x, delta) -> np.ndarray:
        return np.cross(self.u, self.predict(x, delta))

    def heading_residuals(self, x, d) -> np.ndarray:
        """δ(t) − (travel heading at t − Δτ − odometry yaw), linearised in Δτ (rad)."""
        return wrap_angle(self.delta_at(d, self.i_head, self.a_head) - self.yaw_head + self.rate_head * x[6])


def _rotations(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of rotation vectors ``w`` (N, 3) rad (Rodrigues)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1.0 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * K + c * (K @ K)


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
    if params.vo_track_heading:
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
    sM = np.array([rec.marker_map[int(i)].sigma for i in ids[idx]])
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
                    rows[idx], omega)
    pb = Problem(obs, mounting, track, heading, knots, params)
    rng = np.maximum(np.linalg.norm(pb.camera_to_marker(np.zeros(pb.n_x), np.zeros(len(idx))), axis=1), 1e-3)
    pb.sigma = np.sqrt(pb.sigma ** 2 + (sM ** 2 + params.prism_sigma ** 2) / rng ** 2)
    return Setup(pb, idx, keep, ids, skipped)

"""Absolute orientation from marker bearings (doc/design.md §7).

Frames (doc/design.md §1): ``map`` (markers, prism), ``base_link`` with attitude
``R = Rz(yaw) · Ry(pitch) · Rx(roll)``, and the camera fixed to base_link by the static
transform ``base_T_camera`` (rotation ``R_bc``, camera origin ``t_camera`` in base_link);
the prism sits at ``prism_in_base`` (= ``t_prism``) in base_link. An observation is a ray in the
camera frame: a unit direction ``u`` and, for a two-lens camera, the ``origin`` of the lens that saw it
(``camera.DualFisheye.rays``; the camera origin by default), so the lever arm of an observation is
``t_camera + R_bc·origin − t_prism``.

* :func:`yaw_from_marker` — one marker + prism position + lever arm + tilt (roll, pitch from
  VO) ⇒ yaw in closed form. With ``b = R_bc u``, ``l = t_camera − t_prism`` (body) and
  ``D = M − P`` (map): ``Rz(ψ)ᵀ D = R_t (l + s b)`` with ``R_t = Ry(θ) Rx(φ)``. Norms give
  ``s² + 2 s (l·b) + |l|² − |D|² = 0`` whose roots have product ``|l|² − |D|²``: exactly one
  is positive when ``|D| > |l|`` (no 4-way ambiguity). ψ is the difference of the
  horizontal azimuths of ``D`` and ``R_t (l + s b)``. σψ is propagated with the analytic
  Jacobian from bearing, prism, survey, tilt and lever-arm noise.
* :func:`attitude_from_markers` — ≥ 2 markers + prism ⇒ roll, pitch, yaw by robust
  (Cauchy/Huber IRLS) Gauss-Newton on SO(3), then least squares on the markers that pass a
  residual gate (false ids dropped, covariance honest), with the prism position as a parameter
  under its measured prior (so the prism noise common to all markers is handled correctly).
* :func:`fuse_yaws` — the per-marker yaws of one frame fused with their correlation (they share
  the prism, tilt and lever-arm errors), false ids gated out.
* :func:`resection` — ≥ 3 markers (≥ 2 with a known tilt), no prism ⇒ position and attitude of base_link;
  degenerate geometry (collinear markers, markers along one line through the camera or in one small cone)
  refused with the reason.

Units: metres, radians, everything in ``map`` unless named otherwise. numpy only,
Python 3.8 compatible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Optional, Tuple

import numpy as np

from .camera import angle_between
from .errors import GeometryError
from .paramspec import Params, param
from .transforms import cross3, make_T, matrix_to_rpy, rot_x, rot_y, rot_z, rpy_to_matrix, wrap_angle

__all__ = [
    "Mounting",
    "NoiseModel",
    "FitSettings",
    "SolverError",
    "DegenerateGeometryError",
    "YawEstimate",
    "AttitudeEstimate",
    "ResectionEstimate",
    "yaw_from_marker",
    "attitude_from_markers",
    "resection",
    "yaw_consensus",
    "FusedYaw",
    "fuse_yaws",
]


class SolverError(GeometryError):
    """Inputs the solver cannot use (wrong shapes, too few markers, non-finite values)."""


class DegenerateGeometryError(SolverError):
    """The geometry does not determine the requested quantity; ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class Mounting(NamedTuple):
    """Where the camera and the prism sit on base_link: ``base_T_camera`` the static transform base_link ←
    camera (4×4), ``prism_in_base`` the prism position in base_link (3,), metres."""

    base_T_camera: np.ndarray
    prism_in_base: np.ndarray


@dataclass(frozen=True)
class NoiseModel:
    """1-σ noise of a solver's inputs (zero: exact). A solver reads the fields its model has.

    - ``bearing``: bearing noise (rad) per axis perpendicular to the bearing; a scalar, or one per marker
      (N,) in :func:`attitude_from_markers` and :func:`resection`.
    - ``prism_cov``: prism position noise: None (exact), a σ (m) or a 3×3 covariance (m²).
    - ``marker``: marker survey σ per axis (m) (``markers.Marker.sigma``); scalar or (N,) like ``bearing``.
    - ``tilt``: σ of roll and of pitch (rad) in :func:`yaw_from_marker` (:func:`resection` takes its own
      ``tilt_sigma``: there it decides whether the tilt is measured at all).
    - ``lever``: σ per axis of the lever arm camera − prism (m), in :func:`yaw_from_marker`.
    """

    bearing: object = 0.0
    prism_cov: object = None
    marker: object = 0.0
    tilt: float = 0.0
    lever: float = 0.0


@dataclass(frozen=True)
class FitSettings(Params):
    """How :func:`attitude_from_markers` and :func:`resection` fit several markers (cfg/params.yaml's ``fit``
    section): two stages, a robust one that finds the outliers, then plain least squares on the rest."""

    error = SolverError

    loss: str = param("cauchy", "robust loss of the first stage", choices=("cauchy", "huber", "none"))
    loss_scale: float = param(2.0, "scale of the robust loss", "σ", above=0.0)
    outlier_gate: Optional[float] = param(4.0, "markers whose normalised residual (|r|/σ, 2-D) exceeds it after the "
                                          "robust stage are dropped and the rest re-solved by least squares (if "
                                          "enough remain); null keeps the robust solution", "σ", above=0.0,
                                          optional=True)
    max_iterations: int = param(50, "Gauss-Newton iterations per stage", "", 1)


#: the smallest angle (rad) between marker directions seen from the camera that determines an attitude (a
#: resection also refuses markers closer than it to one line); the pipeline's attitude update asks more
#: (``attitude_min_spread_deg``)
MIN_SPREAD = math.radians(3.0)
#: a resection whose markers, seen from the camera, all lie within this angle (rad) of each other (one small cone:
#: range and position poorly determined) is refused; the pipeline's is ``resection_min_cone_deg``
MIN_CONE = math.radians(10.0)

_EXACT = NoiseModel()
#: the bearing noise assumed by the multi-marker solvers when the caller gives none (rad)
_MULTI_NOISE = NoiseModel(bearing=1e-3)
_FIT = FitSettings()


class YawEstimate(NamedTuple):
    """Closed-form yaw of base_link from one marker.

    ``yaw`` and ``sigma`` in radians; ``range`` camera→marker distance in metres;
    ``elevation_residual`` (rad) = elevation of ``M − P`` minus the predicted one (zero for
    consistent data: a check on the marker id, the tilt and the lever arm) with its 1-σ
    ``elevation_sigma`` (rad); ``cov`` the 2×2 covariance of (yaw, elevation_residual) in rad²;
    ``camera_position`` the camera centre in map (m). ``shared_gradient`` (8,) is ∂yaw/∂ of the
    inputs every marker of one frame shares — (prism x, y, z in m; roll, pitch in rad; lever arm
    x, y, z in m) — and ``shared_cov`` (8×8) their covariance, for :func:`fuse_yaws`.
    """

    yaw: float
    sigma: float
    range: float
    elevation_residual: float
    elevation_sigma: float
    cov: np.ndarray
    camera_position: np.ndarray
    shared_gradient: np.ndarray
    shared_cov: np.ndarray


class FusedYaw(NamedTuple):
    """Yaw of base_link (rad) fused from the markers of one frame, with its 1-σ ``sigma`` (rad);
    ``normalized`` (N,) each marker's residual over its σ (rad/rad), ``used`` (N,) the markers kept."""

    yaw: float
    sigma: float
    normalized: np.ndarray
    used: np.ndarray


class AttitudeEstimate(NamedTuple):
    """Attitude of base_link from ≥ 2 markers and the prism.

    ``roll``, ``pitch``, ``yaw`` (rad), ``R`` (3×3) = rpy_to_matrix(roll, pitch, yaw); ``cov`` 3×3
    over (roll, pitch, yaw) in rad² from the a-priori σ (variance factor 1);
    ``prism`` the adjusted prism position (m); ``residuals`` (N,) angle between observed
    and predicted bearing (rad); ``normalized`` (N,) residual / its σ; ``weights`` (N,) final
    weights (1 inlier, 0 outlier after the gate; robust weights if the gate left too few);
    ``variance_factor`` Σ w·r²/σ² / redundancy (≈ 1 when the σ
    are right; NaN without redundancy); ``iterations``.
    """

    roll: float
    pitch: float
    yaw: float
    R: np.ndarray
    cov: np.ndarray
    prism: np.ndarray
    residuals: np.ndarray
    normalized: np.ndarray
    weights: np.ndarray
    variance_factor: float
    iterations: int


class ResectionEstimate(NamedTuple):
    """Pose of base_link from ≥ 3 markers, or ≥ 2 with a known tilt (spatial resection).

    ``position`` (3,) base_link origin in map (m); ``roll``, ``pitch``, ``yaw`` (rad); ``R`` 3×3;
    ``map_T_base`` 4×4; ``cov`` 6×6 over (x, y, z, roll, pitch, yaw) in m²/rad²; other fields as
    in :class:`AttitudeEstimate`.
    """

    position: np.ndarray
    roll: float
    pitch: float
    yaw: float
    R: np.ndarray
    map_T_base: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    normalized: np.ndarray
    weights: np.ndarray
    variance_factor: float
    iterations: int


_EX = np.array([1.0, 0.0, 0.0])
_SHARED = [2, 3, 4, 8, 9, 10, 11, 12]   # prism, roll, pitch, lever arm in yaw_from_marker's Jacobian
_EY = np.array([0.0, 1.0, 0.0])


# ----------------------------------------------------------------------------- helpers


def _vec3(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise SolverError(f"{name}: expected 3 finite numbers (metres or a bearing), got {x!r}")
    return a


def _vecs3(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise SolverError(f"{name}: expected an (N, 3) array of finite numbers, got shape {a.shape}")
    return a


def _transform(T, name: str) -> Tuple[np.ndarray, np.ndarray]:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise SolverError(f"{name}: expected a finite 4×4 homogeneous transform")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise SolverError(f"{name}: the rotation block is not a rotation matrix")
    return R, T[:3, 3].copy()


def _cov3(cov, name: str) -> np.ndarray:
    """None → 0; scalar σ (m) → σ²·I; (3, 3) → itself (symmetric, PSD)."""
    if cov is None:
        return np.zeros((3, 3))
    c = np.asarray(cov, dtype=float)
    if c.ndim == 0:
        if not math.isfinite(float(c)) or c < 0:
            raise SolverError(f"{name}: expected a non-negative σ in metres, got {cov!r}")
        return float(c) ** 2 * np.eye(3)
    if c.shape != (3, 3) or not np.all(np.isfinite(c)) or not np.allclose(c, c.T):
        raise SolverError(f"{name}: expected a symmetric 3×3 covariance (m²) or a σ (m)")
    if np.linalg.eigvalsh(c)[0] < -1e-12 * max(1.0, float(np.abs(c).max())):
        raise SolverError(f"{name}: covariance is not positive semi-definite")
    return c


def _tilt(tilt) -> Tuple[float, float]:
    try:
        roll, pitch = (float(x) for x in tilt)
    except (TypeError, ValueError):
        raise SolverError(f"tilt: expected (roll, pitch) in radians, got {tilt!r}") from None
    if not (math.isfinite(roll) and math.isfinite(pitch)):
        raise SolverError(f"tilt: expected finite radians (roll, pitch), got {roll!r}, {pitch!r}")
    return roll, pitch


def _per_marker(x, n: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy() if np.ndim(x) == 0 else np.asarray(x, float)
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise SolverError(f"{name}: expected a non-negative scalar or {n} values")
    return a


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise SolverError("bearing: zero vector")
    return v / n


def _tangent_basis(u: np.ndarray) -> np.ndarray:
    """Orthonormal basis (..., 3, 2) of the plane perpendicular to unit vector(s) u (..., 3)."""
    a = np.where(np.abs(u[..., :1]) < 0.9, _EX, _EY)
    e1 = _unit(cross3(u, a))
    e2 = cross3(u, e1)
    return np.stack([e1, e2], axis=-1)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix(es) (..., 3, 3): skew(v) @ x = v × x (filled in place: called per observation)."""
    S = np.zeros(v.shape[:-1] + (3, 3))
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    S[..., 0, 1] = -w
    S[..., 0, 2] = y
    S[..., 1, 0] = w
    S[..., 1, 2] = -x
    S[..., 2, 0] = -y
    S[..., 2, 1] = x
    return S


def _so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of rotation vector w (3,) (radians), Rodrigues."""
    th = float(np.linalg.norm(w))
    K = _skew(w)
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + math.sin(th) / th * K + (1 - math.cos(th)) / th ** 2 * K @ K


def _azimuth_gradient(x: np.ndarray) -> np.ndarray:
    h2 = x[0] ** 2 + x[1] ** 2
    return np.array([-x[1], x[0], 0.0]) / h2


def _elevation_gradient(x: np.ndarray) -> np.ndarray:
    h = math.hypot(x[0], x[1])
    return np.array([-x[2] * x[0] / h, -x[2] * x[1] / h, h]) / float(x @ x)


def _elevation(x: np.ndarray) -> float:
    return math.atan2(x[2], math.hypot(x[0], x[1]))


def _rpy_jacobian(R: np.ndarray) -> np.ndarray:
    """∂(roll, pitch, yaw)/∂δ (3×3) for the body-frame perturbation R·Exp(δ), by central differences."""
    K = np.empty((3, 3))
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        a = np.array(matrix_to_rpy(R @ _so3_exp(d)))
        b = np.array(matrix_to_rpy(R @ _so3_exp(-d)))
        K[:, k] = wrap_angle(a - b) / (2 * h)
    return K


# ----------------------------------------------------------------------------- one marker


def yaw_from_marker(bearing, marker, prism, tilt: Tuple[float, float], mounting: Mounting,
                    noise: NoiseModel = _EXACT, *, min_range: float = 0.1,
                    min_horizontal: float = 0.02, origin=None) -> YawEstimate:
    """Yaw of base_link (rad) from one marker bearing, in closed form.

    Args:
        bearing: bearing of the marker centre in the camera frame (3,), any length (normalised here).
        marker: surveyed marker centre M in map (3,), metres.
        prism: prism position P in map (3,), metres.
        tilt: (roll, pitch) of base_link (rad), e.g. from VO (map→odom is yaw only).
        mounting: the camera's and the prism's place on base_link (:class:`Mounting`).
        noise: σ of the bearing, prism, marker survey, tilt and lever arm (:class:`NoiseModel`; a scalar
            bearing and marker σ here), propagated to the yaw's σ.
        min_range: smallest accepted camera→marker range (m).
        min_horizontal: smallest accepted ratio horizontal/total length of ``M − P`` and of the
            predicted vector (below it the azimuth is ill-defined: marker straight above/below).
        origin: where the bearing's ray starts in the camera frame (3,), m (a lens centre); default the origin.

    Raises:
        DegenerateGeometryError: ``|M − P| ≤ |l|`` (marker within the lever arm of the prism:
            no positive range), range < ``min_range``, or a nearly vertical ``M − P``.
        SolverError: malformed inputs.
    """
    u = _unit(_vec3(bearing, "bearing"))
    M = _vec3(marker, "marker")
    P = _vec3(prism, "prism")
    R_bc, t_cam = _transform(mounting.base_T_camera, "base_T_camera")
    t_prism = _vec3(mounting.prism_in_base, "prism_in_base")
    Cp = _cov3(noise.prism_cov, "prism_cov")
    roll, pitch = _tilt(tilt)

    l = t_cam - t_prism  # noqa: E741  (the lever arm, as in doc/design.md §7)
    if origin is not None:
        l = l + R_bc @ _vec3(origin, "origin")  # noqa: E741
    b = R_bc @ u
    D = M - P
    d2 = float(D @ D)
    lb = float(l @ b)
    disc = lb * lb - float(l @ l) + d2
    if d2 <= float(l @ l) or disc <= 0:
        raise DegenerateGeometryError(
            f"marker is {math.sqrt(d2):.3f} m from the prism, not beyond the lever arm "
            f"{float(np.linalg.norm(l)):.3f} m: no unique positive range")
    root = math.sqrt(disc)
    s = root - lb
    if s < min_range:
        raise DegenerateGeometryError(f"camera→marker range {s:.3f} m is below min_range {min_range} m")
    v = l + s * b
    Rt = rot_y(pitch) @ rot_x(roll)
    w = Rt @ v
    for name, x in (("marker − prism", D), ("predicted marker direction", w)):
        if math.hypot(x[0], x[1]) < min_horizontal * float(np.linalg.norm(x)):
            raise DegenerateGeometryError(f"{name} is nearly vertical: the azimuth (yaw) is ill-defined")
    yaw = float(wrap_angle(math.atan2(D[1], D[0]) - math.atan2(w[1], w[0])))
    elev_res = _elevation(D) - _elevation(w)

    # Jacobian of (yaw, elevation residual) w.r.t. z = [bearing tangent (2), P (3), M (3), roll, pitch, l (3)].
    E = R_bc @ _tangent_basis(u)                    # db = E dα
    ds_dD = D / root
    ds_dl = -v / root
    ds_db = -s * l / root
    # dv = dl + b ds + s db; dw = Rt dv + Rt (e_x × v) dφ + e_y × w dθ
    dv_db = np.outer(b, ds_db) + s * np.eye(3)
    dw_dalpha = Rt @ dv_db @ E
    dw_dD = Rt @ np.outer(b, ds_dD)
    dw_dl = Rt @ (np.eye(3) + np.outer(b, ds_dl))
    dw_droll = Rt @ cross3(_EX, v)
    dw_dpitch = cross3(_EY, w)
    J = np.empty((2, 13))
    for row, (gD, gw) in enumerate(((_azimuth_gradient(D), _azimuth_gradient(w)),
                                    (_elevation_gradient(D), _elevation_gradient(w)))):
        dD_total = gD - gw @ dw_dD          # ∂/∂D through both D and s(D)
        J[row, 0:2] = -gw @ dw_dalpha
        J[row, 2:5] = -dD_total                     # D = M − P
        J[row, 5:8] = dD_total
        J[row, 8] = -gw @ dw_droll
        J[row, 9] = -gw @ dw_dpitch
        J[row, 10:13] = -gw @ dw_dl
    Sigma = np.zeros((13, 13))
    Sigma[0:2, 0:2] = noise.bearing ** 2 * np.eye(2)
    Sigma[2:5, 2:5] = Cp
    Sigma[5:8, 5:8] = noise.marker ** 2 * np.eye(3)
    Sigma[8:10, 8:10] = noise.tilt ** 2 * np.eye(2)
    Sigma[10:13, 10:13] = noise.lever ** 2 * np.eye(3)
    cov = J @ Sigma @ J.T
    camera = P + rot_z(yaw) @ Rt @ l
    return YawEstimate(yaw, math.sqrt(max(cov[0, 0], 0.0)), s, float(elev_res),
                       math.sqrt(max(cov[1, 1], 0.0)), cov, camera, J[0, _SHARED].copy(),
                       Sigma[np.ix_(_SHARED, _SHARED)])


def fuse_yaws(estimates, gate: Optional[float] = 4.0) -> FusedYaw:
    """Fuse the per-marker yaws of one frame (:func:`yaw_from_marker`, same prism, tilt and lever arm).

    Their errors are correlated through the shared inputs (prism, tilt, lever arm), so they are
    combined by generalised least squares with the full covariance
    ``C_ij = g_i Σ g_jᵀ + δ_ij·(own variance_i)``; treating them as independent would overstate the
    precision. Outliers (false ids): a consensus first (:func:`yaw_consensus`), then the marker with
    the largest normalised residual beyond ``gate`` is dropped until all pass (None: keep all).

    Returns :class:`FusedYaw`. Raises SolverError for an empty list.
    """
    est = list(estimates)
    if not est:
        raise SolverError("fuse_yaws: no yaw estimates")
    y = np.array([e.yaw for e in est])
    G = np.array([e.shared_gradient for e in est])
    S = est[0].shared_cov
    shared = G @ S @ G.T
    own = np.maximum(np.array([e.sigma ** 2 for e in est]) - np.diag(shared), 0.0)
    C = shared + np.diag(own)
    ref = y[0]
    used = yaw_consensus(y, np.sqrt(np.diag(C)))[1] if len(est) > 2 else np.ones(len(est), bool)
    while True:
        idx = np.flatnonzero(used)
        Ci = np.linalg.pinv(C[np.ix_(idx, idx)])
        info = float(Ci.sum())
        off = wrap_angle(y - ref)
        mean = float(Ci.sum(axis=0) @ off[idx]) / info
        res = wrap_angle(off - mean)
        # residual variance: C_ii − 2·cov(y_i, ŷ) + var(ŷ), with cov(y_i, ŷ) = (C[i, idx] Ci 1) / info
        cov_i_hat = C[:, idx] @ Ci.sum(axis=1) / info
        var_res = np.maximum(np.diag(C) - 2 * cov_i_hat + 1.0 / info, 1e-30)
        z = np.abs(res) / np.sqrt(var_res)
        if gate is None or len(idx) <= 1 or z[idx].max() <= gate:
            break
        used[idx[int(np.argmax(z[idx]))]] = False
    return FusedYaw(float(wrap_angle(ref + mean)), math.sqrt(1.0 / info), z, used)


# ----------------------------------------------------------------------------- several markers


def _robust_weights(e: np.ndarray, loss: str, k: float) -> np.ndarray:
    if loss == "huber":
        return np.where(e <= k, 1.0, k / np.maximum(e, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (e / k) ** 2)
    return np.ones_like(e)


class _Fit(NamedTuple):
    R: np.ndarray
    p: np.ndarray
    cov: np.ndarray          # over [δ (body rotation vector), p] (6×6) or δ only (3×3)
    residuals: np.ndarray
    normalized: np.ndarray
    weights: np.ndarray
    variance_factor: float
    iterations: int


class _Problem(NamedTuple):
    """What :func:`_gauss_newton` fits: observed unit bearings ``u_obs`` (N, 3) of the markers ``M`` (N, 3, m)
    with their σ ``sigma_b`` (N,, rad) and ``sigma_m`` (N,, m); the camera's rotation ``R_bc`` and offset ``a``
    (3,) or per bearing (N, 3), m, from the reference point p in base_link (the ray's origin: a lens centre);
    ``prior`` None or (p_measured, L⁻¹) with L Lᵀ its covariance (m²); ``estimate_p`` whether p is a parameter;
    ``tilt_prior`` None or (roll, pitch, σ) in rad (a measured tilt: IMU, odometry); ``min_inliers`` the fewest
    markers for the least-squares stage."""

    u_obs: np.ndarray
    M: np.ndarray
    sigma_b: np.ndarray
    sigma_m: np.ndarray
    R_bc: np.ndarray
    a: np.ndarray
    prior: Optional[Tuple[np.ndarray, np.ndarray]]
    estimate_p: bool
    tilt_prior: Optional[Tuple[float, float, float]]
    min_inliers: int


def _gauss_newton(pb: _Problem, R0: np.ndarray, p0: np.ndarray, settings: FitSettings) -> _Fit:
    """Robust GN over R (right perturbation R·Exp(δ)) and, if ``pb.estimate_p``, the reference point p,
    from the start (R0, p0).

    Model: camera C = p + R a; predicted camera bearing ``R_bcᵀ Rᵀ (M − C) / |·|``; residual its
    difference from the observed bearing in the observed bearing's tangent plane (≈ rad); a prism
    ``prior`` and a ``tilt_prior`` (:class:`_Problem`) add observations.

    Two stages: IRLS with the robust ``settings.loss`` finds the outliers; then, if at least
    ``min_inliers`` markers have normalised residuals ≤ ``settings.outlier_gate``, plain least squares on
    those (weights 1/0) gives the estimate and an honest covariance. Otherwise the robust solution is kept.
    """
    u_obs, M, sigma_b, sigma_m, R_bc, a, prior, estimate_p, tilt_prior, min_inliers = pb
    loss, loss_scale, outlier_gate = settings.loss, settings.loss_scale, settings.outlier_gate
    max_iterations = settings.max_iterations
    n = len(M)
    npar = 6 if estimate_p else 3
    E = _tangent_basis(u_obs)                                   # (N, 3, 2)
    use_prior = prior is not None and estimate_p

    def linearise(R, p, loss, mask):
        """Predicted bearings, normalised residuals, weights, normal equations and χ² at (R, p)."""
        g = (M - p) @ R                                         # Rᵀ(M − p), (N, 3)
        q = g - a
        rng = np.linalg.norm(q, axis=1)
        if np.any(rng < 1e-6):
            raise DegenerateGeometryError("a marker coincides with the camera")
        qh = q / rng[:, None]
        u_pred = qh @ R_bc
        r = np.einsum("nij,ni->nj", E, u_pred - u_obs)
        sig = np.sqrt(sigma_b ** 2 + (sigma_m / rng) ** 2)
        dq = np.concatenate([_skew(g), np.broadcast_to(-R.T, (n, 3, 3))], axis=2)[:, :, :npar]
        dnorm = (np.eye(3) - qh[:, :, None] * qh[:, None, :]) / rng[:, None, None]
        J = np.einsum("nij,ki,nkl,nlm->njm", E, R_bc, dnorm, dq)
        e = np.linalg.norm(r, axis=1) / sig
        w = _robust_weights(e, loss, loss_scale) * mask
        H = np.einsum("n,nji,njk->ik", w / sig ** 2, J, J)
        gvec = np.einsum("n,nji,nj->i", w / sig ** 2, J, r)
        chi2 = float(np.sum(w * e ** 2))
        if use_prior:
            pm, Linv = prior
            rp = Linv @ (p - pm)
            H[3:, 3:] += Linv.T @ Linv
            gvec[3:] += Linv.T @ rp
            chi2 += float(rp @ rp)
        if tilt_prior is not None:
            r0, p0_, st = tilt_prior
            Jt = _rpy_jacobian(R)[:2] / st
            rt = wrap_angle(np.array(matrix_to_rpy(R)[:2]) - np.array([r0, p0_])) / st
            H[:3, :3] += Jt.T @ Jt
            gvec[:3] += Jt.T @ rt
            chi2 += float(rt @ rt)
        return u_pred, e, w, H, gvec, chi2

    def solve(R, p, loss, mask):
        it = 0
        for it in range(1, max_iterations + 1):  # noqa: B007  (it is reported)
            H, gvec = linearise(R, p, loss, mask)[3:5]
            cond = np.linalg.cond(H)
            if not math.isfinite(cond) or cond > 1e14:
                raise DegenerateGeometryError("the normal equations are singular: the markers do not "
                                              "determine the pose (collinear or too few)")
            step = -np.linalg.solve(H, gvec)
            R = R @ _so3_exp(step[:3])
            if estimate_p:
                p = p + step[3:]
            if np.linalg.norm(step) < 1e-13:
                break
        return R, p, it

    mask = np.ones(n)
    R, p, iterations = solve(R0.copy(), p0.copy(), loss, mask)
    final_loss = loss
    if loss != "none" and outlier_gate is not None:
        inliers = linearise(R, p, "none", mask)[1] <= outlier_gate
        if int(inliers.sum()) >= min_inliers:
            mask = inliers.astype(float)
            final_loss = "none"
            R, p, it2 = solve(R, p, "none", mask)
            iterations += it2
    u_pred, e, weights, H, _, chi2 = linearise(R, p, final_loss, mask)
    dof = 2 * int(np.count_nonzero(mask)) + (3 if use_prior else 0) + (2 if tilt_prior is not None else 0) - npar
    vf = chi2 / dof if dof > 0 else float("nan")
    return _Fit(R, p, np.linalg.inv(H), angle_between(u_pred, u_obs), e, weights, vf, iterations)


def _check_spread(directions: np.ndarray, min_spread: float, what: str) -> None:
    d = _unit(directions)
    sin = np.linalg.norm(cross3(d[:, None, :], d[None, :, :]), axis=-1)
    if float(sin.max()) < math.sin(min_spread):
        raise DegenerateGeometryError(
            f"{what} lie within {math.degrees(math.asin(min(1.0, float(sin.max())))):.2f}° of one line "
            f"(min_spread {math.degrees(min_spread):.2f}°): the rotation about it is unobservable")


def _check_cone(directions: np.ndarray, min_spread: float, min_cone: float) -> None:
    """Refuse markers seen from the camera along one line through it (``min_spread``, rad) or within one
    small cone (largest pairwise angle below ``min_cone``, rad)."""
    _check_spread(directions, min_spread, "the markers seen from the camera (collinear with it)")
    d = _unit(directions)
    widest = float(np.max(np.arccos(np.clip(d @ d.T, -1.0, 1.0))))
    if widest < min_cone:
        raise DegenerateGeometryError(
            f"the markers lie within a cone of {math.degrees(widest):.1f}° seen from the camera (min_cone "
            f"{math.degrees(min_cone):.1f}°): the position along it is poorly determined")


def yaw_consensus(yaws, sigmas, floor: float = math.radians(0.5)) -> Tuple[float, np.ndarray]:
    """Robust mean of yaw samples (rad) with 1-σ ``sigmas`` (rad): the sample with the most others
    within ``max(3·hypot(σi, σj), floor)`` of it, averaged (weighted, on the circle) with them.

    Returns the yaw (rad, wrapped) and the boolean mask (N,) of the samples used (false ids and
    outliers are left out).
    """
    yaws = np.asarray(yaws, dtype=float)
    sigmas = np.asarray(sigmas, dtype=float)
    if yaws.ndim != 1 or yaws.shape != sigmas.shape or len(yaws) == 0:
        raise SolverError("yaw_consensus: expected equally long, non-empty 1-D yaws and sigmas")
    diffs = np.abs(wrap_angle(yaws[:, None] - yaws[None, :]))
    tol = np.maximum(3.0 * np.hypot(sigmas[:, None], sigmas[None, :]), floor)
    support = (diffs <= tol).sum(axis=1)
    best = int(np.argmax(support))
    members = diffs[best] <= tol[best]
    wts = 1.0 / np.maximum(sigmas[members], 1e-9) ** 2
    offs = wrap_angle(yaws[members] - yaws[best])
    return float(wrap_angle(yaws[best] + np.sum(wts * offs) / np.sum(wts))), members


def attitude_from_markers(bearings, markers, prism, mounting: Mounting, *, noise: NoiseModel = _MULTI_NOISE,
                          tilt: Tuple[float, float] = (0.0, 0.0), initial_yaw: Optional[float] = None,
                          settings: FitSettings = _FIT, min_spread: float = MIN_SPREAD,
                          origins=None) -> AttitudeEstimate:
    """Full attitude of base_link from ≥ 2 marker bearings and the prism position.

    Args:
        bearings: (N, 3) marker-centre bearings in the camera frame (normalised here).
        markers: (N, 3) surveyed marker centres in map (m), same order.
        prism: prism position in map (3,), m.
        mounting: the camera's and the prism's place on base_link (:class:`Mounting`).
        noise: ``bearing`` σ (rad, scalar or (N,)); ``prism_cov`` None (prism exact), a σ (m) or a 3×3
            covariance (m²): when given, the prism position is adjusted under this prior and its noise
            enters the covariance; ``marker`` survey σ (m, scalar or (N,)), added as σ_M/range to the
            bearing σ. Default: 1 mrad bearings, the rest exact.
        tilt: (roll, pitch) in rad to start from (VO tilt); yaw starts from the consensus of the
            per-marker closed-form yaws (:func:`yaw_from_marker`), else ``initial_yaw``.
        settings: the robust loss, the outlier gate (the least-squares stage needs ≥ 2 markers left) and the
            iterations (:class:`FitSettings`).
        min_spread: the smallest angle (rad) between the markers' directions from the camera.
        origins: (N, 3) where each bearing's ray starts in the camera frame (m, lens centres); default the origin.

    Raises:
        DegenerateGeometryError: all markers in one direction (or opposite) from the camera,
            singular normal equations, or no usable start yaw.
        SolverError: fewer than 2 markers or malformed inputs.
    """
    u = _unit(_vecs3(bearings, "bearings"))
    M = _vecs3(markers, "markers")
    n = len(u)
    if n < 2 or len(M) != n:
        raise SolverError(f"attitude_from_markers: need ≥ 2 bearings with as many markers, got {n} and {len(M)}")
    P = _vec3(prism, "prism")
    R_bc, t_cam = _transform(mounting.base_T_camera, "base_T_camera")
    t_prism = _vec3(mounting.prism_in_base, "prism_in_base")
    Cp = _cov3(noise.prism_cov, "prism_cov")
    sb = _per_marker(noise.bearing, n, "sigma_bearing")
    sm = _per_marker(noise.marker, n, "marker_sigma")
    roll0, pitch0 = _tilt(tilt)
    o = np.zeros((n, 3)) if origins is None else _vecs3(origins, "origins")

    yaws, sigs = [], []
    for i in range(n):
        try:
            est = yaw_from_marker(u[i], M[i], P, (roll0, pitch0), Mounting(mounting.base_T_camera, t_prism),
                                  NoiseModel(bearing=float(sb[i]), prism_cov=Cp, marker=float(sm[i])), origin=o[i])
        except DegenerateGeometryError:
            continue
        yaws.append(est.yaw)
        sigs.append(est.sigma)
    if yaws:
        yaw0 = yaw_consensus(yaws, sigs, floor=math.radians(2.0))[0]
    elif initial_yaw is not None:
        yaw0 = float(initial_yaw)
    else:
        raise DegenerateGeometryError("no marker gives a closed-form yaw to start from and no initial_yaw")
    R0 = rpy_to_matrix(roll0, pitch0, yaw0)
    C0 = P + R0 @ (t_cam - t_prism)
    _check_spread(M - C0, min_spread, "the markers seen from the camera")

    estimate_p = bool(np.any(Cp != 0))
    prior = None
    if estimate_p:
        try:
            Linv = np.linalg.inv(np.linalg.cholesky(Cp))
        except np.linalg.LinAlgError:
            raise SolverError("prism_cov: must be positive definite (or None for an exact prism)") from None
        prior = (P, Linv)
    fit = _gauss_newton(_Problem(u, M, sb, sm, R_bc, t_cam - t_prism + o @ R_bc.T, prior, estimate_p, None, 2), R0,
                        P.copy(), settings)
    K = _rpy_jacobian(fit.R)
    cov = K @ fit.cov[:3, :3] @ K.T
    r, pch, y = (float(x) for x in matrix_to_rpy(fit.R))
    return AttitudeEstimate(r, pch, y, fit.R, cov, fit.p, fit.residuals, fit.normalized, fit.weights,
                            fit.variance_factor, fit.iterations)


def _scan_yaw(d_level: np.ndarray, M: np.ndarray, steps: int = 720) -> Tuple[float, np.ndarray]:
    """Start yaw (rad) and camera centre (m) for resection: for each yaw on a grid, intersect the
    rays ``M_i − s Rz(ψ) d_i`` by least squares and score the angular misfit."""
    psi = np.linspace(-math.pi, math.pi, steps, endpoint=False)
    d = np.einsum("gij,nj->gni", rot_z(psi), d_level)                        # (G, N, 3)
    A = np.eye(3) - d[..., :, None] * d[..., None, :]                         # (G, N, 3, 3)
    C = np.linalg.solve(A.sum(axis=1) + 1e-12 * np.eye(3), np.einsum("gnij,nj->gi", A, M))
    v = M[None] - C[:, None]                                                  # (G, N, 3)
    ang = np.arctan2(np.linalg.norm(cross3(v, d), axis=-1), np.sum(v * d, axis=-1))  # behind ⇒ > π/2
    cost = np.sum(ang ** 2, axis=1)
    g = int(np.argmin(cost))
    return float(psi[g]), C[g]


def resection(bearings, markers, base_T_camera, *, noise: NoiseModel = _MULTI_NOISE,
              tilt: Tuple[float, float] = (0.0, 0.0), tilt_sigma: Optional[float] = None, initial_pose=None,
              settings: FitSettings = _FIT, min_spread: float = MIN_SPREAD, min_cone: float = MIN_CONE,
              origins=None) -> ResectionEstimate:
    """Position and attitude of base_link from ≥ 3 marker bearings (no prism), or from ≥ 2 when the
    tilt is known (``tilt_sigma`` given).

    Args:
        bearings: (N, 3) bearings in the camera frame; markers: (N, 3) centres in map (m).
        base_T_camera: static transform base_link ← camera (4×4).
        noise: the ``bearing`` and ``marker`` σ, as in :func:`attitude_from_markers` (no prism here).
        tilt: (roll, pitch) (rad) assumed for the start (small-tilt platforms: the default 0, 0).
        tilt_sigma: None (tilt free, ≥ 3 markers) or the 1-σ (rad) of ``tilt`` as a measurement (an IMU's or
            the odometry's roll and pitch): it enters the adjustment and ≥ 2 markers suffice.
        initial_pose: optional map_T_base (4×4) start instead of the yaw scan. Two markers with a known tilt
            can have two solutions: give the predicted pose to get the one near it.
        settings: :class:`FitSettings`: the loss and outlier gate (at least 3 inliers, 2 with a known tilt,
            are needed for the least-squares stage).
        min_spread, min_cone: markers closer than ``min_spread`` (rad) to one line (collinear), or seen from the
            camera along one line through it, and markers whose directions from the camera all lie within
            ``min_cone`` (rad) of each other are degenerate.
        origins: (N, 3) where each bearing's ray starts in the camera frame (m, lens centres); default the origin.

    Raises:
        DegenerateGeometryError: collinear markers, markers collinear with the camera or in one small
            cone, singular normal equations; ``reason`` says which.
        SolverError: too few markers or malformed inputs.
    """
    u = _unit(_vecs3(bearings, "bearings"))
    M = _vecs3(markers, "markers")
    n = len(u)
    need = 3 if tilt_sigma is None else 2
    if n < need or len(M) != n:
        raise SolverError(f"resection: need ≥ {need} bearings with as many markers"
                          f"{'' if tilt_sigma is None else ' (tilt known)'}, got {n} and {len(M)}")
    if tilt_sigma is not None and not (math.isfinite(tilt_sigma) and tilt_sigma > 0):
        raise SolverError(f"tilt_sigma: expected a positive σ in radians, got {tilt_sigma!r}")
    R_bc, t_cam = _transform(base_T_camera, "base_T_camera")
    sb = _per_marker(noise.bearing, n, "sigma_bearing")
    sm = _per_marker(noise.marker, n, "marker_sigma")
    roll0, pitch0 = _tilt(tilt)
    centred = M - M.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] == 0 or (tilt_sigma is None and sv[1] < math.tan(min_spread) * sv[0]):
        raise DegenerateGeometryError("the markers are (nearly) collinear: the rotation about their line "
                                      "and the position around it are not determined")
    if initial_pose is not None:
        R0, p0 = _transform(initial_pose, "initial_pose")
    else:
        Rt = rot_y(pitch0) @ rot_x(roll0)
        yaw0, C0 = _scan_yaw(u @ (Rt @ R_bc).T, M)
        R0 = rpy_to_matrix(roll0, pitch0, yaw0)
        p0 = C0 - R0 @ t_cam
    tilt_prior = None if tilt_sigma is None else (roll0, pitch0, float(tilt_sigma))
    a = t_cam if origins is None else t_cam + _vecs3(origins, "origins") @ R_bc.T
    fit = _gauss_newton(_Problem(u, M, sb, sm, R_bc, a, None, True, tilt_prior, need), R0, p0, settings)
    used = fit.weights > 0.5 if np.count_nonzero(fit.weights > 0.5) >= need else np.ones(n, bool)
    _check_cone(M[used] - (fit.p + fit.R @ t_cam), min_spread, min_cone)
    K = _rpy_jacobian(fit.R)
    T = np.zeros((6, 6))
    T[:3, 3:] = np.eye(3)          # position block: p (map, additive)
    T[3:, :3] = K                  # rpy from the body rotation vector
    cov = T @ fit.cov @ T.T
    r, pch, y = (float(x) for x in matrix_to_rpy(fit.R))
    return ResectionEstimate(fit.p, r, pch, y, fit.R, make_T(fit.R, fit.p), cov, fit.residuals,
                             fit.normalized, fit.weights, fit.variance_factor, fit.iterations)

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
* :func:`fuse_yaws` — the per-marker yaws of one frame fused with their correlation (they share
  the prism, tilt and lever-arm errors), false ids gated out; :func:`yaw_consensus` their robust mean.
* The inputs and settings every solver shares: :class:`Mounting`, :class:`NoiseModel`, :class:`FitSettings`
  and the errors. The fits of several markers (attitude with a prism, resection without) are ``posefit.py``'s.

Units: metres, radians, everything in ``map`` unless named otherwise. numpy only,
Python 3.8 compatible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Optional, Tuple

import numpy as np

from .errors import GeometryError
from .paramspec import Params, param
from .transforms import cross3, rot_x, rot_y, rot_z, wrap_angle

__all__ = [
    "Mounting",
    "NoiseModel",
    "FitSettings",
    "SolverError",
    "DegenerateGeometryError",
    "YawEstimate",
    "yaw_from_marker",
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


_EXACT = NoiseModel()


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


def _azimuth_gradient(x: np.ndarray) -> np.ndarray:
    h2 = x[0] ** 2 + x[1] ** 2
    return np.array([-x[1], x[0], 0.0]) / h2


def _elevation_gradient(x: np.ndarray) -> np.ndarray:
    h = math.hypot(x[0], x[1])
    return np.array([-x[2] * x[0] / h, -x[2] * x[1] / h, h]) / float(x @ x)


def _elevation(x: np.ndarray) -> float:
    return math.atan2(x[2], math.hypot(x[0], x[1]))


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
    s, root = _marker_range(l, b, D, min_range)
    v = l + s * b
    Rt = rot_y(pitch) @ rot_x(roll)
    w = Rt @ v
    for name, x in (("marker − prism", D), ("predicted marker direction", w)):
        if math.hypot(x[0], x[1]) < min_horizontal * float(np.linalg.norm(x)):
            raise DegenerateGeometryError(f"{name} is nearly vertical: the azimuth (yaw) is ill-defined")
    yaw = float(wrap_angle(math.atan2(D[1], D[0]) - math.atan2(w[1], w[0])))
    elev_res = _elevation(D) - _elevation(w)

    J = _yaw_jacobian(R_bc @ _tangent_basis(u), l, b, D, s, root, Rt)
    Sigma = _input_cov(noise, Cp)
    cov = J @ Sigma @ J.T
    camera = P + rot_z(yaw) @ Rt @ l
    return YawEstimate(yaw, math.sqrt(max(cov[0, 0], 0.0)), s, float(elev_res),
                       math.sqrt(max(cov[1, 1], 0.0)), cov, camera, J[0, _SHARED].copy(),
                       Sigma[np.ix_(_SHARED, _SHARED)])


def _marker_range(l: np.ndarray, b: np.ndarray, D: np.ndarray, min_range: float) -> Tuple[float, float]:  # noqa: E741
    """The camera→marker range s (m) along the body bearing ``b`` from ``|l + s b| = |D|`` (the positive root),
    and the square root of the discriminant (m); refused when the marker is within the lever arm ``l`` of the
    prism (``D`` = marker − prism) or nearer than ``min_range``."""
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
    return s, root


def _yaw_jacobian(E: np.ndarray, l: np.ndarray, b: np.ndarray, D: np.ndarray, s: float, root: float,  # noqa: E741
                  Rt: np.ndarray) -> np.ndarray:
    """Jacobian (2×13) of (yaw, elevation residual) of :func:`yaw_from_marker` w.r.t. z = [bearing tangent (2),
    P (3), M (3), roll, pitch, l (3)]; ``E`` the body-frame tangent basis of the bearing (db = E dα)."""
    v = l + s * b
    w = Rt @ v
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
    return J


def _input_cov(noise: NoiseModel, Cp: np.ndarray) -> np.ndarray:
    """Covariance (13×13) of :func:`_yaw_jacobian`'s inputs from ``noise`` and the prism covariance ``Cp``."""
    Sigma = np.zeros((13, 13))
    Sigma[0:2, 0:2] = noise.bearing ** 2 * np.eye(2)
    Sigma[2:5, 2:5] = Cp
    Sigma[5:8, 5:8] = noise.marker ** 2 * np.eye(3)
    Sigma[8:10, 8:10] = noise.tilt ** 2 * np.eye(2)
    Sigma[10:13, 10:13] = noise.lever ** 2 * np.eye(3)
    return Sigma


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

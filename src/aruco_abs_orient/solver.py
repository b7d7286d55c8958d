"""Absolute orientation from marker bearings (DESIGN §4.4–4.5).

Frames (DESIGN §2): ``map`` (markers, prism), ``base_link`` with attitude
``R = Rz(yaw) · Ry(pitch) · Rx(roll)``, and the camera fixed to base_link by the static
transform ``base_T_camera`` (rotation ``R_bc``, camera origin ``t_camera`` in base_link);
the prism sits at ``prism_in_base`` (= ``t_prism``) in base_link. An observation is a unit
bearing ``u`` in the camera frame (from ``camera``/``detection``).

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
* :func:`resection` — ≥ 3 markers, no prism ⇒ position and attitude of base_link.

Units: metres, radians, everything in ``map`` unless named otherwise. numpy only,
Python 3.8 compatible.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Tuple

import numpy as np

from .camera import angle_between
from .errors import GeometryError
from .transforms import make_T, matrix_to_rpy, rot_x, rot_y, rot_z, rpy_to_matrix, wrap_angle

__all__ = [
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


class SolverError(GeometryError, ValueError):
    """Inputs the solver cannot use (wrong shapes, too few markers, non-finite values)."""


class DegenerateGeometryError(SolverError):
    """The geometry does not determine the requested quantity; ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


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
    """Pose of base_link from ≥ 3 markers (spatial resection).

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
    e1 = _unit(np.cross(u, a))
    e2 = np.cross(u, e1)
    return np.stack([e1, e2], axis=-1)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix(es) (..., 3, 3): skew(v) @ x = v × x."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


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


def yaw_from_marker(bearing, marker, prism, roll: float, pitch: float, base_T_camera, prism_in_base, *,
                    sigma_bearing: float = 0.0, prism_cov=None, marker_sigma: float = 0.0,
                    tilt_sigma: float = 0.0, lever_sigma: float = 0.0, min_range: float = 0.1,
                    min_horizontal: float = 0.02) -> YawEstimate:
    """Yaw of base_link (rad) from one marker bearing, in closed form.

    Args:
        bearing: bearing of the marker centre in the camera frame (3,), any length (normalised here).
        marker: surveyed marker centre M in map (3,), metres.
        prism: prism position P in map (3,), metres.
        roll, pitch: tilt of base_link (rad), e.g. from VO (map→odom is yaw only).
        base_T_camera: static transform base_link ← camera (4×4).
        prism_in_base: prism position in base_link (3,), metres.
        sigma_bearing: 1-σ bearing noise (rad) per axis perpendicular to the bearing.
        prism_cov: prism position noise: None, a σ (m) or a 3×3 covariance (m²).
        marker_sigma: marker survey 1-σ per axis (m) (``markers.Marker.sigma``).
        tilt_sigma: 1-σ of roll and of pitch (rad).
        lever_sigma: 1-σ per axis of the lever arm camera − prism (m).
        min_range: smallest accepted camera→marker range (m).
        min_horizontal: smallest accepted ratio horizontal/total length of ``M − P`` and of the
            predicted vector (below it the azimuth is ill-defined: marker straight above/below).

    Raises:
        DegenerateGeometryError: ``|M − P| ≤ |l|`` (marker within the lever arm of the prism:
            no positive range), range < ``min_range``, or a nearly vertical ``M − P``.
        SolverError: malformed inputs.
    """
    u = _unit(_vec3(bearing, "bearing"))
    M = _vec3(marker, "marker")
    P = _vec3(prism, "prism")
    R_bc, t_cam = _transform(base_T_camera, "base_T_camera")
    t_prism = _vec3(prism_in_base, "prism_in_base")
    Cp = _cov3(prism_cov, "prism_cov")
    if not (math.isfinite(roll) and math.isfinite(pitch)):
        raise SolverError(f"roll/pitch: expected finite radians, got {roll!r}, {pitch!r}")

    l = t_cam - t_prism  # noqa: E741  (the lever arm, as in DESIGN §4.4)
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
    dw_droll = Rt @ np.cross(_EX, v)
    dw_dpitch = np.cross(_EY, w)
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
    Sigma[0:2, 0:2] = sigma_bearing ** 2 * np.eye(2)
    Sigma[2:5, 2:5] = Cp
    Sigma[5:8, 5:8] = marker_sigma ** 2 * np.eye(3)
    Sigma[8:10, 8:10] = tilt_sigma ** 2 * np.eye(2)
    Sigma[10:13, 10:13] = lever_sigma ** 2 * np.eye(3)
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


def _gauss_newton(u_obs, M, R_bc, a, R0, p0, sigma_b, sigma_m, prior, estimate_p: bool, loss: str,
                  loss_scale: float, outlier_gate: Optional[float], min_inliers: int,
                  max_iterations: int) -> _Fit:
    """Robust GN over R (right perturbation R·Exp(δ)) and, if ``estimate_p``, the reference point p.

    Model: camera C = p + R a; predicted camera bearing ``R_bcᵀ Rᵀ (M − C) / |·|``; residual its
    difference from the observed bearing in the observed bearing's tangent plane (≈ rad).
    ``prior`` is None or (p_measured, L⁻¹) with L Lᵀ its covariance (m²).

    Two stages: IRLS with the robust ``loss`` finds the outliers; then, if at least ``min_inliers``
    markers have normalised residuals ≤ ``outlier_gate``, plain least squares on those (weights 1/0)
    gives the estimate and an honest covariance. Otherwise the robust solution is kept.
    """
    if loss not in ("huber", "cauchy", "none"):
        raise SolverError(f"loss: expected 'huber', 'cauchy' or 'none', got {loss!r}")
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
    dof = 2 * int(np.count_nonzero(mask)) + (3 if use_prior else 0) - npar
    vf = chi2 / dof if dof > 0 else float("nan")
    return _Fit(R, p, np.linalg.inv(H), angle_between(u_pred, u_obs), e, weights, vf, iterations)


def _check_spread(directions: np.ndarray, min_spread: float, what: str) -> None:
    d = _unit(directions)
    sin = np.linalg.norm(np.cross(d[:, None, :], d[None, :, :]), axis=-1)
    if float(sin.max()) < math.sin(min_spread):
        raise DegenerateGeometryError(
            f"{what} lie within {math.degrees(math.asin(min(1.0, float(sin.max())))):.2f}° of one line "
            f"(min_spread {math.degrees(min_spread):.2f}°): the rotation about it is unobservable")


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


def attitude_from_markers(bearings, markers, prism, base_T_camera, prism_in_base, *,
                          sigma_bearing=1e-3, prism_cov=None, marker_sigma=0.0,
                          tilt: Tuple[float, float] = (0.0, 0.0), initial_yaw: Optional[float] = None,
                          loss: str = "cauchy", loss_scale: float = 2.0, outlier_gate: Optional[float] = 4.0,
                          min_spread: float = math.radians(3.0), max_iterations: int = 50) -> AttitudeEstimate:
    """Full attitude of base_link from ≥ 2 marker bearings and the prism position.

    Args:
        bearings: (N, 3) marker-centre bearings in the camera frame (normalised here).
        markers: (N, 3) surveyed marker centres in map (m), same order.
        prism: prism position in map (3,), m.
        base_T_camera: static transform base_link ← camera (4×4).
        prism_in_base: prism position in base_link (3,), m.
        sigma_bearing: bearing 1-σ (rad) per perpendicular axis, scalar or (N,).
        prism_cov: None (prism exact), a σ (m) or a 3×3 covariance (m²); when given, the prism
            position is adjusted under this prior and its noise enters the covariance.
        marker_sigma: survey 1-σ (m), scalar or (N,), added as σ_M/range to the bearing σ.
        tilt: (roll, pitch) in rad to start from (VO tilt); yaw starts from the consensus of the
            per-marker closed-form yaws (:func:`yaw_from_marker`), else ``initial_yaw``.
        loss: robust loss of the first stage, 'cauchy' (default), 'huber' or 'none'; ``loss_scale`` in σ.
        outlier_gate: markers whose normalised residual (|r|/σ, 2-D) exceeds it after the robust stage
            are dropped (weight 0) and the rest re-solved by plain least squares (if ≥ 2 remain);
            None keeps the robust solution.
        min_spread: smallest angle (rad) between marker directions seen from the camera.

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
    R_bc, t_cam = _transform(base_T_camera, "base_T_camera")
    t_prism = _vec3(prism_in_base, "prism_in_base")
    Cp = _cov3(prism_cov, "prism_cov")
    sb = _per_marker(sigma_bearing, n, "sigma_bearing")
    sm = _per_marker(marker_sigma, n, "marker_sigma")
    roll0, pitch0 = float(tilt[0]), float(tilt[1])

    yaws, sigs = [], []
    for i in range(n):
        try:
            est = yaw_from_marker(u[i], M[i], P, roll0, pitch0, base_T_camera, t_prism,
                                  sigma_bearing=float(sb[i]), prism_cov=Cp, marker_sigma=float(sm[i]))
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
    fit = _gauss_newton(u, M, R_bc, t_cam - t_prism, R0, P.copy(), sb, sm, prior, estimate_p, loss,
                        loss_scale, outlier_gate, 2, max_iterations)
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
    ang = np.arctan2(np.linalg.norm(np.cross(v, d), axis=-1), np.sum(v * d, axis=-1))  # behind ⇒ > π/2
    cost = np.sum(ang ** 2, axis=1)
    g = int(np.argmin(cost))
    return float(psi[g]), C[g]


def resection(bearings, markers, base_T_camera, *, sigma_bearing=1e-3, marker_sigma=0.0,
              tilt: Tuple[float, float] = (0.0, 0.0), initial_pose=None, loss: str = "cauchy",
              loss_scale: float = 2.0, outlier_gate: Optional[float] = 4.0, min_spread: float = math.radians(3.0),
              max_iterations: int = 50) -> ResectionEstimate:
    """Position and attitude of base_link from ≥ 3 marker bearings (no prism).

    Args:
        bearings: (N, 3) bearings in the camera frame; markers: (N, 3) centres in map (m).
        base_T_camera: static transform base_link ← camera (4×4).
        sigma_bearing, marker_sigma, loss, loss_scale, outlier_gate: as in :func:`attitude_from_markers`
            (at least 3 inliers are needed for the least-squares stage).
        tilt: (roll, pitch) (rad) assumed for the start (small-tilt platforms: the default 0, 0).
        initial_pose: optional map_T_base (4×4) start instead of the yaw scan.
        min_spread: markers closer than this (rad) to one line (collinear) are degenerate.

    Raises:
        DegenerateGeometryError: collinear markers, singular normal equations.
        SolverError: fewer than 3 markers or malformed inputs.
    """
    u = _unit(_vecs3(bearings, "bearings"))
    M = _vecs3(markers, "markers")
    n = len(u)
    if n < 3 or len(M) != n:
        raise SolverError(f"resection: need ≥ 3 bearings with as many markers, got {n} and {len(M)}")
    R_bc, t_cam = _transform(base_T_camera, "base_T_camera")
    sb = _per_marker(sigma_bearing, n, "sigma_bearing")
    sm = _per_marker(marker_sigma, n, "marker_sigma")
    centred = M - M.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] == 0 or sv[1] < math.tan(min_spread) * sv[0]:
        raise DegenerateGeometryError("the markers are (nearly) collinear: the rotation about their line "
                                      "and the position around it are not determined")
    if initial_pose is not None:
        R0, p0 = _transform(initial_pose, "initial_pose")
    else:
        Rt = rot_y(float(tilt[1])) @ rot_x(float(tilt[0]))
        yaw0, C0 = _scan_yaw(u @ (Rt @ R_bc).T, M)
        R0 = rpy_to_matrix(float(tilt[0]), float(tilt[1]), yaw0)
        p0 = C0 - R0 @ t_cam
    fit = _gauss_newton(u, M, R_bc, t_cam, R0, p0, sb, sm, None, True, loss, loss_scale, outlier_gate, 3,
                        max_iterations)
    K = _rpy_jacobian(fit.R)
    T = np.zeros((6, 6))
    T[:3, 3:] = np.eye(3)          # position block: p (map, additive)
    T[3:, :3] = K                  # rpy from the body rotation vector
    cov = T @ fit.cov @ T.T
    r, pch, y = (float(x) for x in matrix_to_rpy(fit.R))
    return ResectionEstimate(fit.p, r, pch, y, fit.R, make_T(fit.R, fit.p), cov, fit.residuals,
                             fit.normalized, fit.weights, fit.variance_factor, fit.iterations)

"""The multi-marker pose fits (doc/design.md §7): attitude with a prism, resection without one.

* :func:`attitude_from_markers` — ≥ 2 marker bearings + the prism position ⇒ roll, pitch, yaw of base_link
  (the prism position adjusted under its measured prior), as an :class:`AttitudeEstimate`.
* :func:`resection` — ≥ 3 markers (≥ 2 with a known tilt), no prism ⇒ position and attitude of base_link, as a
  :class:`ResectionEstimate`; degenerate geometry refused with the reason (``DegenerateGeometryError``).

Both run one robust Gauss-Newton on SO(3) (:func:`_gauss_newton`): Cauchy/Huber IRLS finds the outliers, then
plain least squares on the markers that pass the residual gate gives the estimate and an honest covariance
(``solver.FitSettings``). The inputs' types (``Mounting``, ``NoiseModel``) and the one-marker closed form that
seeds the attitude's yaw are ``solver.py``'s. Units: metres, radians, map frame. numpy only, Python 3.8.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional, Tuple

import numpy as np

from .camera import angle_between
from .solver import (
    DegenerateGeometryError,
    FitSettings,
    Mounting,
    NoiseModel,
    SolverError,
    _cov3,
    _per_marker,
    _tangent_basis,
    _tilt,
    _transform,
    _unit,
    _vec3,
    _vecs3,
    yaw_consensus,
    yaw_from_marker,
)
from .transforms import cross3, make_T, matrix_to_rpy, rot_x, rot_y, rot_z, rpy_to_matrix, wrap_angle

__all__ = ["AttitudeEstimate", "ResectionEstimate", "attitude_from_markers", "resection", "MIN_SPREAD", "MIN_CONE"]

#: the smallest angle (rad) between marker directions seen from the camera that determines an attitude (a
#: resection also refuses markers closer than it to one line); the pipeline's attitude update asks more
#: (``attitude_min_spread_deg``)
MIN_SPREAD = math.radians(3.0)
#: a resection whose markers, seen from the camera, all lie within this angle (rad) of each other (one small cone:
#: range and position poorly determined) is refused; the pipeline's is ``resection_min_cone_deg``
MIN_CONE = math.radians(10.0)

#: the bearing noise assumed by the multi-marker solvers when the caller gives none (rad)
_MULTI_NOISE = NoiseModel(bearing=1e-3)
_FIT = FitSettings()


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


def _linearise(pb: _Problem, E: np.ndarray, R: np.ndarray, p: np.ndarray, loss: str, loss_scale: float,
               mask: np.ndarray):
    """Predicted bearings, normalised residuals, weights, normal equations (H, g) and χ² of ``pb`` at (R, p),
    with ``E`` (N, 3, 2) the tangent bases of the observed bearings and ``mask`` (N,) the markers used."""
    u_obs, M, sigma_b, sigma_m, R_bc, a, prior, estimate_p, tilt_prior, _ = pb
    n = len(M)
    npar = 6 if estimate_p else 3
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
    if prior is not None and estimate_p:
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


def _iterate(pb: _Problem, E: np.ndarray, R: np.ndarray, p: np.ndarray, loss: str, settings: FitSettings,
             mask: np.ndarray) -> Tuple[np.ndarray, np.ndarray, int]:
    """Gauss-Newton steps with ``loss`` from (R, p) until the step vanishes or ``settings.max_iterations``:
    the solution and the iterations taken."""
    it = 0
    for it in range(1, settings.max_iterations + 1):  # noqa: B007  (it is reported)
        H, gvec = _linearise(pb, E, R, p, loss, settings.loss_scale, mask)[3:5]
        cond = np.linalg.cond(H)
        if not math.isfinite(cond) or cond > 1e14:
            raise DegenerateGeometryError("the normal equations are singular: the markers do not "
                                          "determine the pose (collinear or too few)")
        step = -np.linalg.solve(H, gvec)
        R = R @ _so3_exp(step[:3])
        if pb.estimate_p:
            p = p + step[3:]
        if np.linalg.norm(step) < 1e-9:    # rad, m: far below any σ (as calibrate's)
            break
    return R, p, it


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
    loss, outlier_gate = settings.loss, settings.outlier_gate
    E = _tangent_basis(pb.u_obs)                                # (N, 3, 2)
    mask = np.ones(len(pb.M))
    R, p, iterations = _iterate(pb, E, R0.copy(), p0.copy(), loss, settings, mask)
    final_loss = loss
    if loss != "none" and outlier_gate is not None:
        inliers = _linearise(pb, E, R, p, "none", settings.loss_scale, mask)[1] <= outlier_gate
        if int(inliers.sum()) >= pb.min_inliers:
            mask = inliers.astype(float)
            final_loss = "none"
            R, p, it2 = _iterate(pb, E, R, p, "none", settings, mask)
            iterations += it2
    u_pred, e, weights, H, _, chi2 = _linearise(pb, E, R, p, final_loss, settings.loss_scale, mask)
    use_prior = pb.prior is not None and pb.estimate_p
    npar = 6 if pb.estimate_p else 3
    dof = (2 * int(np.count_nonzero(mask)) + (3 if use_prior else 0) + (2 if pb.tilt_prior is not None else 0)
           - npar)
    vf = chi2 / dof if dof > 0 else float("nan")
    return _Fit(R, p, np.linalg.inv(H), angle_between(u_pred, pb.u_obs), e, weights, vf, iterations)


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

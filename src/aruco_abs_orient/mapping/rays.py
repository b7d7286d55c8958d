"""Rays and points: each observation's lens ray in map, the point rays meet at, the spread of the places a marker
was seen from.

In: the calibration's :class:`~aruco_abs_orient.calibration.problem.Problem` (observations with their prism,
odometry, mounting and lenses) with the values of its unknowns; rays (origins, directions) in map. Out: rays in
map (:func:`rays_in_map`, through ``camera.DualFisheye.rays``: each stitched bearing from its lens's centre), the
robust point of a bundle of rays (:func:`triangulate`: false sightings cannot pull it) and its covariance from the
rays' own scatter (:func:`scatter_covariance`), the diameter of a point set (:func:`diameter`, the baseline a
marker was seen over).

Units: metres, radians.
"""

from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

from ..calibration.problem import Problem
from ..transforms import rot_z, rotvec_to_matrix, rpy_to_matrix

__all__ = ["triangulate", "scatter_covariance", "rays_in_map", "diameter", "bias_jacobian", "bias_covariance",
           "normal_matrices"]


def triangulate(origins: np.ndarray, directions: np.ndarray, tolerance: float, min_support: int = 2,
                seed: int = 0) -> Tuple[Optional[np.ndarray], np.ndarray]:
    """The point (3,) most rays pass within ``tolerance`` rad of (in front of them), refined by least squares on
    those rays (weighted by 1/range²), and the mask (N,) of those rays; (None, no rays) when fewer than
    ``min_support`` rays meet. Candidates are the closest points of pairs of rays ≥ 2° apart."""
    org = np.asarray(origins, dtype=float).reshape(-1, 3)
    dirs = np.asarray(directions, dtype=float).reshape(-1, 3)
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    n = len(org)
    none = (None, np.zeros(n, dtype=bool))
    if n < max(min_support, 2):
        return none
    rng = np.random.default_rng(seed)
    i, j = rng.integers(0, n, 400), rng.integers(0, n, 400)
    cos = np.sum(dirs[i] * dirs[j], axis=1)
    good = (i != j) & (cos < math.cos(math.radians(2.0)))
    i, j = i[good][:60], j[good][:60]
    if len(i) == 0:
        return none
    # closest points of the ray pairs: o_i + s d_i ≈ o_j + t d_j
    w = org[i] - org[j]
    b, c = np.sum(dirs[i] * dirs[j], axis=1), 1.0 - np.sum(dirs[i] * dirs[j], axis=1) ** 2
    di, dj = np.sum(dirs[i] * w, axis=1), np.sum(dirs[j] * w, axis=1)
    s, t = (b * dj - di) / c, (dj - b * di) / c
    ok = (s > 0) & (t > 0)
    if not np.any(ok):
        return none
    cand = 0.5 * (org[i] + s[:, None] * dirs[i] + org[j] + t[:, None] * dirs[j])[ok]
    support = np.array([np.count_nonzero(_near(X, org, dirs, tolerance)) for X in cand])
    X = cand[int(np.argmax(support))]
    for _ in range(4):
        inl = _near(X, org, dirs, tolerance)
        if np.count_nonzero(inl) < max(min_support, 2):
            return none
        P, r2 = _across(X, org[inl], dirs[inl])
        A = P / r2[:, None, None]
        try:
            X = np.linalg.solve(A.sum(axis=0), np.einsum("nij,nj->i", A, org[inl]))
        except np.linalg.LinAlgError:
            return none
    inl = _near(X, org, dirs, tolerance)
    return (X, inl) if np.count_nonzero(inl) >= max(min_support, 2) else none


def scatter_covariance(X: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The covariance (3, 3) m² of the point ``X`` (3,) that rays (N ≥ 2, unit ``directions``) meet at, from their
    own scatter about it: each ray's miss angle (its distance from X over its range), their mean square over the
    2N − 3 degrees of freedom, times the inverse of Σ (I − d dᵀ) / range²."""
    origins = np.asarray(origins, dtype=float)
    P, r2 = _across(X, origins, np.asarray(directions, dtype=float))
    miss = np.einsum("nij,nj->ni", P, X - origins)
    s2 = float(np.sum(np.sum(miss ** 2, axis=1) / r2)) / max(2 * len(r2) - 3, 1)
    return s2 * np.linalg.inv(np.sum(P / r2[:, None, None], axis=0))


def _across(X, org, dirs) -> Tuple[np.ndarray, np.ndarray]:
    """Per ray: the projection (N, 3, 3) across its unit direction, I − d dᵀ, and the square (N,) of X's range
    along it (at least 1 mm): a miss across a ray over its range is its angle."""
    r = np.maximum(np.sum((X - org) * dirs, axis=1), 1e-3)
    return np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :], r ** 2


def _near(X, org, dirs, tolerance) -> np.ndarray:
    v = X - org
    r = np.linalg.norm(v, axis=1)
    return (np.sum(v * dirs, axis=1) > np.cos(tolerance) * r) & (r > 1e-6)


def rays_in_map(pb: Problem, x: np.ndarray, d: np.ndarray, th: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Each observation's lens ray in map: origins (N, 3) m and unit directions (N, 3), from the prism, the
    odometry with δ and θ (knot values ``d``, tilt knots ``th``), the mounting with the globals ``x`` and the
    lenses (``camera.DualFisheye.rays``)."""
    delta, theta, _ = pb.local(d, th, np.zeros((len(pb.markers.ids), 3)))
    w3 = np.zeros((len(delta), 3))
    w3[:, :2] = theta
    R = rot_z(delta) @ rotvec_to_matrix(w3) @ pb.R_odom                    # map_R_base
    Rc = R @ (rpy_to_matrix(*x[:3]) @ pb.R_bc)                              # map_R_camera
    C = pb.P - pb.V * x[6] + np.einsum("nij,j->ni", R, pb.t_cam + x[3:6] - pb.t_prism)
    o, w = pb.lenses_at(x).rays(pb.u)
    return C + np.einsum("nij,nj->ni", Rc, o), np.einsum("nij,nj->ni", Rc, w)


def diameter(points: np.ndarray) -> float:
    """The largest distance (m) between two of ``points`` (N, 3), by two farthest-point passes (within 13 %)."""
    if len(points) < 2:
        return 0.0
    a = points[int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    b = points[int(np.argmax(np.linalg.norm(points - a, axis=1)))]
    return float(np.max(np.linalg.norm(points - b, axis=1)))


def bias_jacobian(u: np.ndarray) -> np.ndarray:
    """∂(u × d)/∂b (N, 3, 2) of the residuals u × d (d ≈ u) for an offset b of the observed unit bearings ``u``
    (N, 3) along the image's azimuth and elevation (rad of arc)."""
    az = np.arctan2(u[:, 1], u[:, 0])
    el = np.arcsin(np.clip(u[:, 2], -1.0, 1.0))
    e_az = np.stack([-np.sin(az), np.cos(az), np.zeros_like(az)], axis=1)
    e_el = np.stack([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)], axis=1)
    return np.stack([np.cross(e_az, u), np.cross(e_el, u)], axis=2)


def bias_covariance(group: np.ndarray, H: np.ndarray, J: np.ndarray, Jb: np.ndarray, w: np.ndarray,
                    sigma_b: np.ndarray) -> np.ndarray:
    """Covariance (n, p, p) of each group's p unknowns from an offset common to some of its observations: the
    groups' normal matrices ``H`` (n, p, p), those observations' residual Jacobians ``J`` (N, 3, p) by the unknowns
    and ``Jb`` (N, 3, q) by the offset, their weights ``w`` (N,) and groups ``group`` (N,) in [0, n), the offset's
    1-σ per group ``sigma_b`` (n,). The unknowns follow an offset b by −H⁻¹ Σ Jᵀ w Jb b, each axis of b of σ
    ``sigma_b``."""
    n = len(H)
    B = np.zeros((n, J.shape[2], Jb.shape[2]))
    np.add.at(B, group, np.einsum("nji,n,njk->nik", J, w, Jb))
    ok = np.linalg.det(H) > 0
    follow = np.zeros_like(B)
    follow[ok] = np.linalg.solve(H[ok], B[ok])
    return sigma_b[:, None, None] ** 2 * np.einsum("nik,njk->nij", follow, follow)


def normal_matrices(group: np.ndarray, n: int, J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Σ Jᵀ w J (n, p, p) per group of the observations' Jacobians ``J`` (N, 3, p) and weights ``w`` (N,)."""
    H = np.zeros((n, J.shape[2], J.shape[2]))
    np.add.at(H, group, np.einsum("nji,n,njk->nik", J, w, J))
    return H

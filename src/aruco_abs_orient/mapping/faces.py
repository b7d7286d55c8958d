"""Each marker's face from its corners: the orientation of the black square whose centre the network placed.

In: the network's problem (``calibration.problem.Problem``) and the values of its unknowns (the camera's pose at
every observation), each observation's four corner bearings (ArUco order: top-left, top-right, bottom-right,
bottom-left seen from the front) with the detection's centre σ, which observations the network kept, the centres
and the markers' side. Out: per marker id, the unit normal out of its face (3,) and its 1-σ (rad, the larger of
its two tilts; the corners' variance factor and their correlation in time included).

The corners are predicted by the network's own observation model (the corner's offset from the centre,
``R · (±s/2, ±s/2, 0)``, in place of the marker's offset), the centre held: three unknowns per marker, a rotation
vector in map, by Gauss-Newton from the square of its four corners, each triangulated from its rays. A corner's σ
is twice the centre's (the centre averages four corners); a corner residual beyond 4 σ is left out; each corner's
sightings share an error, which their number cannot average away: it is in the normal's σ.

Units: metres, radians.
"""

from __future__ import annotations

import copy
import math
from typing import Dict, Optional, Tuple

import numpy as np

from ..calibration.problem import Problem
from ..calibration.variance import correlation_factor
from ..transforms import rotvec_to_matrix
from .rays import bias_covariance, bias_jacobian, rays_in_map, triangulate

__all__ = ["fit_faces", "problem_for"]

#: corners in the marker's frame (x right, y up the face, z out of it) per unit side, ArUco order
_TEMPLATE = 0.5 * np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0]])
_ITERATIONS = 8
_GATE = 4.0


def problem_for(pb: Problem, bearings: np.ndarray) -> Problem:
    """``pb`` with other bearings (N, 3) in place of its markers' centres: the same observation model, times,
    poses and lenses."""
    out = copy.copy(pb)
    out.u = bearings / np.linalg.norm(bearings, axis=1, keepdims=True)
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def _frame(points: np.ndarray) -> Optional[np.ndarray]:
    """map_R_marker (3, 3) of four corner points (4, 3) in ArUco order, or None when they span no square."""
    right = points[1] + points[2] - points[0] - points[3]
    up = points[0] + points[1] - points[2] - points[3]
    z = np.cross(right, up)
    if np.linalg.norm(z) < 1e-12:
        return None
    x, z = right / np.linalg.norm(right), z / np.linalg.norm(z)
    return np.stack([x, np.cross(z, x), z], axis=1)


def fit_faces(pb: Problem, x, d, th, corners: np.ndarray, sigma: np.ndarray, kept: np.ndarray,
              centres: Dict[int, np.ndarray], size: float, bias: float) -> Dict[int, Tuple[np.ndarray, float]]:
    """Per marker id: (unit normal (3,) out of its face, its 1-σ in rad), for the markers of ``pb`` whose corners
    meet. ``corners`` (N, 4, 3) and ``sigma`` (N,) (the detection's centre σ, rad) of pb's observations, ``kept``
    (N,) those the network kept; ``x``, ``d``, ``th`` its globals, δ knots and tilt knots; ``centres`` the markers'
    centres (m); ``size`` their side (m); ``bias`` (rad): the error each corner's sightings have in common, per axis
    (``MappingParams.bias_deg``), in the normal's σ."""
    ids = [int(i) for i in pb.markers.ids]
    nm = len(ids)
    k = pb.markers.index
    tmpl = size * _TEMPLATE
    has = kept & np.all(np.isfinite(corners), axis=(1, 2)) & (np.linalg.norm(corners, axis=2).min(axis=1) > 0.5)
    problems = [problem_for(pb, np.where(has[:, None], corners[:, c], pb.u)) for c in range(4)]
    rays = [rays_in_map(p, x, d, th) for p in problems]
    R = np.tile(np.eye(3), (nm, 1, 1))
    ok = np.zeros(nm, dtype=bool)
    for j in range(nm):
        sel = np.flatnonzero(has & (k == j))
        points = []
        for org, dirs in rays:
            X, _ = triangulate(org[sel], dirs[sel], math.radians(1.5), min_support=4, seed=j)
            points.append(X)
        if all(p is not None for p in points):
            frame = _frame(np.array(points))
            if frame is not None:
                R[j], ok[j] = frame, True
    delta, theta, _ = pb.local(d, th, np.zeros((nm, 3)))
    M = np.array([centres[i] for i in ids])[k] - pb.M        # each observation's centre offset
    sig_c = 2.0 * np.maximum(sigma, 1e-9)
    use = has & ok[k]
    w = np.where(use, 1.0 / sig_c ** 2, 0.0)
    weights = np.tile(w[:, None], (1, 4))
    scale2 = 1.0
    H = np.zeros((nm, 3, 3))
    resid = np.zeros((len(k), 4))
    jacobians = [np.zeros((len(k), 3, 3))] * 4
    for it in range(_ITERATIONS):
        H = np.zeros((nm, 3, 3))
        g = np.zeros((nm, 3))
        for c, p in enumerate(problems):
            arm = np.einsum("nij,j->ni", R[k], tmpl[c])
            r, _, _, _, cM = p.linearise(x, delta, theta, M + arm, free=())
            J = -np.einsum("nij,njk->nik", cM, _skew(arm))          # ∂r/∂ω: arm → arm + ω × arm
            jacobians[c] = J
            resid[:, c] = np.linalg.norm(r, axis=1) / sig_c
            wc = weights[:, c]
            np.add.at(H, k, np.einsum("nki,nkj->nij", J * wc[:, None, None], J))
            np.add.at(g, k, np.einsum("nki,nk->ni", J * wc[:, None, None], r))
        good = ok & (np.linalg.det(H) > 0)
        step = np.zeros((nm, 3))
        step[good] = -np.linalg.solve(H[good], g[good][:, :, None])[:, :, 0]
        R = rotvec_to_matrix(step) @ R
        in_use = weights > 0
        scale2 = float(np.sum(resid[in_use] ** 2) / max(2 * np.count_nonzero(in_use) - 3 * int(good.sum()), 1))
        if it >= 1:     # the corners beyond the gate, once the faces are near
            weights = np.where(use[:, None] & (resid <= _GATE * math.sqrt(max(scale2, 1e-12))), w[:, None], 0.0)
        if float(np.max(np.abs(step), initial=0.0)) < 1e-10:
            break
    order = np.argsort(pb.t, kind="stable")
    series = (resid * (weights > 0))[order][use[order]]
    corr = correlation_factor(series) if len(series) else 1.0
    # the corners' common error: each corner's own offset
    common = sum(bias_covariance(k, H, jacobians[c], bias_jacobian(problems[c].u), weights[:, c], np.full(nm, bias))
                 for c in range(4))
    out = {}
    for j in np.flatnonzero(ok & (np.linalg.det(H) > 0)):
        cov = np.linalg.inv(H[j]) * max(scale2, 1e-12) * corr + common[j]
        tilts = R[j][:, :2].T @ cov @ R[j][:, :2]            # about the face's own x and y
        out[ids[j]] = (R[j][:, 2].copy(), float(math.sqrt(max(np.linalg.eigvalsh(tilts).max(), 0.0))))
    return out

"""A small marker's corners from its whole known pattern, fitted to the image.

In: a ``sample(pts)`` function giving grey levels at image points (as :func:`.quads.refine_quads` takes: an
image's, or a virtual gnomonic view's from :mod:`.sphere`), quads (M, 4, 2) in ArUco order (pixels) and the
markers' inner bits (M, n, n) (1 = white, rotation 0: the dictionary's codes of their ids). Out: the corners
(M, 4, 2) that make the image of the marker's pattern, blurred by a Gaussian of fitted σ, best match the grey
levels around it (NaN rows where the fit fails), and the fitted σ (px).

Why: an edge located one profile at a time (:func:`.quads.refine_quads`) is pulled by the cells next to it when
they are under about 3 px wide: a white cell against the black border lifts the border's grey levels, a black
cell widens it, so each marker's centre is off by a bias its pattern sets, up to 0.1-0.2 px, the same on every
frame (doc/design.md §5 and §11; ``bench/detection.py --only pattern_bias``). A model of the whole pattern has no
such bias: it knows where every cell is.

The model: the square [0, c]² (c cells across, the black border included, in the marker's own cell units) seen
through the homography the four corners set, white outside the black square (the quiet zone, one cell wide, as
the decoder assumes), the inner bits as given; each cell's image blurred by a Gaussian of σ px (optics, pixel
area, resampling), taken along the square's two axes through the homography's local scale; the grey levels an
affine map of it (black and white levels solved in closed form at each step). Unknowns: the 8 corner coordinates
and log σ, fitted by Levenberg-Marquardt over the pixels within ``margin_cells`` of the black square, all markers
of a call in one batch; the Jacobian analytic through the blurred cells (Φ's derivatives) and by forward
differences through the homography. A fit is refused (NaN) when a corner moves more than ``max_move_cells`` cells
or σ leaves [0.15, 3] px.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Tuple

import numpy as np

__all__ = ["PatternFitParams", "PATTERN_FIT", "fit_patterns", "square_homographies"]

_ERF = (0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429)   # Abramowitz & Stegun 7.1.26
_STEP = 1e-3       # px and log σ: the forward differences' step
_SIGMA_RANGE = (0.15, 3.0)


@dataclass(frozen=True)
class PatternFitParams:
    """How :func:`fit_patterns` runs (the detector's ``pattern_fit_*`` fields set them).

    - ``iterations``: Levenberg-Marquardt steps;
    - ``margin_cells``: the pixels fitted reach this far beyond the black square (cells; the quiet zone is one);
    - ``sigma_px``: the blur σ the fit starts from;
    - ``max_move_cells``: a corner that moves farther than this (cells) refuses the fit.
    """

    iterations: int = 4
    margin_cells: float = 0.7
    sigma_px: float = 0.8
    max_move_cells: float = 0.5


PATTERN_FIT = PatternFitParams()


def _normal(z: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The standard normal distribution Φ(z) (max error 1.5e-7) and its density φ(z)."""
    x = np.abs(z) * (1.0 / math.sqrt(2.0))
    t = 1.0 / (1.0 + 0.3275911 * x)
    e = np.exp(-x * x)
    half = 0.5 * ((((_ERF[4] * t + _ERF[3]) * t + _ERF[2]) * t + _ERF[1]) * t + _ERF[0]) * t * e   # 1 - Φ(|z|)
    return np.where(z >= 0, 1.0 - half, half), e * (1.0 / math.sqrt(2.0 * math.pi))


def square_homographies(quads: np.ndarray, cells: int) -> np.ndarray:
    """Homographies (M, 3, 3), up to scale, taking the pixels of quads (M, 4, 2) (ArUco order) onto the square
    [0, cells]² (corner 0 at the origin, corner 1 at (cells, 0)): the inverse of the unit square's projective
    map onto the quad (Heckbert's closed form), by its adjugate."""
    q = np.asarray(quads, dtype=float)
    x, y = q[..., 0], q[..., 1]
    sx, sy = x[:, 0] - x[:, 1] + x[:, 2] - x[:, 3], y[:, 0] - y[:, 1] + y[:, 2] - y[:, 3]
    dx1, dx2, dy1, dy2 = x[:, 1] - x[:, 2], x[:, 3] - x[:, 2], y[:, 1] - y[:, 2], y[:, 3] - y[:, 2]
    den = dx1 * dy2 - dx2 * dy1
    g, h = (sx * dy2 - dx2 * sy) / den, (dx1 * sy - sx * dy1) / den
    cols = np.stack([np.stack([x[:, 1] - x[:, 0] + g * x[:, 1], y[:, 1] - y[:, 0] + g * y[:, 1], g], axis=1),
                     np.stack([x[:, 3] - x[:, 0] + h * x[:, 3], y[:, 3] - y[:, 0] + h * y[:, 3], h], axis=1),
                     np.stack([x[:, 0], y[:, 0], np.ones(len(q))], axis=1)], axis=1)     # (M, 3 columns, 3)
    adj = np.stack([np.cross(cols[:, 1], cols[:, 2]), np.cross(cols[:, 2], cols[:, 0]),
                    np.cross(cols[:, 0], cols[:, 1])], axis=1)
    adj[:, :2] *= cells
    return adj


def _to_square(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Points (M, N, 2) through homographies (M, 3, 3)."""
    ph = pts @ np.transpose(h[:, :2, :2], (0, 2, 1)) + h[:, None, :2, 2]
    w = pts @ h[:, 2, :2, None] + h[:, None, 2, 2:3]
    return ph / w


def _pattern(st: np.ndarray, sigma: np.ndarray, white: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """The blurred pattern S (M, N) in [0, 1] (0 black) at square coordinates ``st`` (M, N, 2) (cells) of markers
    with cells ``white`` (M, c, c) (1 white) blurred by ``sigma`` (M, 2) cells along s and t, and its derivatives
    (M, 3, N) by s, t and log σ."""
    cells = white.shape[1]
    edges = np.arange(cells + 1, dtype=float)
    parts = []
    for axis in (0, 1):     # each axis: Φ beyond each grid line, its derivatives by the coordinate and by log σ
        z = (st[..., axis, None] - edges) / sigma[:, axis, None, None]      # (M, N, c + 1)
        big, dens = _normal(z)
        parts.append((big, dens / sigma[:, axis, None, None], -dens * z))
    (fs, gs, ks), (ft, gt, kt) = parts

    def cells_of(f):     # each cell's share along the axis, and the black square's
        return f[..., :-1] - f[..., 1:], f[..., 0] - f[..., -1]

    (bs, ss), (bt, sq_t) = cells_of(fs), cells_of(ft)
    (dbs, dss), (dbt, dst) = cells_of(gs), cells_of(gt)
    (kbs, kss), (kbt, kst) = cells_of(ks), cells_of(kt)
    tw = np.matmul(bt, white)
    image = 1.0 - ss * sq_t + np.sum(tw * bs, axis=2)
    d_s = -dss * sq_t + np.sum(tw * dbs, axis=2)
    d_t = -ss * dst + np.sum(np.matmul(dbt, white) * bs, axis=2)
    d_sigma = -(kss * sq_t + ss * kst) + np.sum(tw * kbs + np.matmul(kbt, white) * bs, axis=2)
    return image, np.stack([d_s, d_t, d_sigma], axis=1)


def _blur_cells(h: np.ndarray, quads: np.ndarray, log_sigma: np.ndarray) -> np.ndarray:
    """The blur σ (M, 2) in cells along s and t: σ px times the homography's scale at the quad's centre."""
    centre = quads.mean(axis=1)
    probe = _to_square(h, np.stack([centre, centre + [_STEP, 0.0], centre + [0.0, _STEP]], axis=1))
    return np.exp(log_sigma)[:, None] * np.linalg.norm(probe[:, 1:] - probe[:, :1], axis=1) / _STEP


def _linearise(theta: np.ndarray, grey: np.ndarray, pts: np.ndarray, w: np.ndarray, white: np.ndarray
               ) -> Tuple[np.ndarray, np.ndarray]:
    """Residuals (M, N) of the weighted grey levels against the best affine map of the pattern (black and white
    levels in closed form: variable projection) at theta (M, 9: corners, log σ), and their Jacobian (M, 9, N)
    (Kaufman's: the derivatives of the pattern by theta with the levels' span projected out; the blur's scale
    through the homography held)."""
    m, cells = len(theta), white.shape[1]
    quads = theta[:, :8].reshape(m, 4, 2)
    var = quads[:, None] + _STEP * np.eye(8).reshape(1, 8, 4, 2)       # each corner coordinate moved
    hs = square_homographies(np.concatenate([quads[:, None], var], axis=1).reshape(-1, 4, 2), cells)
    st = _to_square(hs, np.repeat(pts, 9, axis=0)).reshape(m, 9, -1, 2)
    image, d = _pattern(st[:, 0], _blur_cells(hs.reshape(m, 9, 3, 3)[:, 0], quads, theta[:, 8]), white)
    dst = (st[:, 1:] - st[:, :1]) / _STEP                                 # (M, 8, N, 2)
    jac = np.concatenate([dst[..., 0] * d[:, None, 0] + dst[..., 1] * d[:, None, 1], d[:, None, 2]], axis=1)
    sw = np.sqrt(w)
    e1 = sw / np.maximum(np.linalg.norm(sw, axis=1, keepdims=True), 1e-12)     # the levels' span, orthonormal
    e2 = sw * image
    e2 -= np.sum(e2 * e1, axis=1, keepdims=True) * e1
    e2 /= np.maximum(np.linalg.norm(e2, axis=1, keepdims=True), 1e-12)
    q = np.stack([e1, e2], axis=1)                                        # (M, 2, N)

    def off_span(x):     # x (M, k, N) with its part in the levels' span removed
        return x - np.matmul(np.matmul(x, np.transpose(q, (0, 2, 1))), q)

    r = off_span((sw * grey)[:, None])[:, 0]
    total = np.maximum(w.sum(axis=1), 1e-12)
    ds = image - ((w * image).sum(axis=1) / total)[:, None]
    amp = (w * ds * grey).sum(axis=1) / np.maximum((w * ds * ds).sum(axis=1), 1e-12)
    return r, -amp[:, None, None] * off_span(sw[:, None] * jac)


def _solve_spd(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solutions (M, k) of the positive definite systems a (M, k, k) x = b (M, k), by Gaussian elimination
    without pivoting, vectorised over M (LAPACK's per-matrix calls cost more than the work for 9 × 9)."""
    a, b = a.copy(), b.copy()
    k = a.shape[1]
    for i in range(k):
        f = a[:, i + 1:, i] / a[:, i, i, None]
        a[:, i + 1:, i:] -= f[:, :, None] * a[:, None, i, i:]
        b[:, i + 1:] -= f * b[:, i, None]
    x = np.zeros_like(b)
    for i in reversed(range(k)):
        x[:, i] = (b[:, i] - np.sum(a[:, i, i + 1:] * x[:, i + 1:], axis=1)) / a[:, i, i]
    return x


def fit_patterns(sample, quads: np.ndarray, codes: np.ndarray,
                 fit: PatternFitParams = PATTERN_FIT) -> Tuple[np.ndarray, np.ndarray]:
    """Corners (M, 4, 2) of M markers fitted with their whole pattern, NaN rows for those refused, and the
    blur σ (M,) px (see the module doc). ``sample(pts)``: grey levels at points (M, P, P, 2); ``quads``
    (M, 4, 2) in ArUco order, within a fraction of a cell; ``codes`` (M, n, n) inner bits (1 = white)."""
    q0 = np.asarray(quads, dtype=float).reshape(-1, 4, 2)
    m = len(q0)
    if not m:
        return q0.copy(), np.zeros(0)
    n = codes.shape[1]
    cells = n + 2
    white = np.zeros((m, cells, cells))
    white[:, 1:-1, 1:-1] = codes
    cell_px = np.linalg.norm(np.roll(q0, -1, axis=1) - q0, axis=2).mean(axis=1) / cells
    centre = np.round(q0.mean(axis=1))
    reach = np.max(np.abs(q0 - centre[:, None]), axis=(1, 2)) + (fit.margin_cells + 1.0) * cell_px
    p = int(2 * math.ceil(float(reach.max())) + 1)
    k = np.arange(p) - (p - 1) // 2
    grid = centre[:, None, None, :] + np.stack(np.meshgrid(k, k), axis=-1)[None]
    grey = np.asarray(sample(grid), dtype=float).reshape(m, -1)
    pts = grid.reshape(m, -1, 2)
    st = _to_square(square_homographies(q0, cells), pts)
    inside = np.all(st > -fit.margin_cells, axis=2) & np.all(st < cells + fit.margin_cells, axis=2)
    keep = np.argsort(~inside, axis=1, kind="stable")[:, :int(inside.sum(axis=1).max())]   # the fitted pixels first
    grey, pts = np.take_along_axis(grey, keep, axis=1), np.take_along_axis(pts, keep[..., None], axis=1)
    w = np.take_along_axis(inside, keep, axis=1).astype(float)

    theta = np.concatenate([q0.reshape(m, 8), np.full((m, 1), math.log(fit.sigma_px))], axis=1)
    r, jac = _linearise(theta, grey, pts, w, white)
    cost = np.sum(r * r, axis=1)
    lam = np.full(m, 1e-3)
    for _ in range(fit.iterations):
        jtj = np.einsum("min,mjn->mij", jac, jac)
        damp = lam[:, None, None] * (np.einsum("mii->mi", jtj)[:, :, None] * np.eye(9) + 1e-9 * np.eye(9))
        step = -_solve_spd(jtj + damp, np.einsum("min,mn->mi", jac, r))
        r_new, jac_new = _linearise(theta + step, grey, pts, w, white)
        cost_new = np.sum(r_new * r_new, axis=1)
        better = cost_new < cost
        theta = np.where(better[:, None], theta + step, theta)
        r = np.where(better[:, None], r_new, r)
        jac = np.where(better[:, None, None], jac_new, jac)
        cost = np.where(better, cost_new, cost)
        lam = np.where(better, lam * 0.3, lam * 10.0)
    out = theta[:, :8].reshape(m, 4, 2)
    sigma = np.exp(theta[:, 8])
    moved = np.max(np.linalg.norm(out - q0, axis=2), axis=1)
    bad = ~(np.isfinite(moved) & (moved <= fit.max_move_cells * cell_px)
            & (sigma >= _SIGMA_RANGE[0]) & (sigma <= _SIGMA_RANGE[1]))
    out[bad] = np.nan
    return out, sigma

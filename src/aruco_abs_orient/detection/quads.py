"""Marker quads in a perspective image: corner refinement and cell reading.

In: a ``sample(pts, rows)`` function giving grey levels at image points (:func:`image_sampler`
for an image, or a virtual view's sampler from :mod:`.sphere`) and approximate quads (M, 4, 2)
(pixels). Out: refined corners (:func:`refine_quads`: lines fitted to the four edges,
intersected), ``(id, corners in ArUco order)`` readings (:func:`decode_quads`: the cells
correlated with the dictionary's codes) and how much brighter the quiet zone is than the border at
the corners as given (:func:`quiet_zone_contrast`: a first look that sets texture aside). Works in
any perspective image (a gnomonic view, a tracking ROI), and on quads small enough for the
equirect's curvature not to matter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import cv2
import numpy as np

__all__ = ["EdgeFitParams", "DecodeParams", "refine_quads", "decode_quads", "quiet_zone_contrast",
           "image_sampler"]


@dataclass(frozen=True)
class EdgeFitParams:
    """How :func:`refine_quads` finds a quad's edges (the detector's ``edge_*`` fields set them).

    - ``min_contrast``: grey levels a profile across an edge must rise by to count.
    - ``min_half_px``, ``half_bits``: a profile spans ±max(``half_bits`` bit, ``min_half_px`` pixels)
      of the current line.
    - ``samples``: steps across the edge per profile; ``along``: profiles along each edge.
    """

    min_contrast: float = 12.0
    min_half_px: float = 1.5
    half_bits: float = 0.45
    samples: int = 16
    along: int = 20


@dataclass(frozen=True)
class DecodeParams:
    """Acceptance thresholds of :func:`decode_quads` (the detector's ``decode_*`` fields set them).

    - ``min_contrast``: grey levels every quiet-zone cell must be brighter than every border cell.
    - ``min_correlation``: correlation of the inner cells with the best code/order.
    - ``min_lead``: lead of that correlation over every other code/order.
    - ``min_pattern_correlation``: correlation of the whole pattern (quiet zone, border, bits).
    """

    min_contrast: float = 40.0
    min_correlation: float = 0.75
    min_lead: float = 0.15
    min_pattern_correlation: float = 0.9


#: the defaults, for the functions' default arguments
EDGE_FIT = EdgeFitParams()
DECODE = DecodeParams()


def _remap_points(img: np.ndarray, x: np.ndarray, y: np.ndarray, border: int) -> np.ndarray:
    """Bilinear grey levels (float, shape of ``x``) of ``img`` at points (x, y) (pixels)."""
    n = x.size
    cols = 1024  # cv2.remap wants maps narrower than 32767
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n] = x.reshape(-1)
    my[:n] = y.reshape(-1)
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR, borderMode=border)
    return out.reshape(-1)[:n].astype(float).reshape(x.shape)


def refine_quads(sample, quads: np.ndarray, bits: int = 6, iterations: int = 2,
                 fit: EdgeFitParams = EDGE_FIT) -> np.ndarray:
    """Refined corners (M, 4, 2) of markers' black squares in a perspective image; NaN rows
    for the quads that fail (too small, too little contrast, diverging).

    ``sample(pts, rows)``: grey levels at image points (R, ..., 2) (pixels) of the quads
    ``rows`` (R indices into ``quads``; :func:`image_sampler`); ``quads`` (M, 4, 2):
    approximate corners. Along each edge (``fit.along`` profiles) the intensity profile across
    it is sampled, the edge is located at the centroid of the black→white gradient within
    ±max(``fit.half_bits`` bit, ``fit.min_half_px`` pixels) of the current line (``fit.samples``
    steps), a line is fitted to each edge (robust total least squares) and adjacent lines are
    intersected; iterated ``iterations`` times, re-centring the profiles on the new lines.
    ``fit.min_contrast``: grey levels a profile must rise by to count. All markers at once.
    """
    min_contrast, min_half_px, half_bits, samples, along = (fit.min_contrast, fit.min_half_px, fit.half_bits,
                                                            fit.samples, fit.along)
    q = np.array(quads, dtype=float).reshape(-1, 4, 2)
    alive = np.ones(len(q), dtype=bool)
    s = np.linspace(0.15, 0.85, along)
    unit_offs = np.linspace(-1.0, 1.0, samples + 1)
    for _ in range(max(1, iterations)):
        rows = np.flatnonzero(alive)  # each iteration works on the quads still alive only
        if not len(rows):
            break
        qa = q[rows]
        d = np.roll(qa, -1, axis=1) - qa  # (M, 4, 2) sides
        length = np.linalg.norm(d, axis=2)
        live = np.all(length >= 2.0, axis=1)
        t = d / np.maximum(length, 1e-9)[..., None]
        n = np.stack([t[..., 1], -t[..., 0]], axis=2)
        out = np.sum(n * (qa + 0.5 * d - qa.mean(axis=1, keepdims=True)), axis=2)
        n *= np.where(out < 0, -1.0, 1.0)[..., None]  # outward normals
        half = np.maximum(half_bits * length.mean(axis=1) / bits, min_half_px)  # (M,)
        offs = half[:, None] * unit_offs[None, :]  # (M, m)
        base = qa[:, :, None, :] + s[None, None, :, None] * d[:, :, None, :]  # (M, 4, k, 2)
        pts = base[:, :, :, None, :] + offs[:, None, None, :, None] * n[:, :, None, None, :]
        prof = sample(pts, rows)  # (M, 4, k, m)
        grad = np.clip(np.diff(prof, axis=3), 0.0, None)
        total = grad.sum(axis=3)
        mids = 0.5 * (offs[:, 1:] + offs[:, :-1])  # (M, m-1)
        edge = (grad * mids[:, None, None, :]).sum(axis=3) / np.maximum(total, 1e-9)
        ok = (total >= min_contrast) & live[:, None, None]
        live &= np.all(np.count_nonzero(ok, axis=2) >= 3, axis=1)
        ok &= live[:, None, None]
        ok[~live] = True  # dead quads: fit anything, discarded below
        normal, offset = _fit_lines((base + edge[..., None] * n[:, :, None, :]).reshape(-1, along, 2),
                                    ok.reshape(-1, along))
        normal = normal.reshape(-1, 4, 2)
        offset = offset.reshape(-1, 4)
        a = np.stack([np.roll(normal, 1, axis=1), normal], axis=2)  # corner i: sides i−1 and i
        det = np.linalg.det(a)
        live &= np.all(np.abs(det) >= 1e-6, axis=1)
        a[~live] = np.eye(2)
        rhs = np.stack([np.roll(offset, 1, axis=1), offset], axis=2)[..., None]
        newq = np.linalg.solve(a, rhs)[..., 0]
        live &= np.all(np.isfinite(newq), axis=(1, 2))
        live &= np.max(np.linalg.norm(newq - qa, axis=2), axis=1) <= 0.5 * length.mean(axis=1)
        q[rows] = np.where(live[:, None, None], newq, qa)
        alive[rows] = live
    q[~alive] = np.nan
    return q


def image_sampler(img: np.ndarray):
    """``sample(pts, rows=None)`` of :func:`refine_quads` and :func:`decode_quads` for a grey
    image: bilinear, border replicated (``rows`` does not matter: one image for all quads)."""
    def sample(pts: np.ndarray, rows=None) -> np.ndarray:
        return _remap_points(img, pts[..., 0], pts[..., 1], cv2.BORDER_REPLICATE)
    return sample


def decode_quads(sample, quads: np.ndarray, codes: np.ndarray,
                 thresholds: DecodeParams = DECODE) -> List[Optional[Tuple[int, np.ndarray]]]:
    """Read M marker quads (M, 4, 2) of a perspective image: one ``(id, corners (4, 2) in ArUco
    order)`` or None per quad. ``sample(pts)``: grey levels at the image points (M, ..., 2) of
    all quads in one call.

    For small markers whose bits OpenCV cannot threshold (1–2 px cells, blurred). The
    centres of the marker's cells and of the one-cell white quiet zone around it are mapped
    by the quad's homography, 3×3 sub-samples per cell. Accepted when every quiet-zone cell
    is brighter than every border cell by ≥ ``thresholds.min_contrast`` grey levels, and the
    Pearson correlation of the inner cells' grey levels with one code's bits, in one of the
    four corner orders, is ≥ ``min_correlation`` and leads every other code/order by
    ≥ ``min_lead`` (a soft decision: blur lowers isolated white bits below any fixed
    threshold, not their rank), and the whole 8×8 pattern (quiet zone, border, bits)
    correlates ≥ ``min_pattern_correlation`` with the grey levels (:class:`DecodeParams`).
    ``codes``: (N, n, n) inner bits of the dictionary (1 = white), rotation 0.
    """
    min_contrast, min_correlation, min_lead, min_pattern_correlation = (
        thresholds.min_contrast, thresholds.min_correlation, thresholds.min_lead, thresholds.min_pattern_correlation)
    quads = np.asarray(quads, dtype=float).reshape(-1, 4, 2)
    if not len(quads):
        return []
    n = codes.shape[1]
    cells = n + 2
    square = np.array([[0.0, 0.0], [cells, 0.0], [cells, cells], [0.0, cells]], dtype=np.float32)
    idx = np.arange(-1, cells + 1) + 0.5
    gx = (idx[:, None] + np.array([-0.2, 0.0, 0.2])[None, :]).reshape(-1)
    grid = np.stack(np.meshgrid(gx, gx), axis=-1).reshape(-1, 1, 2)  # rows = y
    templates = codes.astype(float)
    templates -= templates.mean(axis=(1, 2), keepdims=True)
    templates /= np.maximum(np.linalg.norm(templates, axis=(1, 2), keepdims=True), 1e-12)
    quads = np.where((_signed_areas(quads) < 0)[:, None, None], quads[:, ::-1], quads)   # all clockwise
    pts = np.stack([cv2.perspectiveTransform(grid, cv2.getPerspectiveTransform(square, q.astype(np.float32)))
                    for q in quads]).reshape(len(quads), len(gx), len(gx), 2)
    cm = sample(pts).reshape(len(quads), cells + 2, 3, cells + 2, 3).mean(axis=(2, 4))
    quiet, border = _quiet_zone_and_border(cells)
    contrast = np.min(cm[:, quiet], axis=1) - np.max(cm[:, border], axis=1) >= min_contrast
    whole = quiet.astype(float)  # the whole pattern: quiet zone, border, bits
    out: List[Optional[Tuple[int, np.ndarray]]] = [None] * len(quads)
    for k in np.flatnonzero(contrast):
        m, q = cm[k], quads[k]
        inner = m[2:-2, 2:-2] - m[2:-2, 2:-2].mean()
        norm = float(np.linalg.norm(inner))
        if norm == 0.0:
            continue
        # starting the quad at its corner k (np.roll(q, -k)) rotates the cell grid by np.rot90(·, k)
        scores = np.stack([np.tensordot(templates, np.rot90(inner, r) / norm, axes=([1, 2], [0, 1]))
                           for r in range(4)])
        flat = np.sort(scores.reshape(-1))
        best = np.unravel_index(int(np.argmax(scores)), scores.shape)
        if flat[-1] < min_correlation or flat[-1] - flat[-2] < min_lead:
            continue
        whole[2:-2, 2:-2] = codes[best[1]]
        if np.corrcoef(np.rot90(m, int(best[0])).reshape(-1), whole.reshape(-1))[0, 1] < min_pattern_correlation:
            continue
        out[k] = (int(best[1]), np.roll(q, -int(best[0]), axis=0))
    return out


def quiet_zone_contrast(sample, quads: np.ndarray, cells: int = 6) -> np.ndarray:
    """How much brighter (grey levels, (M,)) the one-cell quiet zone around each quad (M, 4, 2) of a perspective
    image is than its border cells, on average: the cells' centres placed bilinearly in the quad (its corners as
    given, not refined), one sample each. A marker's is its black-on-white contrast, somewhat less where the
    corners are off; a texture's is about 0. ``cells``: the marker's side in cells, border included."""
    quads = np.asarray(quads, dtype=float).reshape(-1, 4, 2)
    if not len(quads):
        return np.zeros(0)
    c = (np.arange(-1, cells + 1) + 0.5) / cells                        # cell centres, the quiet zone included
    u, v = (a.reshape(-1) for a in np.meshgrid(c, c))
    weights = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=1)   # (G, 4), corners 0-3
    grey = sample(weights @ quads).reshape(len(quads), cells + 2, cells + 2)     # (M, G, 2) points
    quiet, border = _quiet_zone_and_border(cells)
    return grey[:, quiet].mean(axis=1) - grey[:, border].mean(axis=1)


def _quiet_zone_and_border(cells: int) -> Tuple[np.ndarray, np.ndarray]:
    """Masks (cells + 2, cells + 2) of a marker's cell grid with its one-cell quiet zone around it (``cells``: its
    side in cells, border included): the quiet zone (the outer ring) and the black border (the ring inside it)."""
    quiet = np.ones((cells + 2, cells + 2), dtype=bool)
    quiet[1:-1, 1:-1] = False
    border = np.zeros_like(quiet)
    border[1:-1, 1:-1] = True
    border[2:-2, 2:-2] = False
    return quiet, border


def _signed_areas(q: np.ndarray) -> np.ndarray:
    """Signed areas (M,) of polygons (M, N, 2); positive when clockwise in a y-down image."""
    x, y = q[..., 0], q[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def _fit_lines(p: np.ndarray, ok: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Lines n·x = c (unit normals (L, 2), offsets (L,)) through the points p (L, k, 2) where
    ``ok`` (L, k): total least squares, then again without points beyond 3 robust σ — the
    four lines of a quad (L = 4M) together, unless one of them would keep fewer than 3
    points (then none of its four is fitted again: a quad's result never depends on the
    other quads fitted with it)."""
    w = ok.astype(float)
    for _ in range(2):
        sw = w.sum(axis=1)
        m = (w[..., None] * p).sum(axis=1) / sw[:, None]
        d = p - m[:, None, :]
        cxx = (w * d[..., 0] ** 2).sum(axis=1)
        cyy = (w * d[..., 1] ** 2).sum(axis=1)
        cxy = (w * d[..., 0] * d[..., 1]).sum(axis=1)
        theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of the line
        normal = np.stack([-np.sin(theta), np.cos(theta)], axis=1)
        r = np.abs(np.sum(d * normal[:, None, :], axis=2))
        ranked = np.sort(np.where(w > 0, r, np.inf), axis=1)
        sigma = 1.4826 * ranked[np.arange(len(r)), (w.sum(axis=1).astype(int) - 1) // 2]
        keep = w * (r <= np.maximum(3.0 * sigma, 1e-3)[:, None])
        few = np.repeat(np.any((keep.sum(axis=1) < 3).reshape(-1, 4), axis=1), 4)
        keep[few] = w[few]
        if np.array_equal(keep, w):
            break
        w = keep
    return normal, np.sum(normal * m, axis=1)

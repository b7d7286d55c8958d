"""Marker geometry on the sphere: centres, sizes, and the quad stages run on the sphere.

In: corner bearings (..., 4, 3) of markers (unit vectors, camera frame) and, for refinement
and reading, the grey equirect image. Out: centre bearings (:func:`sphere_centre_bearing`,
the diagonals intersected on the sphere; :func:`pixel_centre_bearing`, the biased pixel-space
centre, for benchmarks and tests), angular sizes (:func:`marker_angular_size`), and refined
corner bearings / readings (:func:`refine_corners_many`, :func:`decode_markers`): each marker's
quad refined or read by :mod:`.quads` in a virtual gnomonic view centred on it
(:class:`_MarkerViews`), sampled straight from the equirect through camera.py's mappings.
"""

from __future__ import annotations

from typing import List, Optional, Tuple

import cv2
import numpy as np

from ..camera import Equirect, GnomonicView, angle_between, sphere_centre_bearing
from ..transforms import cross3
from .jpegrows import bilinear_rows, need_rows, partial
from .patternfit import PATTERN_FIT, PatternFitParams, fit_patterns
from .quads import DECODE, EDGE_FIT, DecodeParams, EdgeFitParams, _remap_points, decode_quads, refine_quads

__all__ = ["sphere_centre_bearing", "pixel_centre_bearing", "marker_angular_size", "refine_corners",
           "refine_corners_many", "fit_patterns_many", "decode_marker", "decode_markers"]


def pixel_centre_bearing(equirect: Equirect, corners_px) -> np.ndarray:
    """The NAIVE centre: diagonals intersected in equirect pixel space, then turned into a
    bearing (3,). Biased toward the horizon by about δ²·tan(el)/4 radians; for the
    benchmark and tests only (pipelines use :func:`sphere_centre_bearing`).

    ``corners_px``: (4, 2) pixel coordinates; columns are unwrapped next to corner 0.
    """
    p = np.asarray(corners_px, dtype=float).copy()
    p[:, 0] = equirect.unwrap_u(p[:, 0], p[0, 0])
    d1 = p[2] - p[0]
    d2 = p[3] - p[1]
    a = np.array([[d1[0], -d2[0]], [d1[1], -d2[1]]])
    t = np.linalg.solve(a, p[1] - p[0])[0]
    u, v = p[0] + t * d1
    return equirect.pixel_to_bearing(u, v)


def marker_angular_size(corners):
    """Mean side of markers (radians): great-circle angles between adjacent corner bearings
    (..., 4, 3); a float for one marker."""
    c = np.asarray(corners, dtype=float)
    size = np.mean(angle_between(c, np.roll(c, -1, axis=-2)), axis=-1)
    return float(size) if size.ndim == 0 else size


class _MarkerViews:
    """Virtual gnomonic views (M) centred on markers (corner bearings (M, 4, 3)) at the
    equirect's resolution (nothing is rendered), and ``quads`` (M, 4, 2) the markers' corner
    pixels in them (NaN for a marker with a corner behind its view).

    One camera.py view ``view`` (centred on the first marker) maps pixels and bearings for
    all of them: view k is ``view`` turned by the smallest rotation taking its axis onto
    marker k's centre, ``turn`` (M, 3, 3): view k's bearings (rows) = ``view``'s @ ``turn[k]``.
    """

    def __init__(self, equirect: Equirect, corners):
        c = np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        self.equirect = equirect
        self.quads = np.full((len(c), 4, 2), np.nan)
        if not len(c):
            return
        centres = sphere_centre_bearing(c)
        self.view = GnomonicView(centres[0], (1, 1), 1.0 / equirect.rad_per_px, None)
        self.turn = np.transpose(_rotations_onto(centres[0], centres), (0, 2, 1))
        x, y, front = self.view.bearing_to_pixel(np.matmul(c, np.transpose(self.turn, (0, 2, 1))))
        ok = np.all(front, axis=1)
        self.quads[ok] = np.stack([x, y], axis=2)[ok]

    def bearings(self, pts: np.ndarray, sel) -> np.ndarray:
        """Bearings (M', ..., 3) of pixels (M', ..., 2) of the views ``sel`` (M' indices)."""
        b = self.view.pixel_to_bearing(pts[..., 0], pts[..., 1])
        return np.matmul(b.reshape(len(b), -1, 3), self.turn[sel]).reshape(b.shape)

    def sampler(self, grey: np.ndarray, sel):
        """``sample(pts, rows=None)`` of :func:`refine_quads`/:func:`decode_quads` for points
        (M', ..., 2) in the pixels of the views ``sel`` (``sel[rows]`` with rows): bilinear
        grey levels of the equirect, sampled through camera.py's mappings in one remap."""
        def sample(pts: np.ndarray, rows=None) -> np.ndarray:
            u, v = self.equirect.bearing_to_pixel(self.bearings(pts, sel if rows is None else sel[rows]))
            np.clip(v, 0.0, self.equirect.height - 1.0, out=v)
            if partial(grey) and v.size:
                need_rows(grey, *bilinear_rows(v))
            return _remap_points(grey, u, v, cv2.BORDER_WRAP)
        return sample


def _rotations_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotations (M, 3, 3), R·a = b_k, from a unit vector a (3,) onto unit vectors b (M, 3):
    the smallest ones (about a × b_k); for b_k nearly −a, a half turn about an axis ⟂ a
    followed by the smallest rotation from −a onto b_k."""
    def smallest(a, b):
        v = cross3(a, b)
        vx = np.zeros((len(b), 3, 3))
        vx[:, 0, 1], vx[:, 0, 2], vx[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
        vx -= np.transpose(vx, (0, 2, 1))
        return np.eye(3) + vx + np.matmul(vx, vx) / (1.0 + b @ a)[:, None, None]

    b = np.asarray(b, dtype=float).reshape(-1, 3)
    opposite = b @ a < -0.5
    r = np.empty((len(b), 3, 3))
    r[~opposite] = smallest(a, b[~opposite])
    if np.any(opposite):
        u = cross3(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        r[opposite] = np.matmul(smallest(-a, b[opposite]), 2.0 * np.outer(u, u) - np.eye(3))
    return r


def refine_corners(grey: np.ndarray, equirect: Equirect, corners, bits: int = 6, iterations: int = 2,
                   fit: EdgeFitParams = EDGE_FIT) -> Optional[np.ndarray]:
    """Refined corner bearings (4, 3) of a marker from approximate ones (4, 3), or None.

    The four outer edges of the black square are straight lines in a gnomonic view centred
    on the marker (not in the equirect, where they are curved): :func:`refine_quads` runs in
    such a virtual view, its profiles sampled straight from the equirect ``grey`` image
    (one bilinear interpolation, through camera.py's mappings).
    ``bits``: cells across the marker including its black border (6 for 4×4 dictionaries).
    """
    r = refine_corners_many(grey, equirect, np.asarray(corners, dtype=float)[None], bits, iterations, fit)[0]
    return None if np.isnan(r).any() else r


def refine_corners_many(grey: np.ndarray, equirect: Equirect, corners, bits: int = 6,
                        iterations: int = 2, fit: EdgeFitParams = EDGE_FIT) -> np.ndarray:
    """:func:`refine_corners` of M markers (corner bearings (M, 4, 3)) at once, each in its
    own virtual view, all profiles sampled in one remap: (M, 4, 3), NaN rows for failures."""
    return _in_views(grey, equirect, corners, lambda sample, quads, sel: refine_quads(sample, quads, bits, iterations,
                                                                                       fit))


def fit_patterns_many(grey: np.ndarray, equirect: Equirect, corners, codes: np.ndarray,
                      fit: PatternFitParams = PATTERN_FIT) -> np.ndarray:
    """Corner bearings (M, 4, 3) of M markers (approximate ones (M, 4, 3), ArUco order) with their inner bits
    ``codes`` (M, n, n), each fitted with its whole pattern (:func:`.patternfit.fit_patterns`) in its own virtual
    view, all sampled in one remap; NaN rows for those refused."""
    codes = np.asarray(codes)
    return _in_views(grey, equirect, corners, lambda sample, quads, sel: fit_patterns(sample, quads, codes[sel],
                                                                                       fit)[0])


def _in_views(grey: np.ndarray, equirect: Equirect, corners, refine) -> np.ndarray:
    """Corner bearings (M, 4, 3) of markers (approximate ones (M, 4, 3)) refined in their own views by
    ``refine(sample, quads (M', 4, 2), sel (M',))`` → quads (M', 4, 2), NaN rows for failures (and for markers
    with a corner behind its view)."""
    mv = _MarkerViews(equirect, corners)
    out = np.full((len(mv.quads), 4, 3), np.nan)
    sel = np.flatnonzero(~np.isnan(mv.quads).any(axis=(1, 2)))
    if len(sel):
        r = refine(mv.sampler(grey, sel), mv.quads[sel], sel)
        good = ~np.isnan(r).any(axis=(1, 2))
        if np.any(good):
            out[sel[good]] = mv.bearings(r[good], sel[good])
    return out


def decode_marker(grey: np.ndarray, equirect: Equirect, corners, codes: np.ndarray,
                  thresholds: DecodeParams = DECODE) -> Optional[Tuple[int, np.ndarray]]:
    """Read a candidate quad (corner bearings (4, 3)) straight from the equirect:
    ``(id, corner bearings in ArUco order)`` or None. :func:`decode_quads` in a virtual
    gnomonic view centred on the quad (exact homography for a planar marker), sampling the
    equirect through camera.py's mappings.
    """
    return decode_markers(grey, equirect, np.asarray(corners, dtype=float)[None], codes, thresholds)[0]


def decode_markers(grey: np.ndarray, equirect: Equirect, corners, codes: np.ndarray,
                   thresholds: DecodeParams = DECODE) -> List[Optional[Tuple[int, np.ndarray]]]:
    """:func:`decode_marker` of M candidate quads (corner bearings (M, 4, 3)) at once, all
    cells sampled in one remap: one ``(id, corner bearings)`` or None per quad."""
    mv = _MarkerViews(equirect, corners)
    out: List[Optional[Tuple[int, np.ndarray]]] = [None] * len(mv.quads)
    sel = np.flatnonzero(~np.isnan(mv.quads).any(axis=(1, 2)))
    if len(sel):
        hits = decode_quads(mv.sampler(grey, sel), mv.quads[sel], codes, thresholds)
        for k, hit in zip(sel, hits):
            if hit is not None:
                out[k] = (hit[0], mv.bearings(hit[1][None], [k])[0])
    return out

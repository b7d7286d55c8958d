"""ArUco markers in 360° equirectangular frames (DESIGN §4 steps 1–2).

Full-frame detection (:meth:`MarkerDetector.detect`): cv2.aruco tuned for small far
markers on the whole frame (up to ``pole_overlap_deg`` beyond the polar band); a strip
around the ±180° seam searched again with its halves swapped (the image rolled by W/2
there), for markers straddling the seam (only what reaches across the seam is refined and
read there); two gnomonic (perspective) views of the polar bands, where equirect shapes
are too distorted for OpenCV. The seam and polar searches run in threads beside the full
pass when OpenCV has threads (``cv2.setNumThreads``); the results do not depend on it.
Then this module's own steps: every marker's corners are refined by fitting straight lines
to its four edges in a gnomonic view (never in the equirect, where they are curved), every
id OpenCV read is checked by reading the cells again, and the quads OpenCV rejected —
small far markers whose 1–2 px cells it cannot threshold, close markers too curved for it
— are refined and read here (:func:`decode_quad`).

Each marker becomes a :class:`MarkerObservation` whose centre is the intersection of the
diagonals **on the sphere** (great circles through opposite corners), not in pixel space:
the pixel-space intersection of an equirect image is biased toward the horizon by about
δ²·tan(el)/4 (δ the marker's angular size, el its elevation) for a marker standing on a
corner and up to 1.5× that for an upright one: 0.5–1.3° at 1 m and 45–60° elevation.
:func:`pixel_centre_bearing` computes that biased centre, for the benchmark and tests only.

Map-guided tracking (DESIGN §4 step 3) lives in :mod:`aruco_abs_orient.tracking`.

All pixel↔bearing conversions go through :mod:`aruco_abs_orient.camera`. Angles are in
radians inside the code; the few parameters in degrees say so in their names (``*_deg``).
Works with both OpenCV ArUco APIs: ``cv2.aruco.ArucoDetector`` (OpenCV ≥ 4.7) and the
function API (``detectMarkers``/``DetectorParameters_create``) of OpenCV 4.2–4.6.
Python 3.8 compatible; numpy and OpenCV only.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..camera import Equirect, GnomonicView, angle_between, bearing_to_azel
from ..markers import ARUCO_DICTIONARIES

__all__ = [
    "DetectionError",
    "DetectorParams",
    "MarkerObservation",
    "ArucoBackend",
    "MarkerDetector",
    "decode_jpeg",
    "to_grey",
    "sphere_centre_bearing",
    "pixel_centre_bearing",
    "marker_angular_size",
    "bearing_sigma",
    "refine_corners",
    "refine_corners_many",
    "decode_marker",
    "decode_markers",
    "refine_quad",
    "refine_quads",
    "decode_quad",
    "decode_quads",
    "dedupe_observations",
    "image_sampler",
    "RESCUE_SHRINK",
]

class DetectionError(ValueError):
    """An image, JPEG or dictionary the detector cannot use; the caller counts and skips."""


@dataclass
class DetectorParams:
    """Every knob of detection and tracking, flat scalars (exposed via dynamic_reconfigure).

    cv2.aruco (see ``cv2.aruco.DetectorParameters``):

    - ``min_marker_perimeter_px``: smallest marker perimeter searched for, in pixels of
      the equirect image (DESIGN §6: OpenCV's default rate 0.03 of 3840 px = 115 px finds
      nothing beyond ~4 m). 28 px = 7 px sides: a 0.19 m marker at ~16 m on 3840 px.
      Converted to OpenCV's ``minMarkerPerimeterRate`` for each (sub)image searched.
    - ``max_marker_perimeter_rate``: largest perimeter as a fraction of the searched image's
      larger side (OpenCV's rate).
    - ``adaptive_thresh_win_min/max/step`` (pixels, odd), ``adaptive_thresh_constant`` (grey levels).
    - ``polygonal_approx_accuracy_rate``: polygon fit tolerance (fraction of the perimeter).
    - ``min_corner_distance_rate``: (fraction of the perimeter).
    - ``min_distance_to_border``: pixels.
    - ``min_marker_distance_rate``: candidates closer than this fraction of the perimeter
      are merged; 0 keeps the OpenCV version's own default, which suits its merging logic
      (0.125 since 4.10, 0.05 before: 4.11 loses close markers with 0.05, 4.6 small ones
      with 0.125). The merge may keep the outline around a small marker's quiet zone
      instead of its black square: the rescue also tries that quad shrunk (see below).
    - ``perspective_remove_pixel_per_cell``: pixels per bit cell of the unwarped code.
    - ``perspective_remove_ignored_margin_per_cell``: fraction of a cell.
    - ``max_erroneous_bits_in_border_rate``, ``error_correction_rate``: bit decoding
      tolerance (lower = fewer false ids).
    - ``corner_refinement``: 'none' | 'subpix' | 'contour' | 'apriltag';
      ``corner_refine_win`` (pixels, half window), ``corner_refine_max_iter``,
      ``corner_refine_min_accuracy`` (pixels).

    360° handling:

    - ``seam_strip_deg``: half width (degrees of azimuth) of the strip re-searched around
      the ±180° seam (a marker on the seam must fit in it: 0.19 m at ≥ 0.45 m).
    - ``pole_views``: search two gnomonic views (zenith, nadir) for markers in the polar
      bands ``|el| > pole_band_deg`` (degrees), where equirect shapes are too distorted.
    - ``pole_overlap_deg``: with ``pole_views``, the whole frame and the seam strip are
      searched only up to ``pole_band_deg`` + this (degrees) from the horizon: enough for a
      marker centred on the band's edge at 0.45 m; the polar views see the rest.
    - ``max_view_px``: cap on a view's side (pixels); larger views lower their resolution.

    Corners and ids (this module's own steps after OpenCV's):

    - ``edge_refine``: refine every marker's corners by fitting lines to its edges in a
      gnomonic view (:func:`refine_corners`); OpenCV's subpixel corners are off by
      0.2–0.6 px on blurred small markers.
    - ``view_refine_iterations``: edge-fit iterations for markers OpenCV found in a rendered
      gnomonic view (tracking ROIs, polar views), refined in that image.
    - ``verify_decode``: re-read every OpenCV-decoded marker (:func:`decode_marker`) and drop
      it unless the cells give the same id (OpenCV misreads small markers on texture).
    - ``rescue_max_side_px``: quads OpenCV rejected with sides up to this (equirect pixels)
      are refined and read by :func:`decode_quad` (as they are, and shrunk by
      ``RESCUE_SHRINK``); this is what reaches 12 m (9–10 px markers at 3840 px).
    - ``close_range_size_deg``: so are rejected quads with sides above this (degrees): close
      markers whose equirect image is too curved for OpenCV to read.
    - ``decode_min_contrast`` (grey levels), ``decode_min_correlation``, ``decode_min_lead``,
      ``decode_min_pattern_correlation``: acceptance thresholds of :func:`decode_marker`.

    Noise model (1-σ centre bearing, radians, see :func:`bearing_sigma`):

    - ``corner_sigma_px``: corner noise of a well-resolved marker (pixels).
    - ``small_marker_side_px``: side (pixels) below which corner noise grows ∝ 1/side².
    - ``tracked_sigma_scale``: factor for markers refined in tracking ROI views.

    Map-guided tracking (:class:`aruco_abs_orient.tracking.MarkerTracker`):

    - ``roi_margin``: ROI view field of view = angular size × (1 + 2·margin) + 2·gate.
    - ``roi_min_px``: smallest ROI view side (pixels).
    - ``roi_target_side_px``: ROI views of small markers are upsampled until the marker's
      side spans this many pixels (pixels) ...
    - ``roi_max_upsample``: ... by at most this factor.
    - ``gate_deg``: largest angle (degrees) between an observed and a predicted centre.
    - ``min_predicted_side_px``: markers predicted smaller than this (pixels of the
      equirect) are not tracked.
    - ``sweep_tile_deg``: width (degrees of azimuth) of the vertical strip searched each
      frame while tracking, so markers the prediction misses are found.
    - ``sweep_period_frames``: frames for the sweeping tile to go once around 360°.
    - ``sweep_every_frames``: the tile is searched on every n-th frame only (and moves by
      n steps then).
    - ``sweep_max_el_deg``: the tile spans elevations within this (degrees) of the horizon.
    - ``max_full_interval``: frames between forced full-frame searches while tracking
      (0 = only at start-up and after a loss).
    - ``lost_after_frames``: consecutive frames with predictions but no accepted marker
      after which tracking falls back to full-frame search.
    """

    min_marker_perimeter_px: float = 28.0
    max_marker_perimeter_rate: float = 4.0
    adaptive_thresh_win_min: int = 3
    adaptive_thresh_win_max: int = 23
    adaptive_thresh_win_step: int = 10
    adaptive_thresh_constant: float = 7.0
    polygonal_approx_accuracy_rate: float = 0.05
    min_corner_distance_rate: float = 0.05
    min_distance_to_border: int = 1
    min_marker_distance_rate: float = 0.0
    perspective_remove_pixel_per_cell: int = 8
    perspective_remove_ignored_margin_per_cell: float = 0.13
    max_erroneous_bits_in_border_rate: float = 0.35
    error_correction_rate: float = 0.6
    corner_refinement: str = "subpix"
    corner_refine_win: int = 3
    corner_refine_max_iter: int = 50
    corner_refine_min_accuracy: float = 0.01

    close_range_size_deg: float = 8.0
    seam_strip_deg: float = 25.0
    pole_views: bool = True
    pole_band_deg: float = 55.0
    pole_overlap_deg: float = 20.0
    max_view_px: int = 1024

    edge_refine: bool = True
    view_refine_iterations: int = 2
    verify_decode: bool = True
    rescue_max_side_px: float = 30.0
    decode_min_contrast: float = 40.0
    decode_min_correlation: float = 0.75
    decode_min_lead: float = 0.15
    decode_min_pattern_correlation: float = 0.9

    corner_sigma_px: float = 0.03
    small_marker_side_px: float = 30.0
    tracked_sigma_scale: float = 2.0

    roi_margin: float = 0.5
    roi_min_px: int = 32
    roi_target_side_px: float = 16.0
    roi_max_upsample: float = 3.0
    gate_deg: float = 1.0
    min_predicted_side_px: float = 6.0
    sweep_tile_deg: float = 8.0
    sweep_period_frames: int = 72
    sweep_every_frames: int = 2
    sweep_max_el_deg: float = 60.0
    max_full_interval: int = 0
    lost_after_frames: int = 3

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise DetectionError naming the first out-of-range field."""
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (bool, str)):
                continue
            if not math.isfinite(v) or v < 0:
                raise DetectionError(f"DetectorParams.{f.name}: expected a finite non-negative number, got {v!r}")
        if self.corner_refinement not in _REFINE:
            raise DetectionError(f"DetectorParams.corner_refinement: expected one of {', '.join(_REFINE)}, "
                                 f"got {self.corner_refinement!r}")
        if self.adaptive_thresh_win_min < 3 or self.adaptive_thresh_win_max < self.adaptive_thresh_win_min:
            raise DetectionError("DetectorParams.adaptive_thresh_win_min/max: need 3 ≤ min ≤ max, got "
                                 f"{self.adaptive_thresh_win_min}, {self.adaptive_thresh_win_max}")
        if not 0.0 < self.pole_band_deg < 90.0:
            raise DetectionError(f"DetectorParams.pole_band_deg: expected (0, 90) degrees, got {self.pole_band_deg}")
        if self.sweep_period_frames < 1:
            raise DetectionError("DetectorParams.sweep_period_frames: expected ≥ 1")


_REFINE = {"none": "CORNER_REFINE_NONE", "subpix": "CORNER_REFINE_SUBPIX",
           "contour": "CORNER_REFINE_CONTOUR", "apriltag": "CORNER_REFINE_APRILTAG"}


@dataclass
class MarkerObservation:
    """One marker seen in one equirect frame.

    - ``id``: ArUco id.
    - ``corners``: (4, 3) unit bearings (camera frame) of the corners, OpenCV ArUco order
      (TL, TR, BR, BL as seen from the front).
    - ``centre``: (3,) unit bearing of the centre: the diagonals intersected on the sphere.
    - ``pixel``: (u, v) of ``centre`` in the equirect image (pixels, OpenCV centres).
    - ``corners_px``: (4, 2) corner pixels in the equirect image, u unwrapped next to corner 0
      (may leave [0, W) for a marker on the seam).
    - ``angular_size``: mean side (radians, great-circle angle between adjacent corners).
    - ``sigma``: 1-σ noise of the centre bearing (radians, per axis).
    - ``method``: 'full' | 'seam' | 'gnomonic' | 'tracked'.
    """

    id: int
    corners: np.ndarray
    centre: np.ndarray
    pixel: Tuple[float, float]
    corners_px: np.ndarray
    angular_size: float
    sigma: float
    method: str
    side_px: float = field(default=0.0)  # mean side in the pixels it was detected in

    @property
    def azimuth(self) -> float:
        """Azimuth of the centre (radians, 0 = camera +x, +π/2 = camera left)."""
        return float(bearing_to_azel(self.centre)[0])

    @property
    def elevation(self) -> float:
        """Elevation of the centre (radians, +π/2 = up)."""
        return float(bearing_to_azel(self.centre)[1])


# --------------------------------------------------------------------------- geometry

def sphere_centre_bearing(corners) -> np.ndarray:
    """Centre bearing (..., 3) of markers from their four corner bearings (..., 4, 3).

    Intersection of the great circles through opposite corners (n1 = c0×c2, n2 = c1×c3,
    centre = ±n1×n2, the sign nearest the corners' mean). Exact for a planar square seen
    by a central camera: the diagonals' intersection is the square's centre and lines
    project to great circles. A degenerate quad gives the corners' mean direction.
    """
    c = np.asarray(corners, dtype=float)
    c = c / np.linalg.norm(c, axis=-1, keepdims=True)
    m = np.cross(np.cross(c[..., 0, :], c[..., 2, :]), np.cross(c[..., 1, :], c[..., 3, :]))
    norm = np.linalg.norm(m, axis=-1, keepdims=True)
    mean = c.mean(axis=-2)
    m = np.where(norm < 1e-15, mean, m / np.maximum(norm, 1e-300))
    m = np.where(np.sum(m * mean, axis=-1, keepdims=True) < 0, -m, m)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


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


def bearing_sigma(params: DetectorParams, pitch: float, side_px: float, method: str = "full") -> float:
    """1-σ centre bearing noise (radians, per axis) of a marker with ``side_px`` pixel sides
    in an image of angular pixel pitch ``pitch`` (radians/pixel), found by ``method``.

    Corner noise ``corner_sigma_px`` for a well-resolved marker, growing ∝ 1/side² below
    ``small_marker_side_px`` (1–2 px cells: the edge fit loses its straight run); the
    centre averages four corners (÷2); ``tracked_sigma_scale`` × for markers refined in a
    resampled ROI view. Calibrated on rendered 'realistic' frames (bench/detection.py:
    median |error| ≈ 1.18 σ at every range).
    """
    grow = max(1.0, (params.small_marker_side_px / max(side_px, 1e-6)) ** 2)
    scale = params.tracked_sigma_scale if method == "tracked" else 1.0
    return float(pitch * params.corner_sigma_px * grow * scale / 2.0)


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
            return _remap_points(grey, u, v, cv2.BORDER_WRAP)
        return sample


def _rotations_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotations (M, 3, 3), R·a = b_k, from a unit vector a (3,) onto unit vectors b (M, 3):
    the smallest ones (about a × b_k); for b_k nearly −a, a half turn about an axis ⟂ a
    followed by the smallest rotation from −a onto b_k."""
    def smallest(a, b):
        v = np.cross(a, b)
        vx = np.zeros((len(b), 3, 3))
        vx[:, 0, 1], vx[:, 0, 2], vx[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
        vx -= np.transpose(vx, (0, 2, 1))
        return np.eye(3) + vx + np.matmul(vx, vx) / (1.0 + b @ a)[:, None, None]

    b = np.asarray(b, dtype=float).reshape(-1, 3)
    opposite = b @ a < -0.5
    r = np.empty((len(b), 3, 3))
    r[~opposite] = smallest(a, b[~opposite])
    if np.any(opposite):
        u = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        r[opposite] = np.matmul(smallest(-a, b[opposite]), 2.0 * np.outer(u, u) - np.eye(3))
    return r


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


def refine_corners(grey: np.ndarray, equirect: Equirect, corners, bits: int = 6, iterations: int = 2,
                   ) -> Optional[np.ndarray]:
    """Refined corner bearings (4, 3) of a marker from approximate ones (4, 3), or None.

    The four outer edges of the black square are straight lines in a gnomonic view centred
    on the marker (not in the equirect, where they are curved): :func:`refine_quad` runs in
    such a virtual view, its profiles sampled straight from the equirect ``grey`` image
    (one bilinear interpolation, through camera.py's mappings).
    ``bits``: cells across the marker including its black border (6 for 4×4 dictionaries).
    """
    r = refine_corners_many(grey, equirect, np.asarray(corners, dtype=float)[None], bits, iterations)[0]
    return None if np.isnan(r).any() else r


def refine_corners_many(grey: np.ndarray, equirect: Equirect, corners, bits: int = 6,
                        iterations: int = 2) -> np.ndarray:
    """:func:`refine_corners` of M markers (corner bearings (M, 4, 3)) at once, each in its
    own virtual view, all profiles sampled in one remap: (M, 4, 3), NaN rows for failures."""
    mv = _MarkerViews(equirect, corners)
    out = np.full((len(mv.quads), 4, 3), np.nan)
    sel = np.flatnonzero(~np.isnan(mv.quads).any(axis=(1, 2)))
    if len(sel):
        r = refine_quads(mv.sampler(grey, sel), mv.quads[sel], bits, iterations)
        good = ~np.isnan(r).any(axis=(1, 2))
        if np.any(good):
            out[sel[good]] = mv.bearings(r[good], sel[good])
    return out


def refine_quad(sample, q: np.ndarray, bits: int = 6, iterations: int = 2, **kw) -> Optional[np.ndarray]:
    """Refined corners (4, 2) of one marker quad, or None: :func:`refine_quads` for one."""
    r = refine_quads(sample, np.asarray(q, dtype=float)[None], bits, iterations, **kw)[0]
    return None if np.isnan(r).any() else r


def refine_quads(sample, quads: np.ndarray, bits: int = 6, iterations: int = 2, min_contrast: float = 12.0,
                 min_half_px: float = 1.5, half_bits: float = 0.45, samples: int = 16,
                 along: int = 20) -> np.ndarray:
    """Refined corners (M, 4, 2) of markers' black squares in a perspective image; NaN rows
    for the quads that fail (too small, too little contrast, diverging).

    ``sample(pts, rows)``: grey levels at image points (R, ..., 2) (pixels) of the quads
    ``rows`` (R indices into ``quads``; :func:`image_sampler`); ``quads`` (M, 4, 2):
    approximate corners. Along each edge (``along`` profiles) the intensity profile across
    it is sampled, the edge is located at the centroid of the black→white gradient within
    ±max(``half_bits`` bit, ``min_half_px`` pixels) of the current line (``samples`` steps),
    a line is fitted to each edge (robust total least squares) and adjacent lines are
    intersected; iterated ``iterations`` times, re-centring the profiles on the new lines.
    ``min_contrast``: grey levels a profile must rise by to count. All markers at once.
    """
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


def decode_marker(grey: np.ndarray, equirect: Equirect, corners, codes: np.ndarray,
                  min_contrast: float = 40.0, min_correlation: float = 0.75,
                  min_lead: float = 0.15, min_pattern_correlation: float = 0.9) -> Optional[Tuple[int, np.ndarray]]:
    """Read a candidate quad (corner bearings (4, 3)) straight from the equirect:
    ``(id, corner bearings in ArUco order)`` or None. :func:`decode_quad` in a virtual
    gnomonic view centred on the quad (exact homography for a planar marker), sampling the
    equirect through camera.py's mappings.
    """
    return decode_markers(grey, equirect, np.asarray(corners, dtype=float)[None], codes, min_contrast,
                          min_correlation, min_lead, min_pattern_correlation)[0]


def decode_markers(grey: np.ndarray, equirect: Equirect, corners, codes: np.ndarray,
                   min_contrast: float = 40.0, min_correlation: float = 0.75, min_lead: float = 0.15,
                   min_pattern_correlation: float = 0.9) -> List[Optional[Tuple[int, np.ndarray]]]:
    """:func:`decode_marker` of M candidate quads (corner bearings (M, 4, 3)) at once, all
    cells sampled in one remap: one ``(id, corner bearings)`` or None per quad."""
    mv = _MarkerViews(equirect, corners)
    out: List[Optional[Tuple[int, np.ndarray]]] = [None] * len(mv.quads)
    sel = np.flatnonzero(~np.isnan(mv.quads).any(axis=(1, 2)))
    if len(sel):
        hits = decode_quads(mv.sampler(grey, sel), mv.quads[sel], codes, min_contrast, min_correlation, min_lead,
                            min_pattern_correlation)
        for k, hit in zip(sel, hits):
            if hit is not None:
                out[k] = (hit[0], mv.bearings(hit[1][None], [k])[0])
    return out


def decode_quad(sample, q: np.ndarray, codes: np.ndarray, min_contrast: float = 40.0,
                min_correlation: float = 0.75, min_lead: float = 0.15,
                min_pattern_correlation: float = 0.9) -> Optional[Tuple[int, np.ndarray]]:
    """Read a marker quad (4, 2) of a perspective image: ``(id, corners (4, 2) in ArUco
    order)`` or None. ``sample(pts)``: grey levels at image points (..., 2).

    For small markers whose bits OpenCV cannot threshold (1–2 px cells, blurred). The
    centres of the marker's cells and of the one-cell white quiet zone around it are mapped
    by the quad's homography, 3×3 sub-samples per cell. Accepted when every quiet-zone cell
    is brighter than every border cell by ≥ ``min_contrast`` grey levels, and the Pearson
    correlation of the inner cells' grey levels with one code's bits, in one of the four
    corner orders, is ≥ ``min_correlation`` and leads every other code/order by
    ≥ ``min_lead`` (a soft decision: blur lowers isolated white bits below any fixed
    threshold, not their rank), and the whole 8×8 pattern (quiet zone, border, bits)
    correlates ≥ ``min_pattern_correlation`` with the grey levels.
    ``codes``: (N, n, n) inner bits of the dictionary (1 = white), rotation 0.
    """
    return decode_quads(lambda pts: sample(pts[0])[None], np.asarray(q, dtype=float)[None], codes, min_contrast,
                        min_correlation, min_lead, min_pattern_correlation)[0]


def decode_quads(sample, quads: np.ndarray, codes: np.ndarray, min_contrast: float = 40.0,
                 min_correlation: float = 0.75, min_lead: float = 0.15,
                 min_pattern_correlation: float = 0.9) -> List[Optional[Tuple[int, np.ndarray]]]:
    """:func:`decode_quad` of M quads (M, 4, 2) at once: ``sample(pts)`` gets the points
    (M, ..., 2) of all of them in one call; one ``(id, corners)`` or None per quad."""
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
    quads = np.array([q[::-1] if _signed_area(q) < 0 else q for q in quads])
    pts = np.stack([cv2.perspectiveTransform(grid, cv2.getPerspectiveTransform(square, q.astype(np.float32)))
                    for q in quads]).reshape(len(quads), len(gx), len(gx), 2)
    cm = sample(pts).reshape(len(quads), cells + 2, 3, cells + 2, 3).mean(axis=(2, 4))
    ring = np.concatenate([cm[:, 0], cm[:, -1], cm[:, 1:-1, 0], cm[:, 1:-1, -1]], axis=1)  # quiet zone
    border = np.concatenate([cm[:, 1, 1:-1], cm[:, -2, 1:-1], cm[:, 2:-2, 1], cm[:, 2:-2, -2]], axis=1)
    contrast = np.min(ring, axis=1) - np.max(border, axis=1) >= min_contrast
    whole = np.ones((cells + 2, cells + 2))  # the whole pattern: quiet zone, border, bits
    whole[1:-1, 1:-1] = 0.0
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


def _signed_area(q: np.ndarray) -> float:
    """Signed area of a polygon (N, 2); positive when clockwise in a y-down image."""
    return 0.5 * float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))


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


# --------------------------------------------------------------------------- images

def to_grey(image, what: str = "image") -> np.ndarray:
    """Validate an equirect frame (grey H×W, or BGR/BGRA H×W×3/4, uint8, W = 2H) and return grey.

    Raises DetectionError naming ``what``.
    """
    if not isinstance(image, np.ndarray):
        raise DetectionError(f"{what}: expected a numpy image, got {type(image).__name__}")
    if image.size == 0:
        raise DetectionError(f"{what}: empty image {image.shape}")
    if image.dtype != np.uint8:
        raise DetectionError(f"{what}: expected uint8 pixels, got {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    elif image.ndim != 2:
        raise DetectionError(f"{what}: expected grey H×W or colour H×W×3, got shape {image.shape}")
    h, w = image.shape
    if w != 2 * h:
        raise DetectionError(f"{what}: an equirectangular frame is 2:1, got {w}×{h}")
    return image


def decode_jpeg(data, reduce: int = 1, what: str = "jpeg") -> np.ndarray:
    """Decode JPEG bytes to a grey uint8 image, optionally reduced by 2, 4 or 8 in the DCT.

    Uses simplejpeg (libjpeg-turbo, the fastest measured here: bench/detection.py) when
    installed, else ``cv2.imdecode`` (IMREAD_GRAYSCALE / IMREAD_REDUCED_GRAYSCALE_n).
    Raises DetectionError on a corrupt or truncated JPEG.
    """
    if reduce not in (1, 2, 4, 8):
        raise DetectionError(f"{what}: reduce must be 1, 2, 4 or 8, got {reduce!r}")
    buf = bytes(data) if not isinstance(data, (bytes, bytearray)) else data
    if len(buf) < 4 or buf[:2] != b"\xff\xd8":
        raise DetectionError(f"{what}: not a JPEG (no SOI marker, {len(buf)} bytes)")
    try:
        import simplejpeg
    except ImportError:  # Noetic robots: OpenCV only
        simplejpeg = None
    if simplejpeg is not None:
        try:
            h, w = simplejpeg.decode_jpeg_header(buf)[:2]
            img = simplejpeg.decode_jpeg(buf, colorspace="GRAY", min_height=h // reduce, min_width=w // reduce,
                                         min_factor=float(reduce))
        except ValueError as e:
            raise DetectionError(f"{what}: corrupt JPEG: {e}") from None
        return img[:, :, 0] if img.ndim == 3 else img
    flag = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
            8: cv2.IMREAD_REDUCED_GRAYSCALE_8}[reduce]
    img = cv2.imdecode(np.frombuffer(buf, dtype=np.uint8), flag)
    if img is None or buf[-2:] != b"\xff\xd9":
        raise DetectionError(f"{what}: corrupt or truncated JPEG ({len(buf)} bytes)")
    if reduce > 1 and not _IMDECODE_REDUCES:  # average reduce×reduce blocks, as the DCT scaling does
        img = cv2.resize(img, (-(-img.shape[1] // reduce), -(-img.shape[0] // reduce)), interpolation=cv2.INTER_AREA)
    return img


def _imdecode_reduces() -> bool:
    """Whether ``cv2.imdecode`` honours IMREAD_REDUCED_* (OpenCV 4.6 and 4.11 do; Noetic's 4.2
    ignores it and decodes at full size)."""
    probe = cv2.imencode(".jpg", np.zeros((16, 16), np.uint8))[1]
    return cv2.imdecode(probe, cv2.IMREAD_REDUCED_GRAYSCALE_2).shape == (8, 8)


_IMDECODE_REDUCES = _imdecode_reduces()


# --------------------------------------------------------------------------- OpenCV adapter

class ArucoBackend:
    """cv2.aruco behind one call, for both APIs.

    ``api`` is 'ArucoDetector' (OpenCV ≥ 4.7) or 'function' (OpenCV 4.2–4.6:
    ``detectMarkers`` with ``DetectorParameters_create``/``Dictionary_get``).
    """

    def __init__(self, dictionary: str, params: DetectorParams, api: Optional[str] = None):
        if not hasattr(cv2, "aruco"):
            raise DetectionError("OpenCV was built without the aruco module (install opencv-contrib)")
        aruco = cv2.aruco
        if dictionary not in ARUCO_DICTIONARIES or not hasattr(aruco, dictionary):
            raise DetectionError(f"unknown ArUco dictionary {dictionary!r}; expected one of "
                                 f"{', '.join(d for d in ARUCO_DICTIONARIES if hasattr(aruco, d))}")
        if api is None:
            api = "ArucoDetector" if hasattr(aruco, "ArucoDetector") else "function"
        if api not in ("ArucoDetector", "function"):
            raise DetectionError(f"unknown OpenCV ArUco API {api!r}")
        if api == "function" and not hasattr(aruco, "detectMarkers"):
            raise DetectionError(f"this OpenCV {cv2.__version__} has no aruco.detectMarkers function API")
        self.api = api
        self.params = params
        dict_id = getattr(aruco, dictionary)
        if api == "function" and hasattr(aruco, "Dictionary_get"):
            self.dictionary = aruco.Dictionary_get(dict_id)
        else:
            self.dictionary = aruco.getPredefinedDictionary(dict_id)
        n = int(self.dictionary.markerSize)
        self.bits = n + 2  #: cells across a marker, black border included
        blist = self.dictionary.bytesList
        #: (N, n, n) bits of every code (1 = white), rotation 0, indexed by id
        self.codes = np.array([aruco.Dictionary_getBitsFromByteList(blist[i:i + 1], n) for i in range(len(blist))],
                              dtype=bool)
        self._cache: Dict[float, object] = {}

    def _cv_params(self, min_perimeter_rate: float):
        aruco = cv2.aruco
        p = aruco.DetectorParameters() if self.api == "ArucoDetector" else aruco.DetectorParameters_create()
        q = self.params
        p.minMarkerPerimeterRate = float(min_perimeter_rate)
        p.maxMarkerPerimeterRate = float(q.max_marker_perimeter_rate)
        p.adaptiveThreshWinSizeMin = int(q.adaptive_thresh_win_min)
        p.adaptiveThreshWinSizeMax = int(q.adaptive_thresh_win_max)
        p.adaptiveThreshWinSizeStep = max(1, int(q.adaptive_thresh_win_step))
        p.adaptiveThreshConstant = float(q.adaptive_thresh_constant)
        p.polygonalApproxAccuracyRate = float(q.polygonal_approx_accuracy_rate)
        p.minCornerDistanceRate = float(q.min_corner_distance_rate)
        p.minDistanceToBorder = int(q.min_distance_to_border)
        if q.min_marker_distance_rate > 0:
            p.minMarkerDistanceRate = float(q.min_marker_distance_rate)
        p.perspectiveRemovePixelPerCell = int(q.perspective_remove_pixel_per_cell)
        p.perspectiveRemoveIgnoredMarginPerCell = float(q.perspective_remove_ignored_margin_per_cell)
        p.maxErroneousBitsInBorderRate = float(q.max_erroneous_bits_in_border_rate)
        p.errorCorrectionRate = float(q.error_correction_rate)
        p.cornerRefinementMethod = int(getattr(aruco, _REFINE[q.corner_refinement]))
        p.cornerRefinementWinSize = int(q.corner_refine_win)
        if hasattr(p, "relativeCornerRefinmentWinSize"):  # [sic]
            # newer OpenCV (4.11 here; not 4.2) shrinks the subpixel window to 0.3 cells of a small
            # marker: keep corner_refine_win on every version, so both APIs give the same corners
            p.relativeCornerRefinmentWinSize = 1000.0
        p.cornerRefinementMaxIterations = int(q.corner_refine_max_iter)
        p.cornerRefinementMinAccuracy = float(q.corner_refine_min_accuracy)
        return p

    def detect(self, grey: np.ndarray, min_perimeter_px: float
               ) -> Tuple[List[int], List[np.ndarray], List[np.ndarray]]:
        """ids and (4, 2) float64 corner pixels of the markers in a grey image, and the
        (4, 2) corner pixels of the quads OpenCV rejected (could not decode).

        ``min_perimeter_px``: smallest perimeter searched (pixels of this image).
        """
        rate = round(min(float(min_perimeter_px) / max(grey.shape[:2]), 4.0), 6)
        entry = self._cache.get(rate)
        if entry is None:
            p = self._cv_params(rate)
            entry = cv2.aruco.ArucoDetector(self.dictionary, p) if self.api == "ArucoDetector" else p
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[rate] = entry
        if self.api == "ArucoDetector":
            corners, ids, rejected = entry.detectMarkers(grey)
        else:
            corners, ids, rejected = cv2.aruco.detectMarkers(grey, self.dictionary, parameters=entry)
        rejected = [np.asarray(c, dtype=np.float64).reshape(4, 2) for c in rejected]
        if ids is None or len(ids) == 0:
            return [], [], rejected
        return ([int(i) for i in np.asarray(ids).reshape(-1)],
                [np.asarray(c, dtype=np.float64).reshape(4, 2) for c in corners], rejected)


# --------------------------------------------------------------------------- the detector

class MarkerDetector:
    """Full-frame ArUco detection in equirect frames, seam- and pole-aware.

    >>> det = MarkerDetector("DICT_4X4_50")          # doctest: +SKIP
    >>> observations = det.detect(grey_equirect)     # doctest: +SKIP
    """

    def __init__(self, dictionary: str = "DICT_4X4_50", params: Optional[DetectorParams] = None,
                 api: Optional[str] = None):
        self.params = params if params is not None else DetectorParams()
        self.params.validate()
        self.backend = ArucoBackend(dictionary, self.params, api)
        self._pole_maps: Dict[Tuple[int, int], Tuple[GnomonicView, np.ndarray, np.ndarray]] = {}
        self._threads: Optional[Tuple[int, ThreadPoolExecutor]] = None

    # ---------------------------------------------------------------- building blocks

    def observation(self, equirect: Equirect, marker_id: int, corners: np.ndarray,
                    method: str) -> MarkerObservation:
        """A record from corner bearings (4, 3) in ArUco order."""
        return self.observations(equirect, [marker_id], np.asarray(corners)[None], method)[0]

    def observations(self, equirect: Equirect, ids: Sequence[int], corners: np.ndarray,
                     method: str) -> List[MarkerObservation]:
        """Records from corner bearings (M, 4, 3) in ArUco order, all at once."""
        corners = np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        centres = sphere_centre_bearing(corners)
        u, v = equirect.bearing_to_pixel(np.concatenate([centres[:, None], corners], axis=1))  # (M, 5)
        cu = equirect.unwrap_u(u[:, 1:], u[:, 1:2])
        sizes = np.atleast_1d(marker_angular_size(corners))
        out = []
        for k, marker_id in enumerate(ids):
            side_px = float(sizes[k]) / equirect.rad_per_px
            out.append(MarkerObservation(
                id=int(marker_id), corners=corners[k], centre=centres[k], pixel=(float(u[k, 0]), float(v[k, 0])),
                corners_px=np.stack([cu[k], v[k, 1:]], axis=1), angular_size=float(sizes[k]),
                sigma=bearing_sigma(self.params, equirect.rad_per_px, side_px, method), method=method,
                side_px=side_px))
        return out

    def _finish(self, grey: np.ndarray, equirect: Equirect, found: Tuple[List[int], List[np.ndarray],
                List[np.ndarray]], to_bearing, scale: float, method: str, image: np.ndarray,
                perspective: bool, expect_id: Optional[int] = None, rescue: bool = True,
                skip_ids: Sequence[int] = ()) -> List[MarkerObservation]:
        """Observations from a backend result in ``image``: edge-refined corners of the
        decoded markers, plus rejected quads decoded here (small ones up to
        ``rescue_max_side_px``, large ones from ``close_range_size_deg``).

        ``to_bearing(x, y)``: the image's pixels to bearings; ``scale``: its pixels per
        equirect pixel; ``perspective``: the image is a gnomonic view with exact enough maps
        (corners are refined and read in it directly), else an equirect strip (refined on
        the sphere, :func:`refine_corners`); ``expect_id``: keep only this id (tracking:
        OpenCV's reading of the predicted id at the predicted place is not re-verified);
        ``rescue``: decode the quads OpenCV rejected; ``skip_ids``: ids OpenCV read that are
        not wanted (already observed).
        """
        q = self.params
        bits = self.backend.bits
        codes = self.backend.codes
        ids, corners, rejected = found
        sample = image_sampler(image)
        out = []
        wanted = [k for k, i in enumerate(ids) if not ((expect_id is not None and i != expect_id) or i in skip_ids)]
        if wanted:  # OpenCV's finds, refined (and read again) all at once
            kept_ids = [ids[k] for k in wanted]
            c = np.array([corners[k] for k in wanted])
            b = to_bearing(c[..., 0], c[..., 1])
            if q.edge_refine and perspective:
                rq = refine_quads(sample, c, bits, q.view_refine_iterations)
                b = np.where(np.isnan(rq).any(axis=(1, 2))[:, None, None], b, to_bearing(rq[..., 0], rq[..., 1]))
            elif q.edge_refine:
                rb = refine_corners_many(grey, equirect, b, bits)
                b = np.where(np.isnan(rb).any(axis=(1, 2))[:, None, None], b, rb)
            if q.verify_decode and expect_id is None:
                # OpenCV's id must be what the cells say (else a misread or a texture)
                hits = decode_markers(grey, equirect, b, codes, *self._decode_thresholds())
                same = [k for k, (i, hit) in enumerate(zip(kept_ids, hits)) if hit is not None and hit[0] == i]
                kept_ids, b = [kept_ids[k] for k in same], b[same]
            if kept_ids:
                out += self.observations(equirect, kept_ids, b, method)
        if not rescue or (expect_id is not None and out):
            return out
        small = q.rescue_max_side_px * 4.0 * scale
        large = math.radians(q.close_range_size_deg) / equirect.rad_per_px * 4.0 * scale
        # a small quad is the black square, the outline of its white quiet zone or a looser one
        # (RESCUE_SHRINK): all refined and read at once in the image, then (equirect) again on
        # the sphere; a large one may be a close marker whose curved equirect image OpenCV
        # could not read: in a view read at once, in the equirect on the sphere only.
        rejected = np.array(rejected, dtype=float).reshape(-1, 4, 2)
        perimeters = np.sum(np.linalg.norm(rejected - np.roll(rejected, -1, axis=1), axis=2), axis=1)
        mid = rejected.mean(axis=1, keepdims=True)
        shrunk = mid[:, None] + np.asarray(RESCUE_SHRINK)[None, :, None, None] * (rejected - mid)[:, None]
        tries = shrunk[(perimeters <= small) | (perspective & (perimeters >= large))].reshape(-1, 4, 2)
        refined = refine_quads(sample, tries, bits)
        refined = refined[~np.isnan(refined).any(axis=(1, 2))]
        hits = [h for h in decode_quads(sample, refined, codes, *self._decode_thresholds())
                if h is not None and (expect_id is None or h[0] == expect_id)]
        if hits and perspective:
            out += self.observations(equirect, [h[0] for h in hits],
                                     np.array([to_bearing(h[1][:, 0], h[1][:, 1]) for h in hits]), method)
        elif hits:  # read in the equirect: straighten on the sphere, read again
            # the shrunk tries of one marker read as the same square: one (the next only if it fails)
            b = np.array([to_bearing(h[1][:, 0], h[1][:, 1]) for h in hits])
            out += self._refined_and_read(grey, equirect, b, [h[0] for h in hits], method, keys=_same_squares(hits))
        if not perspective:  # large quads in the equirect: curved edges, refined on the sphere only
            big = perimeters >= large
            if np.any(big):
                quads = shrunk[big].reshape(-1, 4, 2)
                b = to_bearing(quads[..., 0], quads[..., 1])
                # a quick loose reading first: most large quads are texture
                loose = [k for k, h in enumerate(decode_markers(grey, equirect, b, codes, *_LOOSE_DECODE))
                         if h is not None]
                got = self._refined_and_read(grey, equirect, b[loose], [expect_id] * len(loose), method,
                                             keys=[k // len(RESCUE_SHRINK) for k in loose])
                out += got
        return dedupe_observations(out)

    def _refined_and_read(self, grey: np.ndarray, equirect: Equirect, corners: np.ndarray,
                          expect: Sequence[Optional[int]], method: str,
                          keys: Optional[Sequence[int]] = None) -> List[MarkerObservation]:
        """Observations of candidate quads (corner bearings (M, 4, 3)) of the equirect whose
        corners refine on the sphere and whose cells then read as the ``expect`` id (None:
        any id). With ``keys`` (the shrunk tries of one rejected quad share a key), a key's
        tries are taken in order, the next one only when the previous failed."""
        keys = list(range(len(corners))) if keys is None else list(keys)
        ids, bearings = [], []
        todo = list(range(len(corners)))
        while todo:
            batch, seen = [], set()
            for k in todo:  # the first untried try of each key
                if keys[k] not in seen:
                    seen.add(keys[k])
                    batch.append(k)
            rb = refine_corners_many(grey, equirect, corners[batch], self.backend.bits)
            good = np.flatnonzero(~np.isnan(rb).any(axis=(1, 2)))
            hits = decode_markers(grey, equirect, rb[good], self.backend.codes, *self._decode_thresholds())
            done = set()
            for j, hit in zip(good, hits):
                k = batch[j]
                if hit is not None and (expect[k] is None or hit[0] == expect[k]):
                    done.add(keys[k])
                    ids.append(hit[0])
                    bearings.append(hit[1])
            todo = [k for k in todo if k not in batch and keys[k] not in done]
        return self.observations(equirect, ids, np.array(bearings), method) if ids else []

    def detect_in_view(self, grey: np.ndarray, equirect: Equirect, view: GnomonicView, method: str,
                       maps: Optional[Tuple[np.ndarray, np.ndarray]] = None, map_step: int = 1,
                       expect_id: Optional[int] = None) -> List[MarkerObservation]:
        """Markers in a gnomonic view of the equirect frame (corners refined in a view).

        ``maps``: precomputed :meth:`view_maps`, for reused views; else computed exactly
        (``map_step`` 1) or interpolated between every ``map_step`` view pixels (≤ 4: exact
        enough to refine corners in the view image itself).
        ``expect_id``: only this id is wanted (see :meth:`_finish`).
        """
        if maps is None:
            maps = view.remap_maps(equirect, map_step)
        img = cv2.remap(grey, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        scale = view.focal * equirect.rad_per_px  # view pixels per equirect pixel at its centre
        found = self.backend.detect(img, self.params.min_marker_perimeter_px * scale)
        return self._finish(grey, equirect, found, view.pixel_to_bearing, scale, method, img, map_step <= 4,
                            expect_id)

    def _decode_thresholds(self) -> Tuple[float, float, float, float]:
        q = self.params
        return (q.decode_min_contrast, q.decode_min_correlation, q.decode_min_lead, q.decode_min_pattern_correlation)

    def _decode(self, grey: np.ndarray, equirect: Equirect, corners: np.ndarray):
        return decode_marker(grey, equirect, corners, self.backend.codes, *self._decode_thresholds())

    def detect_in_views(self, grey: np.ndarray, equirect: Equirect, views: Sequence[GnomonicView],
                        maps: Sequence[Tuple[np.ndarray, np.ndarray]], expect_ids: Sequence[int],
                        method: str = "tracked", expect_sizes: Optional[Sequence[float]] = None
                        ) -> List[MarkerObservation]:
        """The expected marker in each of several small gnomonic views, in one OpenCV call.

        The views (with their :meth:`view_maps`, step ≤ 4) are rendered into one mosaic
        (stacked, separated by flat grey rows), OpenCV searches it once, every find is
        assigned to its view and kept only if it is that view's ``expect_ids`` entry; its
        corners are edge-refined in the view image. Views whose marker OpenCV did not read
        get their rejected quads within ``gate_deg`` of the view centre decoded
        (:func:`decode_quad`), as in :meth:`detect`; with ``expect_sizes`` (predicted
        angular sizes, radians) only quads within 35 % of that size are tried.
        """
        if not views:
            return []
        gap = 8
        imgs = [cv2.remap(grey, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP) for mx, my in maps]
        tops = np.cumsum([0] + [im.shape[0] + gap for im in imgs])
        mosaic = np.full((int(tops[-1]) - gap, max(im.shape[1] for im in imgs)), 128, np.uint8)
        for im, y0 in zip(imgs, tops):
            mosaic[y0:y0 + im.shape[0], :im.shape[1]] = im
        scale = min(v.focal for v in views) * equirect.rad_per_px
        ids, corners, rejected = self.backend.detect(mosaic, self.params.min_marker_perimeter_px * scale)
        sample = image_sampler(mosaic)
        bits, q = self.backend.bits, self.params
        found = set()

        def tile_of(c):
            k = int(np.searchsorted(tops, float(c[:, 1].mean()), side="right")) - 1
            inside = 0 <= k < len(views) and c[:, 1].max() < tops[k] + imgs[k].shape[0]
            return k if inside and c[:, 0].max() < imgs[k].shape[1] else -1

        def add(k, marker_id, quad):
            view, y0 = views[k], float(tops[k])
            bearings.append(view.pixel_to_bearing(quad[:, 0], quad[:, 1] - y0))
            marker_ids.append(marker_id)
            found.add(k)

        bearings, marker_ids = [], []

        keep = {}
        for i, c in zip(ids, corners):
            k = tile_of(c)
            if k >= 0 and i == expect_ids[k] and k not in keep:
                keep[k] = c

        def near_centre(c, k):  # the expected marker's centre is within the gate of the view's
            dx = c.mean(axis=0) - (views[k].cx, views[k].cy + tops[k])
            return float(np.hypot(*dx)) <= math.tan(math.radians(q.gate_deg)) * views[k].focal + 2.0

        def plausible(quad, k):
            if expect_sizes is None:
                return True
            side = float(np.mean(np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)))
            return abs(side / (expect_sizes[k] * views[k].focal) - 1.0) <= 0.35

        tries = [(k, quad) for c, k in ((c, tile_of(c)) for c in rejected)
                 if k >= 0 and k not in keep and near_centre(c, k)
                 for quad in (c.mean(axis=0) + shrink * (c - c.mean(axis=0)) for shrink in RESCUE_SHRINK)
                 if plausible(quad, k)]
        # OpenCV's finds and the rejected quads worth reading, refined in one batch; OpenCV's
        # corners in a view are close: short profiles do (12 × 12 per edge)
        batch = [(k, keep[k], True) for k in keep] + [(k, quad, False) for k, quad in tries]
        if not batch:
            return []
        quads = np.array([b[1] for b in batch])
        refined = (refine_quads(sample, quads, bits, q.view_refine_iterations, along=12, samples=12)
                   if q.edge_refine or tries else quads)
        for (k, c, read_by_opencv), r in zip(batch, refined):
            if read_by_opencv:
                add(k, expect_ids[k], c if (np.isnan(r).any() or not q.edge_refine) else r)
            elif k not in found and not np.isnan(r).any():
                hit = decode_quad(sample, r, self.backend.codes, *self._decode_thresholds())
                if hit is not None and hit[0] == expect_ids[k]:
                    add(k, hit[0], hit[1])
        return self.observations(equirect, marker_ids, np.array(bearings), method) if bearings else []

    def detect_columns(self, grey: np.ndarray, equirect: Equirect, u0: int, width: int,
                       method: str = "full", rescue: bool = True, max_el: float = math.pi / 2,
                       skip_ids: Sequence[int] = (), across: Optional[float] = None) -> List[MarkerObservation]:
        """Markers in the vertical strip of columns [u0, u0 + width) (wrapping around the seam),
        rows within ``max_el`` (radians) of the horizon; ``rescue``: also decode the quads
        OpenCV rejected (small, close markers); ``skip_ids``: ids not wanted; ``across``: only
        OpenCV's finds and rejected quads that reach across this column of the strip (with
        half their width to spare, for the refinement) are refined and read."""
        w = equirect.width
        u0 = int(u0) % w
        width = int(min(width, w))
        v0 = int(max(0, math.floor(equirect.azel_to_pixel(0.0, max_el)[1])))
        v1 = int(min(equirect.height, math.ceil(equirect.azel_to_pixel(0.0, -max_el)[1]) + 1))
        if u0 + width <= w:
            strip = grey[v0:v1, u0:u0 + width]
        else:
            strip = np.hstack([grey[v0:v1, u0:], grey[v0:v1, :u0 + width - w]])
        found = self.backend.detect(strip, self.params.min_marker_perimeter_px)
        if across is not None:
            ids, corners, rejected = found
            near = [_reaches(c, across) for c in corners]
            found = ([i for i, ok in zip(ids, near) if ok], [c for c, ok in zip(corners, near) if ok],
                     [c for c in rejected if _reaches(c, across)])
        return self._finish(grey, equirect, found, lambda x, y: equirect.pixel_to_bearing(x + u0, y + v0), 1.0,
                            method, strip, False, rescue=rescue, skip_ids=skip_ids)

    @staticmethod
    def view_maps(view: GnomonicView, equirect: Equirect, step: int = 1) -> Tuple[np.ndarray, np.ndarray]:
        """Remap maps equirect → ``view`` for :meth:`detect_in_view` (``GnomonicView.remap_maps``)."""
        return view.remap_maps(equirect, step)

    def view_around(self, equirect: Equirect, centre, fov: float, upsample: float = 1.0) -> GnomonicView:
        """A square gnomonic view of full field of view ``fov`` (radians) around a bearing, at
        ``upsample`` × the equirect resolution, capped at ``max_view_px`` pixels."""
        fov = min(max(fov, 1e-3), math.radians(150.0))
        native = 2.0 * math.tan(fov / 2.0) / equirect.rad_per_px
        size = int(min(max(math.ceil(native * upsample), self.params.roi_min_px), self.params.max_view_px))
        return GnomonicView.around(equirect, centre, fov, size=size)

    def _pool(self) -> Optional[ThreadPoolExecutor]:
        """Threads for :meth:`detect`'s seam and polar searches (one each) when OpenCV has
        threads (``cv2.setNumThreads``); None when it runs single-threaded."""
        n = min(2, cv2.getNumThreads())
        if n <= 1:
            return None
        if self._threads is None or self._threads[0] != n:
            if self._threads is not None:
                self._threads[1].shutdown(wait=False)
            self._threads = (n, ThreadPoolExecutor(max_workers=n, thread_name_prefix="aruco_detect"))
        return self._threads[1]

    def _pole_views(self, equirect: Equirect):
        key = (equirect.width, equirect.height)
        if key not in self._pole_maps:
            fov = 2.0 * math.radians(90.0 - self.params.pole_band_deg + 5.0)
            views = []
            for z in (1.0, -1.0):
                view = self.view_around(equirect, np.array([0.0, 0.0, z]), fov)
                map_x, map_y = view.remap_maps(equirect)
                # columns brought into [0, W) once: cv2.remap is ~2× slower on columns it must wrap
                views.append((view, (np.mod(map_x, np.float32(equirect.width)), map_y)))
            self._pole_maps = {key: views}
        return self._pole_maps[key]

    # ---------------------------------------------------------------- the full pipeline

    def detect(self, image: np.ndarray, what: str = "image") -> List[MarkerObservation]:
        """All markers of an equirect frame (grey or BGR uint8, 2:1): full frame, the strip
        around the ±180° seam, the two polar views; corners edge-refined in gnomonic views;
        one observation per physical marker, sorted by id. Raises DetectionError for an
        unusable image.
        """
        grey = to_grey(image, what)
        eq = Equirect(grey.shape[1], grey.shape[0])
        q = self.params
        # with the polar views, the equirect is searched up to pole_overlap_deg beyond their band
        max_el = math.radians(min(q.pole_band_deg + q.pole_overlap_deg, 90.0)) if q.pole_views else math.pi / 2
        half = int(math.ceil(math.radians(q.seam_strip_deg) / eq.rad_per_px))
        band = math.radians(q.pole_band_deg)
        extra = []  # searches independent of the full pass, run beside it (OpenCV releases the GIL)
        if half > 0:
            extra.append(lambda: [o for o in self.detect_columns(grey, eq, eq.width - half, 2 * half, "seam",
                                                                 max_el=max_el, across=half - 0.5)
                                  if _straddles_seam(o, eq)])
        if q.pole_views:  # one job: the two views share one OpenCV detector (their rate is the same)
            extra.append(lambda: [[o for o in self.detect_in_view(grey, eq, view, "gnomonic", maps)
                                   if abs(o.elevation) > band] for view, maps in self._pole_views(eq)])
        pool = self._pool()
        pending = [pool.submit(job) for job in extra] if pool is not None else []
        found = self.detect_columns(grey, eq, 0, eq.width, "full", max_el=max_el)
        results = [p.result() for p in pending] if pool is not None else [job() for job in extra]
        if half > 0:
            found = dedupe_observations(found + results.pop(0))
        for polar in (results[0] if results else []):
            found = dedupe_observations(found + polar)
        return sorted(found, key=lambda o: o.id)


def _same_squares(hits: Sequence[Tuple[int, np.ndarray]]) -> List[int]:
    """A key per decoded quad ``(id, corners (4, 2))``: the same key for quads of the same id
    whose centres are within a quarter of a side of each other (one marker read twice)."""
    keys: List[int] = []
    for k, (marker_id, q) in enumerate(hits):
        centre = q.mean(axis=0)
        side = float(np.mean(np.linalg.norm(q - np.roll(q, -1, axis=0), axis=1)))
        same = [keys[j] for j in range(k) if hits[j][0] == marker_id
                and float(np.hypot(*(hits[j][1].mean(axis=0) - centre))) < 0.25 * side]
        keys.append(same[0] if same else k)
    return keys


def _reaches(quad: np.ndarray, column: float) -> bool:
    """True when a quad's columns (4, 2), widened by half their span each way, contain ``column``."""
    lo, hi = float(quad[:, 0].min()), float(quad[:, 0].max())
    return lo - 0.5 * (hi - lo) <= column <= hi + 0.5 * (hi - lo)


def _straddles_seam(obs: MarkerObservation, equirect: Equirect) -> bool:
    """True when the marker's corners lie on both sides of the ±180° seam (column −0.5 ≡ W−0.5)."""
    u = obs.corners_px[:, 0]
    return bool(u.min() < -0.5 < u.max() or u.min() < equirect.width - 0.5 < u.max())


#: decode thresholds of a quick first reading of a large rejected quad from OpenCV's corners
_LOOSE_DECODE = (20.0, 0.5, 0.05, 0.6)
#: scales tried on a rejected quad: the black square itself, the outline of its white quiet
#: zone (6/8 for 4×4 codes), a looser outline (OpenCV's candidate merging keeps either)
RESCUE_SHRINK = (1.0, 0.75, 0.55)
_METHOD_RANK = {"gnomonic": 0, "tracked": 0, "full": 1, "seam": 1}


def dedupe_observations(observations: Sequence[MarkerObservation]) -> List[MarkerObservation]:
    """One observation per physical marker: same id and centres closer than the marker's
    size ⇒ the same marker; keep the gnomonic one, else the larger in pixels."""
    ranked = sorted(observations, key=lambda o: (_METHOD_RANK[o.method], -o.side_px))
    kept: List[MarkerObservation] = []
    for o in ranked:
        if not any(k.id == o.id and float(angle_between(k.centre, o.centre)) < max(k.angular_size, o.angular_size)
                   for k in kept):
            kept.append(o)
    return kept

"""Detection tunables and the detection error.

In: nothing (the values come from the caller, cfg/params.yaml or dynamic_reconfigure).
Out: :class:`DetectorParams` (validated on construction), read by every detection stage (the
tracker's own knobs are :class:`aruco_abs_orient.tracking.TrackingParams`); :class:`DetectionError` for
an image, JPEG, dictionary or parameter the detector cannot use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Tuple

from ..errors import InputFileError
from .quads import DecodeParams, EdgeFitParams

__all__ = ["DetectionError", "DetectorParams"]


class DetectionError(InputFileError):
    """An image, JPEG or dictionary the detector cannot use; the caller counts and skips."""


@dataclass
class DetectorParams:
    """Every knob of detection, flat (cfg/params.yaml's ``detection`` section; those worth changing live
    are also in cfg/AbsOrient.cfg, for dynamic_reconfigure). Tracking's own knobs are
    :class:`aruco_abs_orient.tracking.TrackingParams` (the ``tracking`` section).

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
      ``rescue_shrink``); this is what reaches 12 m (9–10 px markers at 3840 px).
    - ``rescue_shrink``: scales tried on a rejected quad: the black square itself, the outline of
      its white quiet zone (6/8 for 4×4 codes), a looser outline (OpenCV's candidate merging
      keeps either).
    - ``close_range_size_deg``: so are rejected quads with sides above this (degrees): close
      markers whose equirect image is too curved for OpenCV to read.
    - ``decode_min_contrast`` (grey levels), ``decode_min_correlation``, ``decode_min_lead``,
      ``decode_min_pattern_correlation``: acceptance thresholds of :func:`decode_marker`
      (:class:`~.quads.DecodeParams`).
    - ``loose_decode_min_contrast``, ``loose_decode_min_correlation``, ``loose_decode_min_lead``,
      ``loose_decode_min_pattern_correlation``: the same for a quick first reading of a large
      rejected quad from OpenCV's corners in the equirect (most are texture).
    - ``edge_min_contrast`` (grey levels), ``edge_min_half_px`` (pixels), ``edge_half_bits`` (bits),
      ``edge_samples``, ``edge_profiles``: how :func:`refine_quads` fits a marker's edges
      (:class:`~.quads.EdgeFitParams`: profile contrast, half width, steps across, profiles along).
    - ``view_edge_samples``, ``view_edge_profiles``: the same two for OpenCV's finds in tracking ROI
      views, whose corners are close: short profiles do.
    - ``view_size_tolerance``: in tracking ROI views, a rejected quad is read only if its side is
      within this fraction of the predicted marker size.

    Noise model (1-σ centre bearing, radians, see :func:`bearing_sigma`):

    - ``corner_sigma_px``: corner noise of a well-resolved marker (pixels).
    - ``small_marker_side_px``: side (pixels) below which corner noise grows ∝ 1/side².
    - ``tracked_sigma_scale``: factor for markers refined in tracking ROI views.
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
    rescue_shrink: Tuple[float, ...] = (1.0, 0.75, 0.55)
    decode_min_contrast: float = DecodeParams.min_contrast
    decode_min_correlation: float = DecodeParams.min_correlation
    decode_min_lead: float = DecodeParams.min_lead
    decode_min_pattern_correlation: float = DecodeParams.min_pattern_correlation
    loose_decode_min_contrast: float = 20.0
    loose_decode_min_correlation: float = 0.5
    loose_decode_min_lead: float = 0.05
    loose_decode_min_pattern_correlation: float = 0.6
    edge_min_contrast: float = EdgeFitParams.min_contrast
    edge_min_half_px: float = EdgeFitParams.min_half_px
    edge_half_bits: float = EdgeFitParams.half_bits
    edge_samples: int = EdgeFitParams.samples
    edge_profiles: int = EdgeFitParams.along
    view_edge_samples: int = 12
    view_edge_profiles: int = 12
    view_size_tolerance: float = 0.35

    corner_sigma_px: float = 0.03
    small_marker_side_px: float = 30.0
    tracked_sigma_scale: float = 2.0

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise DetectionError naming the first out-of-range field."""
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (bool, str)):
                continue
            if isinstance(v, tuple):
                if not v or not all(isinstance(x, (int, float)) and 0.0 < x <= 1.0 for x in v):
                    raise DetectionError(f"DetectorParams.{f.name}: expected a list of scales in (0, 1], got {v!r}")
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
        for name in ("edge_samples", "edge_profiles", "view_edge_samples", "view_edge_profiles"):
            if getattr(self, name) < 2:
                raise DetectionError(f"DetectorParams.{name}: expected ≥ 2, got {getattr(self, name)!r}")

    def decode(self) -> DecodeParams:
        """The acceptance thresholds of a reading (``decode_*``)."""
        return DecodeParams(self.decode_min_contrast, self.decode_min_correlation, self.decode_min_lead,
                            self.decode_min_pattern_correlation)

    def loose_decode(self) -> DecodeParams:
        """The thresholds of the quick first reading of a large rejected quad (``loose_decode_*``)."""
        return DecodeParams(self.loose_decode_min_contrast, self.loose_decode_min_correlation,
                            self.loose_decode_min_lead, self.loose_decode_min_pattern_correlation)

    def edge_fit(self, view: bool = False) -> EdgeFitParams:
        """The edge fit of :func:`refine_quads` (``edge_*``; ``view``: in a tracking ROI view, ``view_edge_*``)."""
        return EdgeFitParams(self.edge_min_contrast, self.edge_min_half_px, self.edge_half_bits,
                             self.view_edge_samples if view else self.edge_samples,
                             self.view_edge_profiles if view else self.edge_profiles)


_REFINE = {"none": "CORNER_REFINE_NONE", "subpix": "CORNER_REFINE_SUBPIX",
           "contour": "CORNER_REFINE_CONTOUR", "apriltag": "CORNER_REFINE_APRILTAG"}

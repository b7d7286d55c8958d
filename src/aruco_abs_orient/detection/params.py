"""Detection tunables and the detection error.

In: nothing (the values come from the caller, cfg/params.yaml or dynamic_reconfigure).
Out: :class:`DetectorParams` (each field declared with its meaning, unit and range; checked on construction),
read by every detection stage (the tracker's own knobs are :class:`aruco_abs_orient.tracking.TrackingParams`);
:class:`DetectionError` for an image, JPEG, dictionary or parameter the detector cannot use.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

from ..errors import InputFileError
from ..paramspec import Params, param
from .patternfit import PatternFitParams
from .quads import DecodeParams, EdgeFitParams

__all__ = ["DetectionError", "DetectorParams"]

#: corner refinement name → OpenCV's constant
_REFINE = {"none": "CORNER_REFINE_NONE", "subpix": "CORNER_REFINE_SUBPIX",
           "contour": "CORNER_REFINE_CONTOUR", "apriltag": "CORNER_REFINE_APRILTAG"}


class DetectionError(InputFileError):
    """An image, JPEG or dictionary the detector cannot use; the caller counts and skips."""


@dataclass
class DetectorParams(Params):
    """Every knob of detection, flat (cfg/params.yaml's ``detection`` section; those worth changing live are also
    in cfg/AbsOrient.cfg). In order: OpenCV's own (``cv2.aruco.DetectorParameters``), the 360° handling (the seam
    strip, the polar views), this module's steps after OpenCV's (edge refinement, decoding checks, the rescue of
    rejected quads) and the noise model of a centre bearing (:func:`bearing_sigma`). Tracking's knobs are
    :class:`aruco_abs_orient.tracking.TrackingParams`. OpenCV's default ``minMarkerPerimeterRate`` (0.03 of
    3840 px = 115 px) finds nothing beyond ~4 m (doc/design.md, platform facts): hence a perimeter in pixels."""

    error = DetectionError

    min_marker_perimeter_px: float = param(28.0, "smallest marker perimeter searched for (28 px = 7 px sides: a "
                                           "0.19 m marker at ~16 m on 3840 px); OpenCV's minMarkerPerimeterRate "
                                           "of each image searched", "px", 4.0, 400.0)
    max_marker_perimeter_rate: float = param(4.0, "largest perimeter as a fraction of the searched image's larger "
                                             "side (OpenCV's rate)", "", 0.0)
    adaptive_thresh_win_min: int = param(3, "smallest adaptive-threshold window (odd)", "px", 3)
    adaptive_thresh_win_max: int = param(23, "largest adaptive-threshold window (odd, ≥ the smallest)", "px", 3)
    adaptive_thresh_win_step: int = param(10, "step between adaptive-threshold windows", "px", 0)
    adaptive_thresh_constant: float = param(7.0, "constant subtracted in the adaptive threshold", "grey levels", 0.0)
    polygonal_approx_accuracy_rate: float = param(0.05, "polygon fit tolerance, a fraction of the perimeter", "", 0.0)
    min_corner_distance_rate: float = param(0.05, "smallest corner distance, a fraction of the perimeter", "", 0.0)
    min_distance_to_border: int = param(1, "smallest distance of a corner from the image border", "px", 0)
    min_marker_distance_rate: float = param(0.0, "candidates closer than this fraction of the perimeter are merged "
                                            "(0: the OpenCV version's own default, 0.125 since 4.10, 0.05 before)",
                                            "", 0.0)
    perspective_remove_pixel_per_cell: int = param(8, "pixels per bit cell of the unwarped code", "px", 0)
    perspective_remove_ignored_margin_per_cell: float = param(0.13, "margin of a cell left out when reading it, a "
                                                              "fraction of the cell", "", 0.0)
    max_erroneous_bits_in_border_rate: float = param(0.35, "border bits allowed wrong, a fraction (lower: fewer "
                                                     "false ids)", "", 0.0)
    error_correction_rate: float = param(0.6, "bit error correction, a fraction of the dictionary's capability "
                                         "(lower: fewer false ids)", "", 0.0)
    corner_refinement: str = param("subpix", "OpenCV's corner refinement", choices=tuple(_REFINE))
    corner_refine_win: int = param(3, "half window of OpenCV's corner refinement", "px", 0)
    corner_refine_max_iter: int = param(50, "iterations of OpenCV's corner refinement", "", 0)
    corner_refine_min_accuracy: float = param(0.01, "convergence of OpenCV's corner refinement", "px", 0.0)

    close_range_size_deg: float = param(8.0, "rejected quads with sides above this are rescued too: close markers "
                                        "whose equirect image is too curved for OpenCV", "deg", 0.0)
    seam_strip_deg: float = param(25.0, "half width of the strip re-searched around the ±180° seam (a marker on "
                                  "the seam must fit in it: 0.19 m at ≥ 0.45 m)", "deg", 0.0)
    pole_views: bool = param(True, "search two gnomonic views (zenith, nadir) for markers in the polar bands, where "
                             "equirect shapes are too distorted")
    pole_band_deg: float = param(55.0, "elevation beyond which the polar views search", "deg", above=0.0,
                                 below=90.0)
    pole_overlap_deg: float = param(20.0, "with pole_views, the whole frame and the seam strip are searched up to "
                                    "pole_band_deg + this from the horizon (a marker centred on the band's edge at "
                                    "0.45 m)", "deg", 0.0)
    max_view_px: int = param(1024, "cap on a view's side; larger views lower their resolution", "px", 0)

    edge_refine: bool = param(True, "refine every marker's corners by fitting lines to its edges in a gnomonic view "
                              "(OpenCV's subpixel corners are 0.2–0.6 px off on blurred small markers)")
    view_refine_iterations: int = param(2, "edge-fit iterations for markers found in a gnomonic view (tracking "
                                        "ROIs, polar views)", "", 0)
    pattern_fit: bool = param(False, "fit the corners of small markers with their whole known pattern, blurred, "
                              "after the edge fit, whose edges the cells next to them pull (a bias of up to 0.2 px, "
                              "the same on every frame, where cells are under 3 px wide); off in the live pipeline "
                              "(it costs about a fifth more CPU and does not change the heading measurably), on in "
                              "the map's detections (mapping.pattern_fit)")
    pattern_fit_max_cell_px: float = param(6.0, "markers whose cells are at most this wide are fitted with their "
                                           "pattern (the edge fit's bias is under 0.02 px above 3.5 px, except "
                                           "along the long edges of a marker seen obliquely)", "px", 0.0)
    pattern_fit_iterations: int = param(PatternFitParams.iterations, "Levenberg-Marquardt steps of the pattern "
                                        "fit", "", 1)
    verify_decode: bool = param(True, "re-read every marker OpenCV decoded and drop it unless its cells give the "
                                "same id (OpenCV misreads small markers on texture)")
    rescue_max_side_px: float = param(30.0, "quads OpenCV rejected with sides up to this are refined and read "
                                      "(what reaches 12 m: 9–10 px markers at 3840 px)", "px", 0.0)
    rescue_shrink: Tuple[float, ...] = param((1.0, 0.75, 0.55), "scales tried on a rejected quad: the black "
                                             "square, the outline of its quiet zone (6/8 for 4×4 codes), a looser "
                                             "outline", "", above=0.0, high=1.0)
    rescue_min_contrast: float = param(10.0, "a small rejected quad is refined and read only when, at one of its "
                                       "rescue_shrink scales, its quiet zone is on average this much brighter than "
                                       "its border at OpenCV's corners (texture: about 0; markers read: 22 and more)",
                                       "grey levels", 0.0)
    decode_min_contrast: float = param(DecodeParams.min_contrast, "every quiet-zone cell must be this much brighter "
                                       "than every border cell (decode_marker)", "grey levels", 0.0)
    decode_min_correlation: float = param(DecodeParams.min_correlation, "correlation of the inner cells with the "
                                          "best code and order", "", 0.0)
    decode_min_lead: float = param(DecodeParams.min_lead, "lead of that correlation over every other code and "
                                   "order", "", 0.0)
    decode_min_pattern_correlation: float = param(DecodeParams.min_pattern_correlation, "correlation of the whole "
                                                  "pattern (quiet zone, border, bits)", "", 0.0)
    loose_decode_min_contrast: float = param(20.0, "decode_min_contrast of the quick first reading of a large "
                                             "rejected quad (most are texture)", "grey levels", 0.0)
    loose_decode_min_correlation: float = param(0.5, "decode_min_correlation of that first reading", "", 0.0)
    loose_decode_min_lead: float = param(0.05, "decode_min_lead of that first reading", "", 0.0)
    loose_decode_min_pattern_correlation: float = param(0.6, "decode_min_pattern_correlation of that first reading",
                                                        "", 0.0)
    edge_min_contrast: float = param(EdgeFitParams.min_contrast, "a profile across a marker's edge must rise by "
                                     "this to count (refine_quads)", "grey levels", 0.0)
    edge_min_half_px: float = param(EdgeFitParams.min_half_px, "a profile spans at least this either side of the "
                                    "edge", "px", 0.0)
    edge_half_bits: float = param(EdgeFitParams.half_bits, "a profile spans at least this either side of the edge",
                                  "bits", 0.0)
    edge_samples: int = param(EdgeFitParams.samples, "steps across the edge per profile", "", 2)
    edge_profiles: int = param(EdgeFitParams.along, "profiles along each edge", "", 2)
    view_edge_samples: int = param(12, "edge_samples in tracking ROI views (close corners: short profiles do)", "",
                                   2)
    view_edge_profiles: int = param(12, "edge_profiles in tracking ROI views", "", 2)
    view_size_tolerance: float = param(0.35, "in tracking ROI views a rejected quad is read only if its side is "
                                       "within this fraction of the predicted marker size", "", 0.0)

    corner_sigma_px: float = param(0.03, "corner noise of a well-resolved marker", "px", 0.0, 5.0)
    small_marker_side_px: float = param(30.0, "side below which corner noise grows ∝ 1/side²", "px", 0.0)
    tracked_sigma_scale: float = param(2.0, "factor on the noise of markers refined in tracking ROI views", "", 0.0)
    pattern_fit_sigma_px: float = param(0.03, "centre noise of a marker 10 px wide fitted with its pattern, ∝ 1/side",
                                        "px", 0.0, 5.0)

    def check_together(self) -> None:
        if self.adaptive_thresh_win_max < self.adaptive_thresh_win_min:
            raise DetectionError("DetectorParams.adaptive_thresh_win_min/max: need 3 ≤ min ≤ max, got "
                                 f"{self.adaptive_thresh_win_min}, {self.adaptive_thresh_win_max}")

    def decode(self) -> DecodeParams:
        """The acceptance thresholds of a reading (``decode_*``)."""
        return DecodeParams(self.decode_min_contrast, self.decode_min_correlation, self.decode_min_lead,
                            self.decode_min_pattern_correlation)

    def loose_decode(self) -> DecodeParams:
        """The thresholds of the quick first reading of a large rejected quad (``loose_decode_*``)."""
        return DecodeParams(self.loose_decode_min_contrast, self.loose_decode_min_correlation,
                            self.loose_decode_min_lead, self.loose_decode_min_pattern_correlation)

    def pattern_fit_params(self) -> PatternFitParams:
        """The pattern fit of :func:`.patternfit.fit_patterns` (``pattern_fit_*``)."""
        return PatternFitParams(iterations=self.pattern_fit_iterations)

    def edge_fit(self, view: bool = False) -> EdgeFitParams:
        """The edge fit of :func:`refine_quads` (``edge_*``; ``view``: in a tracking ROI view, ``view_edge_*``)."""
        return EdgeFitParams(self.edge_min_contrast, self.edge_min_half_px, self.edge_half_bits,
                             self.view_edge_samples if view else self.edge_samples,
                             self.view_edge_profiles if view else self.edge_profiles)


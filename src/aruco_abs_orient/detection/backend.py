"""The OpenCV back-end adapter: cv2.aruco behind one call, for both of its APIs.

In: a grey image, the smallest marker perimeter searched (pixels), the OpenCV fields of
:class:`~.params.DetectorParams`. Out: OpenCV's decoded markers (ids, (4, 2) corner pixels)
and the quads it rejected; the dictionary's codes (:attr:`ArucoBackend.codes`) for
:mod:`.quads`. ``cv2.aruco.ArucoDetector`` (OpenCV ≥ 4.7) or the function API
(``detectMarkers``/``DetectorParameters_create``) of OpenCV 4.2–4.6.
"""

from __future__ import annotations

from typing import Dict, List, Optional, Tuple

import cv2
import numpy as np

from ..markers import ARUCO_DICTIONARIES
from .params import _REFINE, DetectionError, DetectorParams

__all__ = ["ArucoBackend"]


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

"""What one marker sighting is: the record every detection stage produces, its noise model,
and the merge of sightings of one marker found by several searches.

In: corner bearings (from :mod:`.detector` or :mod:`aruco_abs_orient.tracking`), the noise
fields of :class:`~.params.DetectorParams`. Out: :class:`MarkerObservation` records,
:func:`bearing_sigma` (1-σ centre bearing), :func:`dedupe_observations` (one per marker).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Sequence, Tuple

import numpy as np

from ..camera import angle_between, bearing_to_azel
from .params import DetectorParams

__all__ = ["MarkerObservation", "bearing_sigma", "dedupe_observations"]


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


def bearing_sigma(params: DetectorParams, pitch: float, side_px: float, method: str = "full",
                  fitted: bool = False) -> float:
    """1-σ centre bearing noise (radians, per axis) of a marker with ``side_px`` pixel sides
    in an image of angular pixel pitch ``pitch`` (radians/pixel), found by ``method``.

    Corner noise ``corner_sigma_px`` for a well-resolved marker, growing ∝ 1/side² below
    ``small_marker_side_px`` (1–2 px cells: the edge fit loses its straight run); the
    centre averages four corners (÷2); ``tracked_sigma_scale`` × for markers refined in a
    resampled ROI view. A marker ``fitted`` with its whole pattern (``pattern_fit``, sampled
    straight from the equirect): ``pattern_fit_sigma_px`` at 10 px sides, ∝ 1/side (every
    pixel of its edges counts). Calibrated on rendered 'realistic' frames (bench/detection.py:
    median |error| ≈ 1.18 σ at every range).
    """
    if fitted:
        return float(pitch * params.pattern_fit_sigma_px * 10.0 / max(side_px, 1e-6))
    grow = max(1.0, (params.small_marker_side_px / max(side_px, 1e-6)) ** 2)
    scale = params.tracked_sigma_scale if method == "tracked" else 1.0
    return float(pitch * params.corner_sigma_px * grow * scale / 2.0)


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

"""ArUco markers in 360° equirectangular frames (doc/design.md §5).

In: an equirect frame (grey or colour, or JPEG bytes) and :class:`DetectorParams`. Out: one
:class:`MarkerObservation` per marker: its id, the four corners refined on straight edges in a gnomonic view,
the centre's bearing as the intersection of the diagonals on the sphere (not in pixels, which is biased toward
the horizon), and the bearing's σ. The whole frame, the ±180° seam and the polar bands are searched
(:meth:`MarkerDetector.detect`); map-guided tracking is :mod:`aruco_abs_orient.tracking`. Every pixel↔bearing
conversion goes through :mod:`aruco_abs_orient.camera`. OpenCV 4.2–4.6 (function API) and ≥ 4.7
(``ArucoDetector``); Python 3.8; radians inside (``*_deg`` parameters in degrees).

One module per stage: :mod:`.params` (the knobs, :class:`DetectionError`), :mod:`.images` (frames in),
:mod:`.backend` (the OpenCV adapter), :mod:`.quads` (corner refinement and cell reading), :mod:`.sphere` (centre
geometry, quads in virtual views), :mod:`.observation` (:class:`MarkerObservation`, its noise model), and
:mod:`.detector` (:class:`MarkerDetector`, which chains them).
"""

from .backend import ArucoBackend
from .detector import MarkerDetector, Wanted
from .images import decode_jpeg, frame_to_grey, to_grey
from .observation import MarkerObservation, bearing_sigma, dedupe_observations
from .params import DetectionError, DetectorParams
from .quads import decode_quads, image_sampler, refine_quads
from .sphere import (
    decode_marker,
    decode_markers,
    marker_angular_size,
    pixel_centre_bearing,
    refine_corners,
    refine_corners_many,
    sphere_centre_bearing,
)

__all__ = [
    "DetectionError",
    "DetectorParams",
    "MarkerObservation",
    "ArucoBackend",
    "MarkerDetector",
    "Wanted",
    "decode_jpeg",
    "frame_to_grey",
    "to_grey",
    "sphere_centre_bearing",
    "pixel_centre_bearing",
    "marker_angular_size",
    "bearing_sigma",
    "refine_corners",
    "refine_corners_many",
    "decode_marker",
    "decode_markers",
    "refine_quads",
    "decode_quads",
    "dedupe_observations",
    "image_sampler",
]

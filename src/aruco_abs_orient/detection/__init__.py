"""ArUco markers in 360° equirectangular frames (doc/design.md §5).

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

Map-guided tracking (doc/design.md §6) lives in :mod:`aruco_abs_orient.tracking`.

All pixel↔bearing conversions go through :mod:`aruco_abs_orient.camera`. Angles are in
radians inside the code; the few parameters in degrees say so in their names (``*_deg``).
Works with both OpenCV ArUco APIs: ``cv2.aruco.ArucoDetector`` (OpenCV ≥ 4.7) and the
function API (``detectMarkers``/``DetectorParameters_create``) of OpenCV 4.2–4.6.
Python 3.8 compatible; numpy and OpenCV only.

The package, one module per stage (each says what goes in and what comes out):

- :mod:`.params`: :class:`DetectorParams` (every detection knob) and :class:`DetectionError`;
- :mod:`.images`: frames in (:func:`to_grey`, :func:`decode_jpeg`, :func:`frame_to_grey`);
- :mod:`.backend`: the OpenCV adapter (:class:`ArucoBackend`);
- :mod:`.quads`: corner refinement and cell reading of quads in a perspective image;
- :mod:`.sphere`: centre geometry on the sphere, and the quad stages run in virtual views;
- :mod:`.observation`: :class:`MarkerObservation`, its noise model, de-duplication;
- :mod:`.detector`: :class:`MarkerDetector`, which chains them.
"""

from .backend import ArucoBackend
from .detector import MarkerDetector, Wanted
from .images import decode_jpeg, frame_to_grey, to_grey
from .observation import MarkerObservation, bearing_sigma, dedupe_observations
from .params import DetectionError, DetectorParams
from .quads import decode_quad, decode_quads, image_sampler, refine_quad, refine_quads
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
    "refine_quad",
    "refine_quads",
    "decode_quad",
    "decode_quads",
    "dedupe_observations",
    "image_sampler",
]

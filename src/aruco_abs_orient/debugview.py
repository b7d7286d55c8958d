"""The node's debug image: a 360° frame with what the pipeline made of it drawn on it (no ROS).

:func:`debug_frame` downscales the equirect frame to at most ``max_width`` px and draws, in the colours of
:data:`COLOURS`:
- each detected marker's outline (its corner bearings) with its id, green when accepted, red when rejected
  with the reason;
- the predicted position of every marker of the map (from the frame's corrected pose), a yellow circle
  with the id;
- the ±180° seam (the image's left and right edges, where detection rolls the frame) and the horizon of
  ``map`` (the great circle level in map, a curve when the camera is tilted; the image's middle row
  without a pose).

:func:`expected_markers` says, for a frame with a known camera pose, where each of the map's markers should be
and, for each one not found or not used, why (facing away, seen edge-on, too small to find, off where the map
puts it, rejected by the pipeline, missed by its tracker, or hidden): the report's overview draws it.

All pixel positions come from bearings through :class:`aruco_abs_orient.camera.Equirect` (the only
pixel↔bearing code), at the output size, so nothing here depends on the input's resolution. Colours are
BGR. Unit-tested on a rendered frame (``test/unit/test_debugview.py``).
"""

from __future__ import annotations

import math
from typing import Iterable, List, Mapping, NamedTuple, Optional, Tuple

import cv2
import numpy as np

from .camera import Equirect, angle_between
from .errors import InputFileError
from .markers import MarkerMap

__all__ = ["DebugImageError", "COLOURS", "debug_frame", "encode_debug_jpeg", "predicted_bearings", "horizon_bearings",
           "ExpectedMarker", "expected_markers"]

COLOURS = {"accepted": (0, 200, 0), "rejected": (0, 0, 255), "predicted": (0, 220, 255),
           "seam": (255, 0, 255), "horizon": (255, 160, 0)}
"""BGR colour of each kind of drawing."""


class DebugImageError(InputFileError):
    """A frame that cannot be drawn or encoded as a debug image (its shape, the width asked for)."""


def predicted_bearings(marker_map: MarkerMap, map_T_camera: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(ids (n,), unit bearings (n, 3) in the camera frame) of the map's markers seen from ``map_T_camera``
    (4×4, m)."""
    T = np.asarray(map_T_camera, dtype=float)
    ids = np.array([m.id for m in marker_map], dtype=int)
    if not len(ids):
        return ids, np.zeros((0, 3))
    d = (np.array([m.position for m in marker_map], dtype=float) - T[:3, 3]) @ T[:3, :3]
    return ids, d / np.linalg.norm(d, axis=1, keepdims=True)


class ExpectedMarker(NamedTuple):
    """A map marker in a frame: ``id``; ``u``, ``v`` (px of the frame) where the map puts it; ``range`` (m);
    ``side_px`` (its side there if it faced the camera, px); ``status``: "found" (found and used), or why not."""

    id: int
    u: float
    v: float
    range: float
    side_px: float
    status: str


def expected_markers(marker_map: MarkerMap, map_T_camera: np.ndarray, width: int, found: Mapping[int, np.ndarray],
                     used: Mapping[int, str], min_side_px: float = 6.0, gate: float = math.radians(1.0),
                     edge_on: float = math.radians(75.0)) -> List[ExpectedMarker]:
    """Each marker of ``marker_map`` in a ``width`` px wide frame taken from ``map_T_camera`` (4×4, m), nearest
    first, and what became of it. ``found``: id → centre bearing (camera frame) of the markers a search of the
    whole frame found; ``used``: id → the pipeline's outcome for it in that frame ('' accepted, else its reason;
    ids it did not see are absent). A status other than "found" says why: "faces away" / "seen edge-on (80°)"
    (a surveyed face normal), "found, rejected: <reason>", "found here, missed by the tracker (outside its
    window)", "found 1.4° off the map's position" (beyond ``gate`` rad, with the pipeline's reason), "too small
    to find (4 px)" (below ``min_side_px``), or "not found: hidden or blurred"."""
    cam = Equirect(int(width), int(width) // 2)
    ids, bearings = predicted_bearings(marker_map, map_T_camera)
    centre = np.asarray(map_T_camera, dtype=float)[:3, 3]
    out = []
    for mid, b in zip(ids, bearings):
        m = marker_map[int(mid)]
        rng = float(np.linalg.norm(m.position - centre))
        side = 2.0 * math.atan(m.size / (2.0 * max(rng, 1e-6))) / cam.rad_per_px
        u, v = cam.bearing_to_pixel(b)
        tilt = (math.acos(min(1.0, abs(float(np.dot(m.normal, centre - m.position))) / max(rng, 1e-9)))
                if m.normal is not None else 0.0)
        if m.normal is not None and not m.visible_from(centre):
            status = "faces away"
        elif int(mid) in found:
            off = float(angle_between(found[int(mid)], b))
            reason = used.get(int(mid))
            why = reason.split(" (")[0] if reason else ""
            why = why.split(": ")[0] if len(why) > 32 and ": " in why else why
            status = ("found" if reason == "" else "found here, missed by the tracker (outside its window)"
                      if reason is None else f"found, rejected: {why}")
            if off > gate:
                status = f"found {math.degrees(off):.1f}° off the map's position" + (
                    f", rejected: {why}" if why else "")
        elif tilt > edge_on:
            status = f"seen edge-on ({math.degrees(tilt):.0f}°)"
        elif side < min_side_px:
            status = f"too small to find ({side:.0f} px)"
        else:
            status = "not found: hidden or blurred"
        out.append(ExpectedMarker(int(mid), float(u), float(v), rng, float(side), status))
    return sorted(out, key=lambda e: e.range)


def horizon_bearings(map_R_camera: Optional[np.ndarray], n: int = 721) -> np.ndarray:
    """(n, 3) unit bearings in the camera frame of the horizon of ``map`` (level in map), ordered around the
    circle; with ``map_R_camera`` None (no pose yet) the camera's own horizon (elevation 0)."""
    up = np.array([0.0, 0.0, 1.0]) if map_R_camera is None else np.asarray(map_R_camera, dtype=float)[2, :]
    up = up / np.linalg.norm(up)
    e1 = np.cross(up, [0.0, 1.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:  # camera looking straight up or down: any other axis
        e1 = np.cross(up, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    theta = np.linspace(0.0, 2.0 * math.pi, n)
    return np.outer(np.cos(theta), e1) + np.outer(np.sin(theta), e2)


def _polyline(img: np.ndarray, cam: Equirect, bearings: np.ndarray, colour, thickness: int,
              closed: bool) -> None:
    """Draw the path through ``bearings``: made continuous across the seam (each column unwrapped next to
    the previous one), then drawn shifted by −W, 0 and +W (OpenCV clips what falls outside)."""
    u, v = cam.bearing_to_pixel(bearings)
    if closed:
        u, v = np.append(u, u[:1]), np.append(v, v[:1])
    u = np.asarray(u, dtype=float)
    steps = np.asarray(cam.unwrap_u(u[1:], u[:-1]), dtype=float) - u[:-1]   # each within W/2
    u = np.concatenate([u[:1], u[0] + np.cumsum(steps)])
    w = cam.width
    for shift in (-w, 0, w):
        if np.max(u) + shift < 0 or np.min(u) + shift > w - 1:
            continue
        pts = np.round(np.stack([u + shift, v], axis=1)).astype(np.int32)
        cv2.polylines(img, [pts], False, colour, thickness, cv2.LINE_8)  # anti-aliased: 5x slower


def _label(img: np.ndarray, text: str, at: Tuple[float, float], colour, scale: float) -> None:
    x = int(min(max(at[0], 0), img.shape[1] - 10))
    y = int(min(max(at[1], 12), img.shape[0] - 4))
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def debug_frame(image: np.ndarray, observations: Iterable, marker_map: Optional[MarkerMap] = None,
                map_T_camera: Optional[np.ndarray] = None, max_width: int = 1920) -> np.ndarray:
    """The annotated frame: BGR uint8, ``min(W, max_width)`` wide (2:1).

    ``image``: the equirect frame, grey (H, W) or BGR (H, W, 3), any 2:1 size; ``observations``: the
    frame's ``pipeline.ObservationResult`` (``.observation`` with ``.corners``/``.centre`` bearings and
    ``.id``, ``.accepted``, ``.reason``); ``marker_map`` and ``map_T_camera`` (4×4, m; None before
    initialisation) for the predicted positions and the horizon.
    """
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.shape[1] != 2 * img.shape[0]:
        raise DebugImageError(f"debug image: expected a 2:1 equirect frame, got shape {img.shape}")
    if max_width < 2:
        raise DebugImageError(f"debug image: max_width must be at least 2 px, got {max_width}")
    width = min(img.shape[1], int(max_width) // 2 * 2)
    if width != img.shape[1]:
        img = cv2.resize(img, (width, width // 2), interpolation=cv2.INTER_AREA)
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    cam = Equirect(width, width // 2)
    scale = max(0.4, width / 3840.0)
    thick = max(1, int(round(width / 960)))
    # seam and horizon first: the markers are drawn over them
    for u in (0, width - 1):
        for v0 in range(0, width // 2, 16):
            cv2.line(out, (u, v0), (u, v0 + 8), COLOURS["seam"], thick)
    _label(out, "seam +-180 deg", (4, 16), COLOURS["seam"], scale)
    R = None if map_T_camera is None else np.asarray(map_T_camera, dtype=float)[:3, :3]
    _polyline(out, cam, horizon_bearings(R), COLOURS["horizon"], thick, closed=False)
    if marker_map is not None and map_T_camera is not None:
        ids, bearings = predicted_bearings(marker_map, map_T_camera)
        u, v = cam.bearing_to_pixel(bearings)
        for i, x, y in zip(ids, u, v):
            cv2.circle(out, (int(round(x)), int(round(y))), 6 * thick, COLOURS["predicted"], thick, cv2.LINE_AA)
            _label(out, str(i), (x + 7 * thick, y + 14 * thick), COLOURS["predicted"], scale)
    for r in observations:
        o = r.observation
        colour = COLOURS["accepted"] if r.accepted else COLOURS["rejected"]
        _polyline(out, cam, np.asarray(o.corners, dtype=float), colour, thick + 1, closed=True)
        u, v = cam.bearing_to_pixel(np.asarray(o.corners, dtype=float))
        text = f"id {o.id}" if r.accepted else f"id {o.id}: {r.reason or 'rejected'}"
        _label(out, text, (float(np.min(u)), float(np.min(v)) - 6), colour, scale)
    return out


def encode_debug_jpeg(frame: np.ndarray, quality: int = 80) -> bytes:
    """JPEG bytes of a debug frame (for ``sensor_msgs/CompressedImage``)."""
    ok, buf = cv2.imencode(".jpg", frame, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    if not ok:
        raise DebugImageError(f"debug image: JPEG encoding failed for shape {frame.shape}")
    return buf.tobytes()

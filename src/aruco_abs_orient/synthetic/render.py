"""Rendering of equirectangular 360° frames with ArUco markers (the synthetic world's camera).

Inverse mapping with supersampling: for every (sub)pixel in a marker's bounding pixel box the
ray of ``camera.Equirect.pixel_to_bearing`` (the package's one pixel↔bearing convention) is
intersected with the marker plane, the ArUco bit under the hit point is looked up and the
sub-samples are averaged. A two-lens camera (``camera.DualFisheye``) casts each pixel's ray from
its lens's centre along its lens's direction, both lenses' in the blend band, weighted. The rest of
the frame is a precomputed background panorama (textured or flat grey) rolled by the camera's yaw.
Then optional Gaussian blur, sensor noise and a JPEG round trip, as set by a :class:`RenderProfile`.

Units: metres for positions and sizes, radians for angles, pixels for blur, grey levels (DN,
0–255) for noise. Frames: the camera frame of doc/design.md §1 (x = image centre column, y left, z up).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from ..camera import SINGLE_CENTRE, DualFisheye, Equirect, bearing_to_azel
from ..errors import ConfigurationError
from ..markers import ARUCO_DICTIONARIES
from ..transforms import rot_x, rot_z

__all__ = [
    "RenderError",
    "PlacedMarker",
    "facing_marker",
    "RenderProfile",
    "PROFILES",
    "render_equirect",
    "finish_frame",
    "encode_jpeg",
    "decode_jpeg",
    "QUIET_ZONE_BITS",
]

# White margin around the black square, in bit widths (keeps markers detectable on texture).
QUIET_ZONE_BITS = 1


class RenderError(ConfigurationError):
    """Invalid rendering input: image width, profile name, marker geometry, dictionary, id."""


@dataclass(frozen=True, eq=False)
class PlacedMarker:
    """A marker placed in the camera frame.

    ``id``: ArUco id; ``size``: side of the black square in metres; ``center`` (3,): marker centre
    in the camera frame (x fwd, y left, z up) in metres; ``camera_R_marker`` (3, 3): rotation from
    the marker frame (x right, y up on the printed face, z out of the face towards the viewer) to
    the camera frame.
    """

    id: int
    size: float
    center: np.ndarray
    camera_R_marker: np.ndarray

    def corners(self) -> np.ndarray:
        """Camera-frame corners (4, 3) in metres of the black square, OpenCV ArUco order as seen
        from the front: top-left, top-right, bottom-right, bottom-left."""
        return self.points_on_face(_CORNER_SIGNS * (self.size / 2.0))

    def points_on_face(self, xy) -> np.ndarray:
        """Camera-frame points (..., 3) in metres of marker-face coordinates ``xy`` (..., 2) in metres."""
        xy = np.asarray(xy, dtype=float)
        R = np.asarray(self.camera_R_marker, dtype=float)
        return np.asarray(self.center, dtype=float) + xy[..., :1] * R[:, 0] + xy[..., 1:2] * R[:, 1]

    @property
    def normal(self) -> np.ndarray:
        """Unit normal (3,) of the printed face in the camera frame (marker +z)."""
        return np.asarray(self.camera_R_marker, dtype=float)[:, 2].copy()


_CORNER_SIGNS = np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])


def facing_marker(id: int, size: float, center, roll: float = 0.0, tilt: float = 0.0) -> PlacedMarker:
    """A marker at ``center`` (3,) m (camera frame) whose face is turned towards the camera origin.

    Upright: the marker's y axis is as close to camera +z as possible (for a marker straight above
    or below the camera, its y axis points towards camera +x / −x). Then rotated by ``roll``
    (radians) about its normal and tilted by ``tilt`` (radians) about its (rolled) x axis:
    ``camera_R_marker = R_facing · Rz(roll) · Rx(tilt)``.
    """
    c = np.asarray(center, dtype=float).reshape(3)
    dist = float(np.linalg.norm(c))
    if not (math.isfinite(dist) and dist > 0):
        raise RenderError(f"marker {id}: centre must be a finite non-zero point, got {center!r}")
    if not (size > 0 and math.isfinite(size)):
        raise RenderError(f"marker {id}: size must be a positive number of metres, got {size!r}")
    z = -c / dist
    y = np.array([0.0, 0.0, 1.0]) - z[2] * z
    if np.linalg.norm(y) < 1e-9:  # straight above/below: "up" is away from the camera's forward
        y = np.array([math.copysign(1.0, c[2]), 0.0, 0.0]) - z[0] * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1) @ rot_z(roll) @ rot_x(tilt)
    return PlacedMarker(int(id), float(size), c, R)


@dataclass(frozen=True)
class RenderProfile:
    """How a frame is degraded: ``supersample`` sub-samples per pixel side (≥ 1),
    ``blur_sigma_px`` Gaussian blur σ in pixels (0 = none; optics and the camera's processing),
    ``noise_sigma`` Gaussian sensor noise σ in grey levels added before the blur (0 = none),
    ``jpeg_quality`` 1–100 or None (no JPEG round trip), ``background`` 'textured' or 'grey'."""

    supersample: int
    blur_sigma_px: float
    noise_sigma: float
    jpeg_quality: Optional[int]
    background: str


PROFILES: Dict[str, RenderProfile] = {
    "clean": RenderProfile(supersample=8, blur_sigma_px=0.0, noise_sigma=0.0, jpeg_quality=None,
                           background="grey"),
    "realistic": RenderProfile(supersample=8, blur_sigma_px=0.7, noise_sigma=2.0, jpeg_quality=85,
                               background="textured"),
    # the realistic world's (synthetic/world.py): 5×5 sub-samples (25 grey levels of coverage, below its
    # noise and JPEG) keep a 60 s 3840 px demo, rolling shutter included, within 3 minutes on 2 cores
    "hall": RenderProfile(supersample=5, blur_sigma_px=0.7, noise_sigma=2.0, jpeg_quality=85, background="textured"),
}

_GREY_LEVEL = 128
_WHITE = 255.0
_BLACK = 0.0


def _resolve_profile(profile: Union[str, RenderProfile]) -> RenderProfile:
    if isinstance(profile, RenderProfile):
        p = profile
    else:
        try:
            p = PROFILES[profile]
        except KeyError:
            raise RenderError(f"unknown render profile {profile!r}; expected one of {', '.join(PROFILES)}") from None
    if int(p.supersample) != p.supersample or p.supersample < 1:
        raise RenderError(f"render profile: supersample must be an integer >= 1, got {p.supersample!r}")
    if p.background not in ("textured", "grey"):
        raise RenderError(f"render profile: background must be 'textured' or 'grey', got {p.background!r}")
    if p.jpeg_quality is not None and not 1 <= p.jpeg_quality <= 100:
        raise RenderError(f"render profile: jpeg_quality must be 1..100 or None, got {p.jpeg_quality!r}")
    if p.blur_sigma_px < 0 or p.noise_sigma < 0:
        raise RenderError("render profile: blur_sigma_px and noise_sigma must be >= 0")
    return p


def _marker_image(dictionary, marker_id: int, side_px: int) -> np.ndarray:
    """cv2.aruco's image (side_px, side_px) uint8 of a marker with a one-bit border:
    ``generateImageMarker`` (OpenCV ≥ 4.7) or ``drawMarker`` (Noetic's 4.2), same arguments."""
    draw = getattr(cv2.aruco, "generateImageMarker", None) or cv2.aruco.drawMarker
    return draw(dictionary, marker_id, side_px, borderBits=1)


@functools.lru_cache(maxsize=64)
def _marker_bits(dictionary: str, marker_id: int) -> np.ndarray:
    """Grey levels (n, n) float32 of the marker's bits incl. the black border and the white quiet
    zone; row 0 is the top (marker +y), column 0 the left (marker −x)."""
    if dictionary not in ARUCO_DICTIONARIES:
        raise RenderError(f"unknown ArUco dictionary {dictionary!r}")
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n_marker = d.markerSize + 2
    n_ids = d.bytesList.shape[0]
    if not 0 <= marker_id < n_ids:
        raise RenderError(f"marker id {marker_id} is not in {dictionary} (ids 0..{n_ids - 1})")
    bits = _marker_image(d, int(marker_id), n_marker)
    q = QUIET_ZONE_BITS
    out = np.full((n_marker + 2 * q, n_marker + 2 * q), _WHITE, dtype=np.float32)
    out[q:q + n_marker, q:q + n_marker] = np.where(bits > 127, _WHITE, _BLACK)
    out.flags.writeable = False
    return out


def _marker_bit_count(dictionary: str) -> int:
    """Bits across the black square (data bits + 2 border bits)."""
    return _marker_bits(dictionary, 0).shape[0] - 2 * QUIET_ZONE_BITS


@functools.lru_cache(maxsize=8)
def _background(width: int, seed: int) -> np.ndarray:
    """A textured panorama (H, W) uint8, periodic in azimuth: low-frequency blobs plus lines,
    rectangles and edges (candidate quads for false-positive tests). Read-only, cached."""
    height = width // 2
    rng = np.random.default_rng(seed)
    # low-frequency blobs: a coarse random grid, wrapped in azimuth, upsampled smoothly
    cw = 20
    ch = cw // 2
    coarse = rng.normal(0.0, 1.0, (ch, cw)).astype(np.float32)
    tiled = np.concatenate([coarse[:, -4:], coarse, coarse[:, :4]], axis=1)
    scale = width / cw
    up = cv2.resize(tiled, (int(round(tiled.shape[1] * scale)), height), interpolation=cv2.INTER_CUBIC)
    off = int(round(4 * scale))
    img = 135.0 + 28.0 * up[:, off:off + width]
    # straight edges: rectangles (filled and outlined) and lines, drawn at 1920-wide scale
    s = width / 1920.0
    canvas = img.astype(np.float32)
    for _ in range(60):
        w = rng.uniform(10, 160) * s
        h = rng.uniform(10, 120) * s
        x0 = rng.uniform(0, width - w)
        y0 = rng.uniform(0.1 * height, 0.9 * height - h)
        level = float(rng.uniform(50, 215))
        p0 = (int(x0), int(y0))
        p1 = (int(x0 + w), int(y0 + h))
        thick = -1 if rng.random() < 0.6 else max(1, int(round(rng.uniform(1, 4) * s)))
        cv2.rectangle(canvas, p0, p1, level, thick, lineType=cv2.LINE_AA)
    for _ in range(40):
        p0 = (int(rng.uniform(0, width)), int(rng.uniform(0, height)))
        p1 = (int(p0[0] + rng.normal(0, 200 * s)), int(p0[1] + rng.normal(0, 100 * s)))
        cv2.line(canvas, p0, p1, float(rng.uniform(40, 220)), max(1, int(round(rng.uniform(1, 3) * s))),
                 lineType=cv2.LINE_AA)
    # a gentle ground/sky gradient
    rows = np.linspace(1.0, -1.0, height, dtype=np.float32)[:, None]
    canvas += 18.0 * rows
    out = np.clip(np.rint(canvas), 0, 255).astype(np.uint8)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=4)
def _noise_field(height: int, width: int, seed: int) -> np.ndarray:
    """Standard normal float32 field a little larger than (height, width); read-only, cached."""
    field = np.random.default_rng([seed, 0xA015E]).standard_normal((height + 61, width + 67), dtype=np.float32)
    field.flags.writeable = False
    return field


def _bounding_box(equirect: Equirect, marker: PlacedMarker, half: float, extra_pad: float = 0.0
                  ) -> Optional[Tuple[int, int, int, int]]:
    """Pixel box (u0, u1, v0, v1), inclusive, u possibly outside [0, W) (wraps), of the marker's
    face square of half side ``half`` (m), padded by ``extra_pad`` px. None when the square is behind
    the camera entirely."""
    n_edge = 24
    t = np.linspace(-1.0, 1.0, n_edge, endpoint=False)
    ones = np.ones_like(t)
    outline = np.concatenate([
        np.stack([t, ones], -1), np.stack([ones, -t], -1), np.stack([-t, -ones], -1), np.stack([-ones, t], -1),
    ]) * half
    pts = marker.points_on_face(outline)
    az, el = bearing_to_azel(pts)
    az_c = float(bearing_to_azel(marker.center)[0])
    az_u = az_c + (az - az_c + math.pi) % (2.0 * math.pi) - math.pi
    el_min, el_max = float(el.min()), float(el.max())
    # a pole inside the square: the ray along ±z hits the face inside the outline
    all_columns = False
    for pole in (1.0, -1.0):
        R = np.asarray(marker.camera_R_marker, dtype=float)
        n = R[:, 2]
        denom = pole * n[2]
        if abs(denom) < 1e-12:
            continue
        s = float(np.dot(marker.center, n)) / denom
        if s <= 0:
            continue
        hit = np.array([0.0, 0.0, pole * s]) - marker.center
        if abs(hit @ R[:, 0]) <= half and abs(hit @ R[:, 1]) <= half:
            all_columns = True
            if pole > 0:
                el_max = math.pi / 2
            else:
                el_min = -math.pi / 2
    # great-circle edges bulge between outline samples: pad by the sample spacing's sagitta + 2 px
    pad = 2.0 + extra_pad + (2.0 * half / n_edge) / max(float(np.linalg.norm(pts, axis=-1).min()), 1e-9) \
        / equirect.rad_per_px
    if all_columns or float(az_u.max() - az_u.min()) > math.pi:
        u0, u1 = 0, equirect.width - 1
    else:
        ua, _ = equirect.azel_to_pixel(az_u.max(), 0.0)
        ua = float(equirect.unwrap_u(ua, equirect.azel_to_pixel(az_c, 0.0)[0]))
        ub = ua + (az_u.max() - az_u.min()) / equirect.rad_per_px
        u0, u1 = int(math.floor(ua - pad)), int(math.ceil(ub + pad))
        if u1 - u0 + 1 >= equirect.width:
            u0, u1 = 0, equirect.width - 1
    _, v_top = equirect.azel_to_pixel(0.0, el_max)
    _, v_bot = equirect.azel_to_pixel(0.0, el_min)
    v0 = max(0, int(math.floor(float(v_top) - pad)))
    v1 = min(equirect.height - 1, int(math.ceil(float(v_bot) + pad)))
    if v1 < v0:
        return None
    return u0, u1, v0, v1


class _MarkerShader:
    """Ray casting against one planar textured square (a marker's black square + quiet zone, or any
    square ``bits`` texture) in the camera frame.

    The placement may be one pose (``center`` (3,), ``camera_R_marker`` (3, 3)) or one pose per
    image row (``center`` (H, 3), ``camera_R_marker`` (H, 3, 3)): a rolling shutter, each row
    seeing the square where it was at that row's capture time. ``lens`` (a ``DualFisheye`` and the index
    of one of its lenses), optional: the rays start at that lens's centre and run along its direction for
    each stitched pixel (the placement is then relative to the camera origin, as always)."""

    def __init__(self, equirect: Equirect, marker: PlacedMarker, bits: np.ndarray, n_bits_black: int,
                 lens: Optional[Tuple[DualFisheye, int]] = None):
        self.lens = lens
        if lens is not None:   # ray casting from the lens centre: the square relative to it
            centre = np.asarray(marker.center, dtype=float) - lens[0].centres[lens[1]]
            marker = PlacedMarker(marker.id, marker.size, centre, marker.camera_R_marker)
        self.marker = marker
        self.equirect = equirect
        R = np.asarray(marker.camera_R_marker, dtype=float)
        c = np.asarray(marker.center, dtype=float)
        self.per_row = c.ndim == 2
        self.R = R
        self.bits = bits
        self.n_all = bits.shape[0]
        self.bit = marker.size / n_bits_black  # bit width, m
        self.half = 0.5 * self.bit * self.n_all  # half side incl. the quiet zone, m
        cn = np.einsum("...i,...ij->...j", c, R)  # centre along marker x, y, z (per row)
        self.c_x, self.c_y, self.c_n = cn[..., 0], cn[..., 1], cn[..., 2]
        mid = c.shape[0] // 2 if self.per_row else None
        c_mid, R_mid, n_mid = (c[mid], R[mid], float(cn[mid, 2])) if self.per_row else (c, R, float(cn[2]))
        self.front = n_mid < 0.0  # the camera (origin) is on the printed side
        self.edge_on = abs(n_mid) < 1e-12
        # smallest on-image bit width (px) at the centre, foreshortening included
        b = c_mid / np.linalg.norm(c_mid)
        perp = [R_mid[:, k] - (R_mid[:, k] @ b) * b for k in (0, 1)]
        self.bit_px = self.bit * min(float(np.linalg.norm(p)) for p in perp) / float(np.linalg.norm(c_mid)) \
            / equirect.rad_per_px

    def shade(self, u, v) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(inside, grey, distance) at pixel coordinates u, v (same shape): whether the ray hits the
        face (square + quiet zone), its grey level (float32) and the distance along the ray (m)."""
        d = self.equirect.pixel_to_bearing(u, v)
        if self.lens is not None:
            d = self.lens[0].lens_rays(d, self.lens[1])[1]
        if self.per_row:
            # pixel centres at integer rows: a sub-sample belongs to the nearest row
            row = np.clip(np.floor(np.asarray(v) + 0.5).astype(np.intp), 0, self.R.shape[0] - 1)
            if row.ndim == 2 and row.shape[1] > 1 and np.asarray(v)[0, 0] == np.asarray(v)[0, -1]:
                dp = np.matmul(d, self.R[row[:, 0]])  # a grid, one image row per grid row: batched d @ R
            else:
                Rr = self.R.reshape(-1, 9)[row]  # each sample's row rotation, flattened: d @ R without einsum
                dp = d[..., 0:1] * Rr[..., 0:3] + d[..., 1:2] * Rr[..., 3:6] + d[..., 2:3] * Rr[..., 6:9]
            c_x, c_y, c_n = self.c_x[row], self.c_y[row], self.c_n[row]
        else:
            dp = d @ self.R  # ray components along marker x, y, z
            c_x, c_y, c_n = self.c_x, self.c_y, self.c_n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = c_n / dp[..., 2]
            mx = t * dp[..., 0] - c_x
            my = t * dp[..., 1] - c_y
            inside = (t > 0) & (np.abs(mx) < self.half) & (np.abs(my) < self.half)
        if self.front:
            n = self.n_all
            col = np.clip(np.floor((np.where(inside, mx, 0.0) + self.half) / self.bit).astype(np.intp), 0, n - 1)
            row = np.clip(np.floor((self.half - np.where(inside, my, 0.0)) / self.bit).astype(np.intp), 0, n - 1)
            grey = self.bits[row, col]
        else:  # the back of the board: plain white
            grey = np.full(inside.shape, _WHITE, dtype=np.float32)
        return inside, grey, t


# below this on-image bit width (px) every pixel of the box is supersampled
_ADAPTIVE_MIN_BIT_PX = 3.0


def _splat_marker(canvas: np.ndarray, equirect: Equirect, marker: PlacedMarker, bits: np.ndarray,
                  n_bits_black: int, supersample: int, depth: Optional[np.ndarray] = None,
                  light: Tuple[float, float] = (1.0, 0.0), lenses: DualFisheye = SINGLE_CENTRE) -> None:
    """Average the marker (with its quiet zone) into ``canvas`` (H, W) float32 in place.

    Pixels are shaded by S×S sub-samples (S = ``supersample``). When a bit spans at least
    ``_ADAPTIVE_MIN_BIT_PX`` pixels, pixels whose 8 neighbours all have the centre's shade
    (same side of every edge) are taken from their centre sample and only the rest are
    supersampled (the same result, several times faster for close markers).

    ``marker`` may be placed per image row (a rolling shutter, see :class:`_MarkerShader`).
    The texture's grey g is painted as ``offset + gain · g`` (illumination: ``light`` = (gain, offset)).
    ``depth`` (H, W), optional: a depth buffer (m along the ray); pixels at least half covered get the face's
    distance where it is nearer, and the face is not painted where the buffer is nearer.
    ``lenses``: the camera's two lenses; each pixel is shaded through the lens(es) the stitcher takes it from,
    weighted by their share (:meth:`DualFisheye.front_weight`).
    """
    gain, offset = light
    if lenses.single_centre:
        views = [(_MarkerShader(equirect, marker, bits, n_bits_black), None, 0.0)]
    else:
        # a lens's stitched image is its own view turned by half the relative rotation and moved by the
        # stitching distance's parallax: pad each lens's box by that
        pad = (0.5 * float(np.linalg.norm(lenses.lens_rotation)) + lenses.lens_offset / lenses.stitch_distance) \
            / equirect.rad_per_px + 1.0
        views = [(_MarkerShader(equirect, marker, bits, n_bits_black, (lenses, k)), k, pad) for k in (0, 1)]
    views = [v for v in views if not v[0].edge_on]
    boxes = []
    for shader, _, pad in views:
        boxes.append(_bounding_box(equirect, _row_placement(shader.marker, 0), shader.half, pad))
        if shader.per_row:  # the union of the boxes at the first, middle and last row's poses
            rows = shader.marker.center.shape[0]
            boxes += [_bounding_box(equirect, _row_placement(shader.marker, k), shader.half, pad)
                      for k in (rows // 2, rows - 1)]
    box = _union_boxes(equirect, boxes)
    if box is None:
        return
    u0, u1, v0, v1 = box
    uu, vv = np.meshgrid(np.arange(u0, u1 + 1, dtype=float), np.arange(v0, v1 + 1, dtype=float))
    covered = paint = dist = None
    front = None if lenses.single_centre else lenses.front_weight(equirect.pixel_to_bearing(uu, vv)).astype(np.float32)
    for shader, k, _ in views:
        share = None if k is None else (front if k == 0 else 1.0 - front)
        if share is not None and not share.any():
            continue
        cover = _coverage(shader, uu, vv, int(supersample), depth is not None)
        if cover is None:
            continue
        c_k, p_k, d_k = cover if share is None else (cover[0] * share, cover[1] * share, cover[2])
        if covered is None:
            covered, paint, dist = c_k, p_k, d_k
        else:
            covered, paint = covered + c_k, paint + p_k
            if d_k is not None:   # the depth of the lens with the larger share
                dist = d_k if dist is None else np.where(front >= 0.5, dist, d_k)
    if covered is None:
        return
    if gain != 1.0 or offset != 0.0:
        paint = (gain * paint + offset * covered).astype(np.float32)
    cols = np.arange(u0, u1 + 1) % equirect.width
    if depth is not None:
        behind = depth[v0:v1 + 1][:, cols]
        dist = np.where(np.isfinite(dist) & (dist > 0), dist, np.inf).astype(np.float32)
        hidden = behind < dist
        covered = np.where(hidden, np.float32(0.0), covered)
        paint = np.where(hidden, np.float32(0.0), paint)
        depth[v0:v1 + 1, cols] = np.where(covered >= 0.5, dist, behind)
    patch = canvas[v0:v1 + 1][:, cols]
    canvas[v0:v1 + 1, cols] = patch * (1.0 - covered) + paint


def _coverage(shader: _MarkerShader, uu: np.ndarray, vv: np.ndarray, S: int, with_depth: bool):
    """(covered fraction, mean grey × covered, distance or None) float32 per pixel of the grid ``uu``, ``vv``
    (pixel centres of a box) by S×S sub-samples (adaptive, see :func:`_splat_marker`); None when the face
    covers none of it."""
    rows_n, cols_n = uu.shape
    offs = (np.arange(S) + 0.5) / S - 0.5
    if S > 1 and shader.bit_px >= _ADAPTIVE_MIN_BIT_PX:
        inside, grey, dist = shader.shade(uu, vv)
        if not inside.any():
            return None
        label = np.pad(np.where(inside, grey, -1.0), 1, mode="edge")
        centre = label[1:-1, 1:-1]
        mixed = np.zeros(centre.shape, dtype=bool)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                mixed |= label[dy:dy + rows_n, dx:dx + cols_n] != centre
        covered = inside.astype(np.float32)
        paint = np.where(inside, grey, np.float32(0.0)).astype(np.float32)
        iy, ix = np.nonzero(mixed)
        if iy.size:
            su = (uu[iy, ix][:, None, None] + offs[None, None, :]).repeat(S, axis=1)
            sv = (vv[iy, ix][:, None, None] + offs[None, :, None]).repeat(S, axis=2)
            s_in, s_grey, _ = shader.shade(su, sv)
            covered[iy, ix] = s_in.mean(axis=(1, 2), dtype=np.float32)
            paint[iy, ix] = np.where(s_in, s_grey, np.float32(0.0)).mean(axis=(1, 2), dtype=np.float32)
        return covered, paint, dist
    us = (uu[0][:, None] + offs[None, :]).ravel()
    vs = (vv[:, 0][:, None] + offs[None, :]).ravel()
    inside, grey, _ = shader.shade(*np.meshgrid(us, vs))
    if not inside.any():
        return None
    # per pixel: the covered fraction and the mean of the covered samples' grey
    covered = inside.reshape(rows_n, S, cols_n, S).mean(axis=(1, 3), dtype=np.float32)
    paint = np.where(inside, grey, np.float32(0.0)).reshape(rows_n, S, cols_n, S).mean(axis=(1, 3), dtype=np.float32)
    return covered, paint, (shader.shade(uu, vv)[2] if with_depth else None)


def _row_placement(marker: PlacedMarker, row: int) -> PlacedMarker:
    """The placement of ``marker`` at image row ``row`` (itself when it has a single pose)."""
    c = np.asarray(marker.center)
    if c.ndim == 1:
        return marker
    return PlacedMarker(marker.id, marker.size, c[row], np.asarray(marker.camera_R_marker)[row])


def _union_boxes(equirect: Equirect, boxes) -> Optional[Tuple[int, int, int, int]]:
    """The pixel box covering all ``boxes`` (None entries skipped), columns unwrapped near the first."""
    boxes = [b for b in boxes if b is not None]
    if not boxes:
        return None
    W = equirect.width
    u0, u1, v0, v1 = boxes[0]
    for a0, a1, b0, b1 in boxes[1:]:
        if u1 - u0 + 1 >= W or a1 - a0 + 1 >= W:
            u0, u1 = 0, W - 1
        else:
            shift = W * round(((u0 + u1) - (a0 + a1)) / (2.0 * W))
            u0, u1 = min(u0, a0 + shift), max(u1, a1 + shift)
        v0, v1 = min(v0, b0), max(v1, b1)
    if u1 - u0 + 1 >= W:
        u0, u1 = 0, W - 1
    return u0, u1, v0, v1


def render_equirect(width: int, markers: Sequence[PlacedMarker], dictionary: str = "DICT_4X4_50",
                    profile: Union[str, RenderProfile] = "realistic", seed: int = 0,
                    background_yaw: float = 0.0, noise_seed: Optional[int] = None) -> np.ndarray:
    """Render a grey equirect frame (H, W) = (width // 2, width) uint8 with ``markers``.

    ``profile``: a name of :data:`PROFILES` or a :class:`RenderProfile`. ``seed`` selects the
    background panorama and, unless ``noise_seed`` is given (e.g. the frame index), the noise.
    ``background_yaw`` (radians): the camera's yaw in the
    background's world; a background direction at azimuth a appears at camera azimuth
    a − background_yaw (the panorama is rolled by whole pixels). When the profile has a
    ``jpeg_quality``, the frame returned is the decoded JPEG (what a bag will hold).
    Markers do not occlude one another (later ones are painted over earlier ones).
    """
    if int(width) != width or width < 8 or width % 2:
        raise RenderError(f"image width must be an even integer >= 8, got {width!r}")
    if not math.isfinite(background_yaw):
        raise RenderError(f"background_yaw must be finite, got {background_yaw!r}")
    width = int(width)
    p = _resolve_profile(profile)
    equirect = Equirect(width, width // 2)
    if p.background == "textured":
        shift = int(round(background_yaw / equirect.rad_per_px))
        canvas = np.roll(_background(width, int(seed)), shift, axis=1).astype(np.float32)
    else:
        canvas = np.full((equirect.height, width), float(_GREY_LEVEL), dtype=np.float32)
    n_black = _marker_bit_count(dictionary)
    for m in markers:
        _splat_marker(canvas, equirect, m, _marker_bits(dictionary, int(m.id)), n_black, p.supersample)
    return finish_frame(canvas, p, int(seed), int(seed if noise_seed is None else noise_seed))


def finish_frame(canvas: np.ndarray, profile: RenderProfile, seed: int, noise_seed: int) -> np.ndarray:
    """The frame's last steps on ``canvas`` (H, W) float32 grey levels (modified): the profile's
    sensor noise, optical blur, rounding to uint8 and, when it has a ``jpeg_quality``, the JPEG
    round trip. ``seed`` selects the cached noise field, ``noise_seed`` this frame's window of it."""
    p = profile
    height, width = canvas.shape
    if p.noise_sigma > 0:
        # a window of a cached i.i.d. N(0, 1) field at an offset drawn from the noise seed (cheap;
        # every pixel of a frame independent, successive frames shifted copies of one field)
        field = _noise_field(height, width, int(seed))
        dy, dx = np.random.default_rng([int(noise_seed), 0x5EED]).integers(
            0, [field.shape[0] - height + 1, field.shape[1] - width + 1])
        window = field[dy:dy + height, dx:dx + width]
        cv2.scaleAdd(window, float(p.noise_sigma), canvas, dst=canvas)
    if p.blur_sigma_px > 0:
        cv2.GaussianBlur(canvas, (0, 0), p.blur_sigma_px, dst=canvas, borderType=cv2.BORDER_REPLICATE)
    # rounding: floor(x + 0.5), negatives to 0, then OpenCV's saturating conversion of these whole numbers:
    # the same pixels as numpy's clip to 0..255 and astype, in 10-14 instead of 17-26 ms a 3840x1920 frame
    np.add(canvas, 0.5, out=canvas)
    np.floor(canvas, out=canvas)
    cv2.threshold(canvas, 0.0, 0.0, cv2.THRESH_TOZERO, dst=canvas)
    image = cv2.convertScaleAbs(canvas)
    if p.jpeg_quality is not None:
        image = decode_jpeg(encode_jpeg(image, p.jpeg_quality))
    return image


def encode_jpeg(image: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of a grey uint8 image at ``quality`` (1–100)."""
    if not 1 <= int(quality) <= 100:
        raise RenderError(f"JPEG quality must be 1..100, got {quality!r}")
    ok, buf = cv2.imencode(".jpg", image, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    if not ok:
        raise RenderError("JPEG encoding failed")
    return buf.tobytes()


def decode_jpeg(data: bytes) -> np.ndarray:
    """Grey uint8 image of JPEG bytes."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise RenderError("not a decodable JPEG")
    return image


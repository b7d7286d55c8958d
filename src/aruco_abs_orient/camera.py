"""Equirectangular camera model and gnomonic (perspective) views.

This is the only module that knows how pixels map to bearings (doc/design.md §2).

Camera frame of an equirectangular image: x = the image's centre column, y = left,
z = up. A pixel (u, v) of a W×H image, OpenCV pixel centres (integer u is the centre
of column u), has

    az = π − 2π(u + 0.5)/W      (radians; 0 = camera +x, +π/2 = camera left)
    el = π/2 − π(v + 0.5)/H     (radians; +π/2 = up)

and the unit bearing (cos el cos az, cos el sin az, sin el).

A real 360° camera is two back-to-back fisheye lenses whose projection centres are not one point;
:class:`DualFisheye` is that geometry (each lens's centre offset along its own axis, each lens's residual
rotation, the stitching distance and the blend band at the seams): the ray in space of a stitched bearing
(:meth:`DualFisheye.rays`), and the stitched bearing of a point (:meth:`DualFisheye.project`). With a zero
offset and rotation it is the single-centre model above (a ray from the camera origin along the bearing).

A gnomonic view is a virtual pinhole camera (OpenCV convention: x right, y down,
z forward, pixel centres at integers) whose optical axis points along a chosen bearing
of the equirectangular camera; it is used to detect markers without the equirect
distortion (near the poles, close by) and to track predicted markers in small windows.

Everything here is vectorised over leading array dimensions. Python 3.8 compatible.
"""

from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

from .errors import ConfigurationError
from .transforms import cross3, rotvec_to_matrix

__all__ = [
    "CameraModelError",
    "Equirect",
    "DualFisheye",
    "SINGLE_CENTRE",
    "GnomonicView",
    "sphere_centre_bearing",
    "azel_to_bearing",
    "bearing_to_azel",
    "angle_between",
]


class CameraModelError(ConfigurationError):
    """Invalid camera model parameters (image size, view size, field of view)."""


def azel_to_bearing(az, el) -> np.ndarray:
    """Unit bearing(s) (..., 3) from azimuth and elevation in radians."""
    az = np.asarray(az, dtype=float)
    el = np.asarray(el, dtype=float)
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=-1)


def bearing_to_azel(bearing) -> Tuple[np.ndarray, np.ndarray]:
    """Azimuth in (−π, π] and elevation in [−π/2, π/2] (radians) of bearing(s) (..., 3).

    The bearing need not be unit length; it must not be zero.
    """
    b = np.asarray(bearing, dtype=float)
    x, y, z = b[..., 0], b[..., 1], b[..., 2]
    az = np.arctan2(y, x)
    el = np.arctan2(z, np.hypot(x, y))
    return az, el


def angle_between(a, b) -> np.ndarray:
    """Angle (radians) between vectors a and b (..., 3); accurate for tiny angles."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cross = np.linalg.norm(cross3(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    return np.arctan2(cross, dot)


class Equirect:
    """Equirectangular image model of size ``width`` × ``height`` pixels (width = 2·height).

    >>> cam = Equirect(3840, 1920)
    >>> u, v = cam.bearing_to_pixel([1.0, 0.0, 0.0])
    >>> float(u), float(v)
    (1919.5, 959.5)
    """

    def __init__(self, width: int, height: int):
        if int(width) != width or int(height) != height or width <= 0 or height <= 0:
            raise CameraModelError(f"image size must be positive integers, got {width!r}x{height!r}")
        if width != 2 * height:
            raise CameraModelError(
                f"an equirectangular image is 2:1, got {width}x{height}")
        self.width = int(width)
        self.height = int(height)

    def __repr__(self) -> str:
        return f"Equirect({self.width}, {self.height})"

    @property
    def rad_per_px(self) -> float:
        """Angular pixel pitch (radians per pixel), the same along both axes."""
        return 2.0 * math.pi / self.width

    def pixel_to_azel(self, u, v) -> Tuple[np.ndarray, np.ndarray]:
        """Azimuth and elevation (radians) of pixel coordinates (OpenCV pixel centres)."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        az = math.pi * (1.0 - 2.0 * (u + 0.5) / self.width)
        el = math.pi * (0.5 - (v + 0.5) / self.height)
        return az, el

    def azel_to_pixel(self, az, el) -> Tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (u in [−0.5, W−0.5), v in [−0.5, H−0.5]) of az/el in radians."""
        az = np.asarray(az, dtype=float)
        el = np.asarray(el, dtype=float)
        u = np.mod((0.5 - az / (2.0 * math.pi)) * self.width, self.width) - 0.5
        v = (0.5 - el / math.pi) * self.height - 0.5
        return u, v

    def pixel_to_bearing(self, u, v) -> np.ndarray:
        """Unit bearing(s) (..., 3) in the camera frame of pixel coordinates."""
        az, el = self.pixel_to_azel(u, v)
        return azel_to_bearing(az, el)

    def bearing_to_pixel(self, bearing) -> Tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of bearing(s) (..., 3) in the camera frame (need not be unit)."""
        az, el = bearing_to_azel(bearing)
        return self.azel_to_pixel(az, el)

    def unwrap_u(self, u, reference) -> np.ndarray:
        """Shift column(s) ``u`` by multiples of W to lie within W/2 of ``reference``.

        Useful for pixel geometry of an object that straddles the ±180° seam.
        """
        u = np.asarray(u, dtype=float)
        return u - self.width * np.round((u - reference) / self.width)


def sphere_centre_bearing(corners) -> np.ndarray:
    """Centre bearing (..., 3) of markers from their four corner bearings (..., 4, 3).

    Intersection of the great circles through opposite corners (n1 = c0×c2, n2 = c1×c3,
    centre = ±n1×n2, the sign nearest the corners' mean). Exact for a planar square seen
    by a central camera: the diagonals' intersection is the square's centre and lines
    project to great circles. A degenerate quad gives the corners' mean direction.
    """
    c = np.asarray(corners, dtype=float)
    c = c / np.linalg.norm(c, axis=-1, keepdims=True)
    m = cross3(cross3(c[..., 0, :], c[..., 2, :]), cross3(c[..., 1, :], c[..., 3, :]))
    norm = np.linalg.norm(m, axis=-1, keepdims=True)
    mean = c.mean(axis=-2)
    m = np.where(norm < 1e-15, mean, m / np.maximum(norm, 1e-300))
    m = np.where(np.sum(m * mean, axis=-1, keepdims=True) < 0, -m, m)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


class DualFisheye:
    """The stitched image of two back-to-back fisheye lenses, as a stitcher makes it.

    Camera frame as for :class:`Equirect`. The front lens looks along ``a`` = (cos α, sin α, 0), α =
    ``axis_azimuth`` (rad; 0: the image's centre column), the back lens along −a; the stitch seams are the
    great circle a·d = 0 (azimuths α ± 90°).

    - ``lens_offset`` (m): each lens's projection centre sits this far from the camera origin along its own
      axis: front ``+o·a``, back ``−o·a`` (the camera origin is their midpoint; an estimate near 0 may be
      negative).
    - ``lens_rotation`` (3,) rad: rotation vector of the back lens relative to the front one (what is left of
      the factory's stitching calibration); each lens is turned by half of it, front ``exp(−ε/2)``, back
      ``exp(+ε/2)``, so that the camera frame (the boresight) stays their mean.
    - ``stitch_distance`` (m, may be inf): the stitcher maps a stitched direction d to lens k's direction
      ``(D·d − c_k)/|D·d − c_k|``: a point at that distance from the camera origin is seen where a single
      centre would see it; nearer or farther points are displaced by about o·sin θ·(1/r − 1/D) rad (θ from
      the lens axis, r the range).
    - ``blend_band`` (rad): width of the band at each seam across which the two images are blended (the
      front lens's weight rises linearly from 0 to 1 over it); a marker in it shows twice, weighted.

    A lens k with centre ``c_k`` and rotation ``E_k`` records a point X at direction ``g = E_kᵀ (X − c_k)/|·|``
    and the stitcher puts it at the stitched direction d solving ``(D d − c_k)/|·| = g``, |d| = 1. Pure
    numpy, vectorised over leading dimensions, Python 3.8.

    >>> cam = DualFisheye(lens_offset=0.01)
    >>> az, _ = bearing_to_azel(cam.project([1.0, 3.0, 0.0]))   # 71.565° from one centre, 0.172° further
    >>> round(float(np.degrees(az)), 3)                           # from the front lens's axis
    71.737
    >>> o, w = cam.rays(cam.project([1.0, 3.0, 0.0]))             # that lens's ray passes through the point
    >>> bool(np.allclose(np.cross(np.array([1.0, 3.0, 0.0]) - o, w), 0.0, atol=1e-12))
    True
    """

    def __init__(self, lens_offset: float = 0.0, lens_rotation=(0.0, 0.0, 0.0), stitch_distance: float = math.inf,
                 blend_band: float = math.radians(2.0), axis_azimuth: float = 0.0):
        rot = np.asarray(lens_rotation, dtype=float).reshape(-1)
        checks = (
            ("lens_offset", math.isfinite(lens_offset) and abs(lens_offset) < 0.2, "metres, |o| < 0.2"),
            ("lens_rotation", rot.shape == (3,) and bool(np.all(np.isfinite(rot)))
             and float(np.linalg.norm(rot)) < math.radians(10.0), "a rotation vector of 3 finite radians, < 10°"),
            ("stitch_distance", stitch_distance > 0.5 and not math.isnan(stitch_distance), "metres > 0.5, or inf"),
            ("blend_band", math.isfinite(blend_band) and 0.0 < blend_band < math.radians(30.0), "radians in (0, 30°)"),
            ("axis_azimuth", math.isfinite(axis_azimuth), "a finite angle in radians"),
        )
        for name, ok, what in checks:
            if not ok:
                raise CameraModelError(f"DualFisheye.{name}: expected {what}, got {locals()[name]!r}")
        self.lens_offset = float(lens_offset)
        self.lens_rotation = rot.copy()
        self.stitch_distance = float(stitch_distance)
        self.blend_band = float(blend_band)
        self.axis_azimuth = float(axis_azimuth)
        self.axis = np.array([math.cos(axis_azimuth), math.sin(axis_azimuth), 0.0])
        self.centres = np.stack([self.lens_offset * self.axis, -self.lens_offset * self.axis])   # front, back
        self.rotations = np.stack([rotvec_to_matrix(-0.5 * rot), rotvec_to_matrix(0.5 * rot)])  # E_front, E_back

    def __repr__(self) -> str:
        return (f"DualFisheye(lens_offset={self.lens_offset!r}, lens_rotation={self.lens_rotation.tolist()!r}, "
                f"stitch_distance={self.stitch_distance!r}, blend_band={self.blend_band!r}, "
                f"axis_azimuth={self.axis_azimuth!r})")

    def __eq__(self, other) -> bool:
        return isinstance(other, DualFisheye) and repr(self) == repr(other)

    def __hash__(self) -> int:     # a value: never changed after construction
        return hash(repr(self))

    def replace(self, **changes) -> DualFisheye:
        """A copy with some of the constructor's arguments changed."""
        args = {"lens_offset": self.lens_offset, "lens_rotation": self.lens_rotation,
                "stitch_distance": self.stitch_distance, "blend_band": self.blend_band,
                "axis_azimuth": self.axis_azimuth}
        args.update(changes)
        return DualFisheye(**args)

    @property
    def single_centre(self) -> bool:
        """True when the model is the single-centre one (no offset, no relative rotation)."""
        return self.lens_offset == 0.0 and not np.any(self.lens_rotation)

    def front_weight(self, bearings) -> np.ndarray:
        """The front lens's share (...) of the stitched image at stitched bearing(s) (..., 3): 1 in the front
        hemisphere beyond the blend band, 0 in the back one, linear in the angle from the seam across it."""
        b = np.asarray(bearings, dtype=float)
        s = (b @ self.axis) / np.linalg.norm(b, axis=-1)
        return np.clip(np.arcsin(np.clip(s, -1.0, 1.0)) / self.blend_band + 0.5, 0.0, 1.0)

    def blend_error(self, bearings, ranges) -> np.ndarray:
        """How far (rad, ...) :meth:`rays` may be off for stitched bearing(s) (..., 3) of points at ``ranges`` (m)
        in the blend band, where the image is a weighted mix of both lenses' (the ray is the dominant lens's):
        twice the smaller weight times the lens offset's parallax |o|·|1/r − 1/D|; 0 outside the band."""
        if self.single_centre:
            return np.zeros(np.shape(bearings)[:-1])
        w = self.front_weight(bearings)
        r = np.maximum(np.asarray(ranges, dtype=float), 1e-3)
        return 2.0 * np.minimum(w, 1.0 - w) * abs(self.lens_offset) * np.abs(1.0 / r - 1.0 / self.stitch_distance)

    def _lens_direction(self, d: np.ndarray, k: int) -> np.ndarray:
        """Lens k's own direction g (..., 3) sampled for stitched unit directions ``d`` (..., 3)."""
        if math.isinf(self.stitch_distance):
            return d
        g = self.stitch_distance * d - self.centres[k]
        return g / np.linalg.norm(g, axis=-1, keepdims=True)

    def _stitched(self, g: np.ndarray, k: int) -> np.ndarray:
        """The stitched unit direction (..., 3) where lens k's direction ``g`` (unit, ..., 3) lands: d with
        (D·d − c_k) ∥ g, |d| = 1 (exact: the positive root of |c_k + λ g| = D)."""
        if math.isinf(self.stitch_distance):
            return g
        c = self.centres[k]
        cg = g @ c
        lam = -cg + np.sqrt(cg * cg - float(c @ c) + self.stitch_distance ** 2)
        return (c + lam[..., None] * g) / self.stitch_distance

    def lens_rays(self, bearings, lens: int) -> Tuple[np.ndarray, np.ndarray]:
        """Lens ``lens``'s rays (origin (3,) m, unit directions (..., 3)) in the camera frame that the stitcher
        samples for stitched bearing(s) (..., 3) (0 the front lens, 1 the back one; a renderer blends both
        in the band with :meth:`front_weight`)."""
        b = np.asarray(bearings, dtype=float)
        d = b / np.linalg.norm(b, axis=-1, keepdims=True)
        return self.centres[lens], self._lens_direction(d, lens) @ self.rotations[lens].T   # w = E_k g

    def rays(self, bearings) -> Tuple[np.ndarray, np.ndarray]:
        """The rays (origins (..., 3) m, unit directions (..., 3)) in the camera frame along which stitched
        bearing(s) (..., 3) look: from the centre of the lens that dominates there (exact outside the blend
        band; in it, that of the lens with the larger weight), whatever the range."""
        b = np.asarray(bearings, dtype=float)
        if self.single_centre:
            return np.zeros(b.shape), b / np.linalg.norm(b, axis=-1, keepdims=True)
        front = self.front_weight(b) >= 0.5
        (o_f, w_f), (o_b, w_b) = self.lens_rays(b, 0), self.lens_rays(b, 1)
        return np.where(front[..., None], o_f, o_b), np.where(front[..., None], w_f, w_b)

    def marker_rays(self, centres, corners) -> Tuple[np.ndarray, np.ndarray]:
        """The rays (origins (N, 3) m, unit directions (N, 3)) along which detected marker centres (N, 3) look,
        from their corners' stitched bearings (N, 4, 3): a marker whose corners one lens imaged is that lens's
        (:meth:`rays`); one across a seam or in the blend band is seen from the lenses' centres and directions
        weighted by their share of its corners (the diagonals of a square split by the seam meet where the
        mean of the two lenses sees its centre). Rows whose corners are unknown (zero or not finite) use the
        centre, as :meth:`rays` does."""
        d = np.asarray(centres, dtype=float).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        if self.single_centre:
            return np.zeros(d.shape), d
        c = np.asarray(corners, dtype=float).reshape(-1, 4, 3)
        known = np.all(np.isfinite(c), axis=(1, 2)) & np.all(np.linalg.norm(c, axis=-1) > 0, axis=1)
        w = np.where(known, self.front_weight(np.where(known[:, None, None], c, 1.0)).mean(axis=1),
                     (self.front_weight(d) >= 0.5).astype(float))[:, None]
        (o_f, w_f), (o_b, w_b) = self.lens_rays(d, 0), self.lens_rays(d, 1)
        direction = w * w_f + (1.0 - w) * w_b
        return w * o_f + (1.0 - w) * o_b, direction / np.linalg.norm(direction, axis=-1, keepdims=True)

    def project(self, points) -> np.ndarray:
        """Stitched unit bearing(s) (..., 3) of camera-frame point(s) (..., 3) m: each lens's image of the
        point, weighted by that lens's share of the stitched image where the image lands (one of them outside
        the blend band; both, ghosted, in it)."""
        X = np.asarray(points, dtype=float)
        if self.single_centre:
            return X / np.linalg.norm(X, axis=-1, keepdims=True)
        copies, weights = [], []
        for k in (0, 1):
            w = X - self.centres[k]
            g = (w / np.linalg.norm(w, axis=-1, keepdims=True)) @ self.rotations[k]   # g = E_kᵀ w
            d = self._stitched(g, k)
            copies.append(d)
            share = self.front_weight(d)
            weights.append(share if k == 0 else 1.0 - share)
        wf, wb = weights
        total = wf + wb
        none = total <= 0.0    # the point falls in neither lens's part (nearer than the band allows): its side
        wf = np.where(none, (X @ self.axis >= 0).astype(float), wf)
        wb = np.where(none, 1.0 - wf, wb)
        d = wf[..., None] * copies[0] + wb[..., None] * copies[1]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project_marker(self, centres, corners) -> np.ndarray:
        """Stitched unit bearing(s) (..., 3) of marker centre(s) as a detector finds them: the diagonals of the
        four corners' stitched bearings intersected on the sphere (:func:`sphere_centre_bearing`), from the
        camera-frame centre(s) (..., 3) and corners (..., 4, 3) in m, in cyclic order. A marker across a seam
        has its corners from both lenses: its centre is neither lens's image of the centre point. The
        single-centre camera gives the centre's direction (what the diagonals give)."""
        if self.single_centre:
            return self.project(centres)
        return sphere_centre_bearing(self.project(corners))


#: the single-centre camera (no lens offset or rotation): rays from the camera origin along the bearing
SINGLE_CENTRE = DualFisheye()


def _look_rotation(forward, up_hint=None) -> np.ndarray:
    """Rotation camera_R_view whose columns are the view's x (right), y (down), z (forward)."""
    f = np.asarray(forward, dtype=float)
    n = np.linalg.norm(f)
    if not np.isfinite(n) or n == 0.0:
        raise CameraModelError(f"view direction must be a finite non-zero vector, got {forward!r}")
    f = f / n
    up = np.array([0.0, 0.0, 1.0]) if up_hint is None else np.asarray(up_hint, dtype=float)
    right = cross3(f, up)
    if np.linalg.norm(right) < 1e-6:  # looking straight up/down: any right will do
        right = cross3(f, np.array([1.0, 0.0, 0.0]))
        if np.linalg.norm(right) < 1e-6:
            right = cross3(f, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    down = cross3(f, right)
    return np.stack([right, down, f], axis=1)


class GnomonicView:
    """A virtual pinhole camera looking along a bearing of the equirectangular camera.

    Parameters
    ----------
    center_bearing : (3,) bearing of the optical axis in the camera frame.
    size : (width, height) of the view in pixels.
    focal : focal length in pixels. Choose ``focal = 1 / Equirect.rad_per_px`` for
        the equirect image's resolution at the view centre.
    up_hint : (3,) camera-frame direction that appears "up" in the view (default +z).

    View pixel (x, y) has OpenCV pixel centres; the principal point is the view centre
    ((width − 1)/2, (height − 1)/2).
    """

    def __init__(self, center_bearing, size: Tuple[int, int], focal: float,
                 up_hint: Optional[np.ndarray] = None):
        w, h = size
        if int(w) != w or int(h) != h or w <= 0 or h <= 0:
            raise CameraModelError(f"view size must be positive integers, got {size!r}")
        if not (focal > 0 and math.isfinite(focal)):
            raise CameraModelError(f"focal length must be positive, got {focal!r}")
        self.width = int(w)
        self.height = int(h)
        self.focal = float(focal)
        self.cx = (self.width - 1) / 2.0
        self.cy = (self.height - 1) / 2.0
        self.camera_R_view = _look_rotation(center_bearing, up_hint)

    @classmethod
    def around(cls, equirect: Equirect, center_bearing, fov: float, size: Optional[int] = None,
               up_hint=None) -> GnomonicView:
        """A square view of full field of view ``fov`` (radians, < π) around a bearing.

        Without ``size``, the view keeps the equirect image's resolution at its centre.
        """
        if not 0.0 < fov < math.pi:
            raise CameraModelError(f"field of view must be in (0, π) radians, got {fov!r}")
        if size is None:
            size = int(math.ceil(2.0 * math.tan(fov / 2.0) / equirect.rad_per_px))
            size = max(size, 8)
        focal = (size / 2.0) / math.tan(fov / 2.0)
        return cls(center_bearing, (size, size), focal, up_hint)

    @property
    def center_bearing(self) -> np.ndarray:
        return self.camera_R_view[:, 2].copy()

    @property
    def K(self) -> np.ndarray:
        """OpenCV intrinsic matrix of the view."""
        return np.array([[self.focal, 0.0, self.cx], [0.0, self.focal, self.cy], [0.0, 0.0, 1.0]])

    def pixel_to_bearing(self, x, y) -> np.ndarray:
        """Unit camera-frame bearing(s) (..., 3) of view pixel coordinates."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        ray = np.stack([(x - self.cx) / self.focal, (y - self.cy) / self.focal, np.ones_like(x)], axis=-1)
        b = ray @ self.camera_R_view.T
        return b / np.linalg.norm(b, axis=-1, keepdims=True)

    def bearing_to_pixel(self, bearing) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """View pixel coordinates of camera-frame bearing(s), and a mask of those in front.

        Bearings behind the view (z ≤ 0 in the view frame) get NaN coordinates.
        """
        b = np.asarray(bearing, dtype=float) @ self.camera_R_view
        z = b[..., 2]
        front = z > 1e-12
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(front, self.focal * b[..., 0] / z + self.cx, np.nan)
            y = np.where(front, self.focal * b[..., 1] / z + self.cy, np.nan)
        return x, y, front

    def remap_maps(self, equirect: Equirect, step: int = 1) -> Tuple[np.ndarray, np.ndarray]:
        """float32 maps (map_x, map_y) for ``cv2.remap(..., borderMode=cv2.BORDER_WRAP)`` from the
        equirect image to this view: columns may leave [0, W) (the remap wraps them round the
        ±180° seam), rows are clamped at the poles (they never wrap).

        With ``step`` > 1 the exact mapping is computed every ``step`` view pixels and
        interpolated bilinearly in between (≪ 0.1 px off for small views), ~step² times cheaper.
        """
        import cv2

        if step <= 1:
            xs, ys = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
            u, v = equirect.bearing_to_pixel(self.pixel_to_bearing(xs, ys))
            u = equirect.unwrap_u(u, u[self.height // 2, self.width // 2])
            map_x, map_y = u.astype(np.float32), v.astype(np.float32)
        else:
            nx = -(-(self.width - 1) // step) + 1
            ny = -(-(self.height - 1) // step) + 1
            gx, gy = np.meshgrid(np.arange(nx, dtype=float) * step, np.arange(ny, dtype=float) * step)
            u, v = equirect.bearing_to_pixel(self.pixel_to_bearing(gx, gy))
            u = equirect.unwrap_u(u, u[ny // 2, nx // 2])  # no jump at the seam inside the coarse grid
            fx, fy = np.meshgrid(np.arange(self.width, dtype=np.float32) / step,
                                 np.arange(self.height, dtype=np.float32) / step)
            map_x = cv2.remap(u.astype(np.float32), fx, fy, cv2.INTER_LINEAR)
            map_y = cv2.remap(v.astype(np.float32), fx, fy, cv2.INTER_LINEAR)
        np.clip(map_y, 0.0, equirect.height - 1.0, out=map_y)
        return map_x, map_y

    def render(self, image: np.ndarray, equirect: Optional[Equirect] = None,
               interpolation: Optional[int] = None) -> np.ndarray:
        """The view cut out of an equirect ``image`` (grey or colour) by bilinear remap.

        Columns wrap around the ±180° seam.
        """
        import cv2

        if equirect is None:
            equirect = Equirect(image.shape[1], image.shape[0])
        map_x, map_y = self.remap_maps(equirect)
        interp = cv2.INTER_LINEAR if interpolation is None else interpolation
        return cv2.remap(image, map_x, map_y, interp, borderMode=cv2.BORDER_WRAP)

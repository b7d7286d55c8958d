"""camera.py: the equirect convention of doc/design.md §2 and gnomonic views, checked against
hand-computed values and by property tests (round trips, the ±180° seam, the poles)."""
import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.camera import (
    SINGLE_CENTRE,
    CameraModelError,
    DualFisheye,
    Equirect,
    GnomonicView,
    angle_between,
    azel_to_bearing,
    bearing_to_azel,
    sphere_centre_bearing,
)

CAM = Equirect(3840, 1920)
widths = st.sampled_from([64, 960, 1920, 3840])
azimuths = st.floats(-math.pi, math.pi, allow_nan=False)
elevations = st.floats(-math.pi / 2 + 1e-6, math.pi / 2 - 1e-6, allow_nan=False)


def test_hand_checked_pixels():
    # image centre column: camera +x; a quarter to the left: +90° azimuth (camera +y)
    u, v = CAM.bearing_to_pixel([1.0, 0.0, 0.0])
    assert (float(u), float(v)) == (1919.5, 959.5)
    u, v = CAM.bearing_to_pixel([0.0, 1.0, 0.0])
    assert float(u) == pytest.approx(959.5)
    u, v = CAM.bearing_to_pixel([0.0, -1.0, 0.0])
    assert float(u) == pytest.approx(2879.5)
    # pixel (0, 0): its centre is half a pixel right of az = +180° and below el = +90°
    az, el = CAM.pixel_to_azel(0, 0)
    assert float(az) == pytest.approx(math.pi - math.pi / 3840)
    assert float(el) == pytest.approx(math.pi / 2 - math.pi / 3840)
    # straight up lands in the top row band, straight down in the bottom one
    assert float(CAM.bearing_to_pixel([0.0, 0.0, 1.0])[1]) == pytest.approx(-0.5)
    assert float(CAM.bearing_to_pixel([0.0, 0.0, -1.0])[1]) == pytest.approx(1919.5)


@given(widths, st.floats(0, 1, exclude_max=True), st.floats(0, 1))
def test_pixel_bearing_round_trip(width, fu, fv):
    cam = Equirect(width, width // 2)
    u = -0.5 + fu * width
    v = -0.5 + fv * (width // 2)
    b = cam.pixel_to_bearing(u, v)
    assert np.linalg.norm(b) == pytest.approx(1.0)
    if abs(v - (-0.5)) < 1e-9 or abs(v - (width // 2 - 0.5)) < 1e-9:
        return  # at a pole every column is the same bearing
    u2, v2 = cam.bearing_to_pixel(b)
    assert float(v2) == pytest.approx(v, abs=1e-7)
    du = (float(u2) - u + width / 2) % width - width / 2  # the seam: u = −0.5 and W − 0.5 are one column
    assert du == pytest.approx(0.0, abs=1e-6)


@given(azimuths, elevations)
def test_bearing_azel_round_trip(az, el):
    b = azel_to_bearing(az, el)
    az2, el2 = bearing_to_azel(b)
    assert float(el2) == pytest.approx(el, abs=1e-9)
    assert math.remainder(float(az2) - az, 2 * math.pi) == pytest.approx(0.0, abs=1e-9 / max(math.cos(el), 1e-6))
    u, v = CAM.bearing_to_pixel(b)
    assert -0.5 <= float(u) < CAM.width - 0.5
    assert -0.5 <= float(v) <= CAM.height - 0.5


@given(st.floats(1e-6, 1e-4), elevations)
def test_seam_columns_are_neighbours(eps, el):
    # bearings just either side of az = ±180° land on the first and last columns, close after unwrapping
    a, b = azel_to_bearing(math.pi - eps, el), azel_to_bearing(-math.pi + eps, el)
    ua, _ = CAM.bearing_to_pixel(a)
    ub, _ = CAM.bearing_to_pixel(b)
    assert float(ua) < 10 and float(ub) > CAM.width - 10
    assert abs(float(CAM.unwrap_u(ub, ua)) - float(ua)) < 1.0


def test_vectorised_shapes():
    u = np.arange(12.0).reshape(3, 4) * 100
    v = np.full((3, 4), 500.0)
    b = CAM.pixel_to_bearing(u, v)
    assert b.shape == (3, 4, 3)
    u2, v2 = CAM.bearing_to_pixel(b)
    np.testing.assert_allclose(u2, u, atol=1e-7)
    np.testing.assert_allclose(v2, v, atol=1e-7)


@pytest.mark.parametrize("size", [(0, 480), (960, 960), (961, 480), (-2, -1)])
def test_invalid_size_is_rejected(size):
    with pytest.raises(CameraModelError):
        Equirect(*size)


def test_angle_between_is_accurate_for_tiny_angles():
    a = azel_to_bearing(0.3, 0.2)
    b = azel_to_bearing(0.3 + 1e-9, 0.2)
    assert float(angle_between(a, b)) == pytest.approx(1e-9 * math.cos(0.2), rel=1e-6)


@given(azimuths, elevations, st.floats(0.05, 1.5), st.floats(-0.9, 0.9), st.floats(-0.9, 0.9))
def test_gnomonic_round_trip(az, el, fov, fx, fy):
    view = GnomonicView.around(CAM, azel_to_bearing(az, el), fov, size=257)
    x = view.cx + fx * view.width / 2
    y = view.cy + fy * view.height / 2
    b = view.pixel_to_bearing(x, y)
    x2, y2, front = view.bearing_to_pixel(b)
    assert bool(front)
    assert float(x2) == pytest.approx(x, abs=1e-7)
    assert float(y2) == pytest.approx(y, abs=1e-7)


@given(azimuths, elevations)
def test_gnomonic_centre_and_orientation(az, el):
    d = azel_to_bearing(az, el)
    view = GnomonicView.around(CAM, d, 0.5, size=101)
    np.testing.assert_allclose(view.pixel_to_bearing(view.cx, view.cy), d, atol=1e-12)
    # the view's "up" (smaller y) points towards higher elevation, unless looking at a pole
    if abs(el) < 1.4:
        up = view.pixel_to_bearing(view.cx, view.cy - 20)
        assert bearing_to_azel(up)[1] > el
    # a bearing behind the view is flagged, not projected
    _, _, front = view.bearing_to_pixel(-d)
    assert not bool(front)


@pytest.mark.parametrize("az_deg,el_deg", [(0, 0), (180, 0), (-179.9, 10), (30, 80), (-120, -85), (0, 90)])
def test_gnomonic_render_matches_equirect(az_deg, el_deg):
    """A view cut from an image whose grey value is a known function of the bearing shows that
    function at the view's pixels (seam and poles included)."""
    cam = Equirect(1920, 960)
    vs, us = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    b = cam.pixel_to_bearing(us, vs)
    # smooth functions of the bearing: no seam, no pole discontinuity
    image = np.stack([128 + 100 * b[..., i] for i in range(3)], axis=-1).astype(np.float32)
    view = GnomonicView.around(cam, azel_to_bearing(math.radians(az_deg), math.radians(el_deg)), 0.8, size=64)
    out = view.render(image, cam, interpolation=cv2.INTER_LINEAR)
    yy, xx = np.mgrid[0:64, 0:64].astype(float)
    expected = 128 + 100 * view.pixel_to_bearing(xx, yy)
    # bilinear interpolation of a smooth field: error ≲ curvature · pixel², plus the pole row clamp
    np.testing.assert_allclose(out, expected, atol=0.35)


def test_gnomonic_rejects_bad_parameters():
    with pytest.raises(CameraModelError):
        GnomonicView.around(CAM, [1, 0, 0], math.pi)
    with pytest.raises(CameraModelError):
        GnomonicView([0, 0, 0], (10, 10), 5.0)
    with pytest.raises(CameraModelError):
        GnomonicView([1, 0, 0], (10, 10), -1.0)


# ---------------------------------------------------------------------------- the two lenses (DualFisheye)

offsets = st.floats(0.0, 0.03)
stitch = st.sampled_from([math.inf, 1.0, 2.0, 5.0])
rotations = st.lists(st.floats(-0.003, 0.003), min_size=3, max_size=3)
ranges = st.floats(0.8, 30.0)


def _point(az, el, r):
    return r * azel_to_bearing(az, el)


def test_single_centre_is_the_one_centre_model():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(500, 3)) * 5
    d = X / np.linalg.norm(X, axis=1, keepdims=True)
    assert np.allclose(SINGLE_CENTRE.project(X), d, atol=1e-15)
    o, w = SINGLE_CENTRE.rays(d)
    assert np.all(o == 0.0) and np.allclose(w, d, atol=1e-15)
    assert SINGLE_CENTRE.single_centre and not DualFisheye(lens_offset=0.01).single_centre


@pytest.mark.parametrize("az_deg, r, stitch_m", [(70.0, 3.0, math.inf), (110.0, 3.0, math.inf), (45.0, 6.0, math.inf),
                                                  (80.0, 3.0, 2.0), (-60.0, 1.5, 2.0), (150.0, 8.0, 2.0)])
def test_parallax_matches_the_small_angle_formula(az_deg, r, stitch_m):
    """A point at range r, θ from its lens's axis, is pushed away from that axis by o·sin θ·(1/r − 1/D) rad
    (hand formula, to first order in o): 1 cm at 3 m abeam is 0.18° at infinity stitching, none at r = D."""
    o = 0.01
    cam = DualFisheye(lens_offset=o, stitch_distance=stitch_m)
    az = math.radians(az_deg)
    az_seen, el_seen = bearing_to_azel(cam.project(_point(az, 0.0, r)))
    theta = abs(az) if abs(az) < math.pi / 2 else math.pi - abs(az)   # angle from the lens's own axis
    away = 1.0 if abs(az) < math.pi / 2 else -1.0                   # front: away from +x is away from az 0
    expected = away * math.copysign(1.0, az) * o * math.sin(theta) * (1.0 / r - 1.0 / stitch_m)
    assert float(el_seen) == pytest.approx(0.0, abs=1e-12)
    assert float(az_seen) - az == pytest.approx(expected, rel=0.01, abs=2e-6)
    # the figure: 1 cm, 3 m abeam, stitched at infinity → about 0.19°
    if stitch_m == math.inf and az_deg == 70.0:
        assert math.degrees(abs(float(az_seen) - az)) == pytest.approx(0.18, abs=0.01)


@given(azimuths, st.floats(-1.2, 1.2), ranges, offsets, stitch, rotations)
def test_the_ray_of_a_projected_point_passes_through_it(az, el, r, o, d_stitch, rot):
    """Outside the blend band the ray of the stitched bearing of any point goes through the point, for any
    offset, rotation and stitching distance (the forward and inverse models agree exactly)."""
    cam = DualFisheye(lens_offset=o, lens_rotation=rot, stitch_distance=d_stitch)
    X = _point(az, el, r)
    d = cam.project(X)
    if 0.0 < float(cam.front_weight(d)) < 1.0:
        return
    origin, w = cam.rays(d)
    assert np.linalg.norm(np.cross(X - origin, w)) < 1e-9 * r and float((X - origin) @ w) > 0


@given(azimuths, st.floats(-1.2, 1.2), ranges, offsets, rotations, st.floats(0.05, 0.4), st.floats(-1.0, 1.0))
def test_a_marker_seen_by_one_lens_is_its_centre_seen_by_it(az, el, r, o, rot, size, turn):
    """A square within one lens's part of the image (stitched at infinity: each lens a central camera) has its
    diagonals meet at that lens's image of its centre, at any orientation; with a single centre, at the
    centre's direction."""
    from aruco_abs_orient.markers import square_corners

    cam = DualFisheye(lens_offset=o, lens_rotation=rot)
    X = _point(az, el, r)
    corners = X + square_corners(size, -X + turn * np.array([0.0, 0.0, r]))
    weights = cam.front_weight(cam.project(corners))
    if not (np.all(weights == 1.0) or np.all(weights == 0.0)):
        return                                       # across a seam: the rendered test covers it (test_world)
    assert angle_between(cam.project_marker(X, corners), cam.project(X)) < 1e-9
    # the single centre's shortcut (the centre's direction) is what its corners' diagonals give
    assert angle_between(sphere_centre_bearing(SINGLE_CENTRE.project(corners)), X) < 1e-9
    # and back: its ray is that lens's, as it is where its corners are unknown
    d = cam.project(X)[None]
    for seen in (cam.project(corners)[None], np.zeros((1, 4, 3))):
        origin, w = cam.marker_rays(d, seen)
        o_lens, w_lens = cam.rays(d)
        assert np.allclose(origin, o_lens, atol=1e-15) and np.allclose(w, w_lens, atol=1e-12)


@given(azimuths, st.floats(-1.2, 1.2), st.floats(1.0, 20.0), st.floats(0.001, 0.03))
def test_a_point_at_the_stitching_distance_shows_no_parallax(az, el, d_stitch, o):
    cam = DualFisheye(lens_offset=o, stitch_distance=d_stitch)
    X = _point(az, el, d_stitch)
    assert angle_between(cam.project(X), X) < 1e-12


def test_each_lens_is_turned_by_half_the_relative_rotation():
    """Front points turn by −ε/2, back points by +ε/2: ε is the back lens's rotation relative to the front."""
    eps = np.radians([0.0, 0.0, 0.05])   # the back lens turned 0.05° about z relative to the front
    cam = DualFisheye(lens_rotation=eps)
    for az, sign in ((0.3, -1.0), (2.8, 1.0), (-2.8, 1.0), (-0.3, -1.0)):
        seen = float(bearing_to_azel(cam.project(_point(az, 0.0, 5.0)))[0])
        assert seen - az == pytest.approx(-sign * 0.5 * eps[2], abs=1e-12)


def test_the_blend_band_ghosts_both_images_and_is_continuous():
    """On the seam both copies are weighted equally; across the band the stitched bearing moves smoothly from
    the front copy to the back copy (no jump larger than the parallax between neighbouring points)."""
    cam = DualFisheye(lens_offset=0.01, blend_band=math.radians(2.0))
    r = 3.0
    az = np.radians(np.linspace(85.0, 95.0, 2001))
    X = _point(az, np.zeros_like(az), r)
    seen = bearing_to_azel(cam.project(X))[0]
    step = np.diff(seen - az)
    assert np.max(np.abs(step)) < 2e-4                      # continuous (0.01° per 0.005° step at most)
    front = np.degrees(seen - az)[az < np.radians(88.0)]
    back = np.degrees(seen - az)[az > np.radians(92.0)]
    assert np.all(front > 0.15) and np.all(back < -0.15)    # front lens pushes to larger az, back to smaller
    on_seam = cam.project(_point(math.pi / 2, 0.0, r))
    assert float(bearing_to_azel(on_seam)[0]) == pytest.approx(math.pi / 2, abs=1e-12)


def test_lens_model_rejects_bad_parameters():
    for kwargs in ({"lens_offset": -0.3}, {"lens_offset": math.nan}, {"stitch_distance": 0.1},
                   {"lens_rotation": [0.0, 0.0]}, {"blend_band": 0.0}, {"lens_rotation": [1.0, 0.0, 0.0]}):
        with pytest.raises(CameraModelError, match=list(kwargs)[0]):
            DualFisheye(**kwargs)
    assert DualFisheye(lens_offset=0.01).replace(stitch_distance=2.0) == DualFisheye(lens_offset=0.01,
                                                                                     stitch_distance=2.0)

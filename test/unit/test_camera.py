"""camera.py: the equirect convention of DESIGN §2 and gnomonic views, checked against
hand-computed values and by property tests (round trips, the ±180° seam, the poles)."""
import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.camera import (
    CameraModelError,
    Equirect,
    GnomonicView,
    angle_between,
    azel_to_bearing,
    bearing_to_azel,
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

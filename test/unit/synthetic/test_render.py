"""synthetic/render.py: rendered markers land where camera.py says they should.

Independent check: plain cv2.aruco (not the package's detection module) finds the marker, with
the right id and corner order, in a GnomonicView (camera.py) cut around it; its corners are then
refined by fitting straight lines to the 50 % crossings of the black square's four outer edges in
that perspective view (a marker's edges are straight lines in any pinhole view), mapped back
through GnomonicView.pixel_to_bearing and Equirect.bearing_to_pixel and compared with the true
corners' pixels. (cv2.aruco's own subpixel corners carry a refinement bias of up to ~1–2 px on
such views, so they only check the id and the corner order.)
"""
import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.camera import Equirect, GnomonicView, angle_between, azel_to_bearing
from aruco_abs_orient.synthetic.render import (
    PROFILES,
    PlacedMarker,
    RenderError,
    RenderProfile,
    decode_jpeg,
    encode_jpeg,
    facing_marker,
    render_equirect,
)

_PARAMS = cv2.aruco.DetectorParameters()
_PARAMS.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
_PARAMS.minMarkerPerimeterRate = 0.01
DETECTOR = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), _PARAMS)
BITS_ACROSS = 6  # DICT_4X4: 4 data bits + 2 border bits
VIEW_UPSAMPLE = 3  # gnomonic view pixels per equirect pixel (edge profiles need a few samples per bit)


def _edge_corners(view_img: np.ndarray, rough: np.ndarray) -> np.ndarray:
    """Corners (4, 2) where lines fitted to the mid-level crossings of the four outer edges meet.

    ``rough``: approximate corners (4, 2) in ArUco order; only used to place the edge profiles.
    """
    img = view_img.astype(np.float32)
    centre = rough.mean(axis=0)
    # black and white levels of the marker (its large areas keep them through blur and JPEG)
    mask = np.zeros(img.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(rough).astype(np.int32), 1)
    lo, hi = np.percentile(img[mask > 0], [5, 95])
    mid = 0.5 * (lo + hi)
    bit_px = float(np.mean(np.linalg.norm(rough - np.roll(rough, -1, axis=0), axis=1))) / BITS_ACROSS
    reach = 0.6 * bit_px  # stay inside the black border bit and the white quiet zone
    steps = np.linspace(-reach, reach, max(9, int(6 * reach)))
    lines = []
    for i in range(4):
        a, b = rough[i], rough[(i + 1) % 4]
        t = (b - a) / np.linalg.norm(b - a)
        n = np.array([t[1], -t[0]])
        if np.dot((a + b) / 2 - centre, n) < 0:
            n = -n  # outward
        pts = []
        for f in np.linspace(0.2, 0.8, 25):
            base = a + f * (b - a)
            xy = (base + steps[:, None] * n).astype(np.float32)
            prof = cv2.remap(img, xy[:, :1], xy[:, 1:], cv2.INTER_LINEAR).ravel()
            brighter = prof >= mid
            k = np.nonzero(brighter[:-1] != brighter[1:])[0]
            if len(k) != 1:
                continue  # no clean black→white step here
            k = int(k[0])
            s = steps[k] + (mid - prof[k]) / (prof[k + 1] - prof[k]) * (steps[k + 1] - steps[k])
            pts.append(base + s * n)
        assert len(pts) >= 6, f"edge {i}: only {len(pts)} clean edge crossings"
        pts = np.array(pts)
        c = pts.mean(axis=0)
        direction = np.linalg.svd(pts - c)[2][0]
        lines.append((c, direction))
    corners = []
    for i in range(4):  # corner i joins edge i-1 (from corner i-1) and edge i (to corner i+1)
        (c1, d1), (c2, d2) = lines[(i - 1) % 4], lines[i]
        s = np.linalg.solve(np.array([d1, -d2]).T, c2 - c1)
        corners.append(c1 + s[0] * d1)
    return np.array(corners)


def corner_errors(image: np.ndarray, marker: PlacedMarker):
    """(edge-fit errors, cv2.aruco errors), each (4,) in equirect pixels, of ``marker`` in ``image``."""
    eq = Equirect(image.shape[1], image.shape[0])
    corners = marker.corners()
    half_angle = float(np.max(angle_between(corners, marker.center)))

    def view_around(fov_factor, upsample):
        fov = min(fov_factor * half_angle, 2.5)
        size = int(math.ceil(2.0 * math.tan(fov / 2.0) / eq.rad_per_px * upsample))
        view = GnomonicView.around(eq, marker.center, fov, size=size)
        return view, view.render(image, eq)

    # cv2.aruco's decoding of ~2 px bits is sensitive to the resampling: try a few views
    for fov_factor, upsample in ((4, VIEW_UPSAMPLE), (4, 2), (8, 1), (8, VIEW_UPSAMPLE)):
        view, view_img = view_around(fov_factor, upsample)
        found, ids, _ = DETECTOR.detectMarkers(view_img)
        if ids is not None:
            break
    assert ids is not None and marker.id in ids.ravel(), f"cv2.aruco did not find marker {marker.id}"
    assert ids.size == 1, f"spurious detections: {ids.ravel()}"
    aruco_bearings = view.pixel_to_bearing(found[0][0, :, 0], found[0][0, :, 1])
    fine_view, fine_img = view_around(4, VIEW_UPSAMPLE)
    x, y, _ = fine_view.bearing_to_pixel(aruco_bearings)
    refined = np.stack([x, y], axis=1)
    for _ in range(2):  # the second pass places the profiles on the first pass's edges
        refined = _edge_corners(fine_img, refined)
    edge_bearings = fine_view.pixel_to_bearing(*refined.T)
    u_true, v_true = eq.bearing_to_pixel(corners)

    def errors(bearings):
        u, v = eq.bearing_to_pixel(bearings)
        return np.hypot(eq.unwrap_u(u, u_true) - u_true, v - v_true)

    return errors(edge_bearings), errors(aruco_bearings)


# ---- corners land where camera.py says ---------------------------------------------------------

CASES = [  # (distance m, azimuth deg, elevation deg, width px)
    (1.0, 17.0, 0.0, 1920),
    (1.0, 180.0, 3.0, 1920),  # straddles the ±180° seam
    (1.0, -140.0, 60.0, 1920),
    (1.0, 75.0, -60.0, 1920),
    (3.0, 180.0, 0.0, 3840),
    (5.0, 179.5, -10.0, 3840),
    (10.0, 40.0, 0.0, 3840),
    (10.0, 180.0, 5.0, 3840),
    (10.0, -100.0, 60.0, 3840),
    (10.0, 120.0, -60.0, 3840),
]


@pytest.mark.parametrize("profile", ["clean", "realistic"])
@pytest.mark.parametrize("distance,az_deg,el_deg,width", CASES)
def test_corners_land_where_camera_says(profile, distance, az_deg, el_deg, width):
    centre = distance * azel_to_bearing(math.radians(az_deg), math.radians(el_deg))
    marker = facing_marker(7, 0.19, centre, roll=0.35, tilt=0.25)
    image = render_equirect(width, [marker], profile=profile, seed=3)
    edge_err, aruco_err = corner_errors(image, marker)
    limit = 0.2 if profile == "clean" else 0.5  # blur, noise and JPEG cost ~0.4 px at 10 m (2 px bits)
    assert edge_err.max() <= limit, f"edge-fit corner errors {edge_err.round(3)} px"
    # right id and corner order, cv2.aruco's own corners within its refinement bias
    assert aruco_err.max() <= 2.5, f"cv2.aruco corner errors {aruco_err.round(3)} px"


@st.composite
def placements(draw):
    """A profile and a marker pose; realistic (blur + JPEG) up to 4 m, where a bit is ≥ 3.8 px at
    3840 px and cv2.aruco decodes reliably (beyond that the fixed cases above cover it)."""
    profile = draw(st.sampled_from(["clean", "realistic"]))
    distance = draw(st.floats(1.0, 8.0 if profile == "clean" else 4.0))
    centre = distance * azel_to_bearing(draw(st.floats(-math.pi, math.pi)), draw(st.floats(-1.05, 1.05)))
    marker = facing_marker(draw(st.integers(0, 49)), 0.19, centre, roll=draw(st.floats(-math.pi, math.pi)),
                           tilt=draw(st.floats(-0.6, 0.6)))
    return profile, marker


@settings(max_examples=25)
@given(placements())
def test_corners_property(placement):
    profile, marker = placement
    image = render_equirect(3840, [marker], profile=profile, seed=marker.id)
    edge_err, aruco_err = corner_errors(image, marker)
    assert edge_err.max() <= (0.3 if profile == "clean" else 0.5)
    assert aruco_err.max() <= 2.5  # right corner order; a swap would be ≥ a side (≥ 12 px)


def test_marker_over_the_pole_spans_all_columns_and_is_found():
    marker = facing_marker(11, 0.19, [0.0, 0.0, 0.8], roll=0.7)  # straight above the camera
    image = render_equirect(1920, [marker], profile="clean")
    assert (image[:12] != 128).all()  # the marker (black and white, never grey) covers the top rows
    edge_err, _ = corner_errors(image, marker)
    assert edge_err.max() <= 0.5


def test_two_markers_and_ids_decoded():
    markers = [facing_marker(i, 0.19, 2.0 * azel_to_bearing(a, 0.1)) for i, a in ((3, 0.5), (42, -2.0))]
    image = render_equirect(1920, markers, profile="realistic")
    _, ids, _ = DETECTOR.detectMarkers(image)
    assert sorted(ids.ravel().tolist()) == [3, 42]


# ---- facing_marker geometry --------------------------------------------------------------------

@given(st.floats(0.3, 20.0), st.floats(-math.pi, math.pi), st.floats(-1.2, 1.2))
def test_facing_marker_faces_the_camera_upright(distance, az, el):
    centre = distance * azel_to_bearing(az, el)
    m = facing_marker(0, 0.19, centre)
    R = m.camera_R_marker
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(m.normal, -centre / distance, atol=1e-12)  # z towards the origin
    assert abs(R[:, 0][2]) < 1e-12  # upright: x horizontal, y in the vertical plane
    assert R[:, 1][2] > 0
    c = m.corners()
    np.testing.assert_allclose(np.linalg.norm(c[1] - c[0]), 0.19)
    np.testing.assert_allclose(c.mean(axis=0), centre, atol=1e-12)
    # ArUco order seen from the camera: top-left is higher than bottom-left and further left
    # (larger azimuth, i.e. more counter-clockwise about +z) than top-right (while the marker
    # does not reach over the zenith: |el| ≤ 1.2 rad)
    assert c[0][2] > c[3][2]
    assert np.cross(c[1], c[0])[2] > 0


def test_roll_and_tilt():
    centre = np.array([3.0, 0.0, 0.0])
    m = facing_marker(0, 0.2, centre, roll=math.pi / 2)
    np.testing.assert_allclose(m.camera_R_marker[:, 1], [0.0, 1.0, 0.0], atol=1e-12)  # y now to the left
    m = facing_marker(0, 0.2, centre, tilt=0.3)
    assert angle_between(m.normal, -centre) == pytest.approx(0.3)
    np.testing.assert_allclose(m.camera_R_marker[:, 0], [0.0, -1.0, 0.0], atol=1e-12)  # x unchanged


def test_back_of_marker_shows_no_code():
    m = facing_marker(5, 0.19, [2.0, 0.0, 0.0], tilt=math.pi)  # turned away from the camera
    image = render_equirect(1920, [m], profile="clean")
    _, ids, _ = DETECTOR.detectMarkers(image)
    assert ids is None
    assert image.max() == 255  # the white board is there


# ---- profiles, background, noise, JPEG ---------------------------------------------------------

def test_clean_is_deterministic_and_grey_outside_markers():
    m = facing_marker(1, 0.19, [2.0, 1.0, 0.0])
    a = render_equirect(960, [m], profile="clean")
    b = render_equirect(960, [m], profile="clean", seed=99)
    assert a.shape == (480, 960) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert np.count_nonzero(a != 128) < 0.01 * a.size


def test_background_yaw_rolls_the_panorama():
    flat = RenderProfile(supersample=1, blur_sigma_px=0.0, noise_sigma=0.0, jpeg_quality=None,
                         background="textured")
    base = render_equirect(960, [], profile=flat, seed=5)
    assert base.std() > 10  # textured
    yaw = 10 * 2 * math.pi / 960  # ten pixels of yaw
    rolled = render_equirect(960, [], profile=flat, seed=5, background_yaw=yaw)
    # a background direction at azimuth a appears at a − yaw: 10 px further right
    np.testing.assert_array_equal(rolled, np.roll(base, 10, axis=1))
    assert not np.array_equal(base, render_equirect(960, [], profile=flat, seed=6))


def test_noise_and_jpeg():
    p = PROFILES["realistic"]
    a = render_equirect(960, [], profile="realistic", seed=1, noise_seed=1)
    b = render_equirect(960, [], profile="realistic", seed=1, noise_seed=1)
    c = render_equirect(960, [], profile="realistic", seed=1, noise_seed=2)
    np.testing.assert_array_equal(a, b)
    diff = a.astype(float) - c.astype(float)
    assert 0.3 < diff.std() < 2 * p.noise_sigma  # new noise, same background
    assert abs(diff.mean()) < 0.2
    data = encode_jpeg(a, 85)
    assert data[:2] == b"\xff\xd8"
    back = decode_jpeg(data)
    assert back.shape == a.shape
    assert np.abs(back.astype(float) - a).mean() < 2.0


@pytest.mark.parametrize("kwargs,match", [
    ({"width": 961}, "width"),
    ({"width": 0}, "width"),
    ({"profile": "fancy"}, "profile"),
    ({"dictionary": "DICT_9X9_1"}, "dictionary"),
    ({"markers": [facing_marker(50, 0.19, [2.0, 0.0, 0.0])]}, "id 50"),
    ({"profile": RenderProfile(0, 0.0, 0.0, None, "grey")}, "supersample"),
    ({"profile": RenderProfile(2, 0.0, 0.0, 101, "grey")}, "jpeg_quality"),
    ({"profile": RenderProfile(2, 0.0, 0.0, None, "sky")}, "background"),
])
def test_bad_input_raises_render_error(kwargs, match):
    args = {"width": 960, "markers": []}
    args.update(kwargs)
    with pytest.raises(RenderError, match=match):
        render_equirect(**args)


def test_bad_marker_geometry():
    with pytest.raises(RenderError, match="centre"):
        facing_marker(0, 0.19, [0.0, 0.0, 0.0])
    with pytest.raises(RenderError, match="size"):
        facing_marker(0, -1.0, [1.0, 0.0, 0.0])
    with pytest.raises(RenderError, match="quality"):
        encode_jpeg(np.zeros((8, 16), np.uint8), 0)

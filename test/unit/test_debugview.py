"""debugview: the node's debug image, drawn on a rendered frame with known geometry.

Pixel positions are checked against the doc/design.md §2 formula worked by hand (az = π − 2π(u + 0.5)/W,
el = π/2 − π(v + 0.5)/H), not against camera.py's output.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.camera import azel_to_bearing
from aruco_abs_orient.debugview import (
    COLOURS,
    DebugImageError,
    debug_frame,
    encode_debug_jpeg,
    expected_markers,
    horizon_bearings,
)
from aruco_abs_orient.detection import MarkerDetector, decode_jpeg
from aruco_abs_orient.markers import Marker, MarkerMap
from aruco_abs_orient.pipeline import ObservationResult
from aruco_abs_orient.synthetic.render import facing_marker, render_equirect
from aruco_abs_orient.transforms import make_T, rot_z, rpy_to_matrix


def near(img, u, v, colour, radius=3):
    """Is ``colour`` (BGR, ± 40 per channel) within ``radius`` px of (u, v)?"""
    u, v = int(round(u)), int(round(v))
    patch = img[max(v - radius, 0):v + radius + 1, max(u - radius, 0):u + radius + 1].astype(int)
    return bool(np.any(np.all(np.abs(patch - np.array(colour)) <= 40, axis=-1)))


@pytest.fixture(scope="module")
def scene():
    """A 3840×1920 rendered frame: marker 7 straight ahead 2 m away, marker 3 on the left (az +90°) 3 m
    away, both at the camera's height; the camera level at the map origin, looking along map +x."""
    markers = [facing_marker(7, 0.30, 2.0 * azel_to_bearing(0.0, 0.0)),
               facing_marker(3, 0.30, 3.0 * azel_to_bearing(math.pi / 2, 0.0))]
    image = render_equirect(3840, markers, seed=4)
    found = {o.id: o for o in MarkerDetector("DICT_4X4_50").detect(image)}
    assert set(found) == {3, 7}
    marker_map = MarkerMap([Marker(7, np.array([2.0, 0.0, 0.0]), 0.30, 0.0),
                            Marker(3, np.array([0.0, 3.0, 0.0]), 0.30, 0.0),
                            Marker(5, np.array([0.0, -4.0, 1.0]), 0.30, 0.0)])  # not in the frame
    results = [ObservationResult(found[7], accepted=True),
               ObservationResult(found[3], accepted=False, reason="elevation disagrees with the map")]
    return image, results, marker_map


def test_the_frame_is_downscaled_to_1920_and_the_markers_outlined(scene):
    image, results, marker_map = scene
    out = debug_frame(image, results, marker_map, np.eye(4))
    assert out.shape == (960, 1920, 3) and out.dtype == np.uint8
    # marker 7 at az 0, el 0 → u = W/2 − 0.5 = 959.5, v = H/2 − 0.5 = 479.5; 0.30 m at 2 m spans
    # 2·atan(0.075) = 8.58° = 45.8 px at 1920: its outline is 22.9 px left/right of the centre
    half = 1920 * math.atan(0.15 / 2.0) / (2 * math.pi)
    assert near(out, 959.5 - half, 479.5, COLOURS["accepted"]) and near(out, 959.5 + half, 479.5, COLOURS["accepted"])
    assert not near(out, 959.5, 479.5 - 2 * half, COLOURS["accepted"])  # the outline, not a filled area
    # marker 3 at az +90° → u = 1920·(0.5 − 0.25) − 0.5 = 479.5, rejected: red outline
    half3 = 1920 * math.atan(0.15 / 3.0) / (2 * math.pi)
    assert near(out, 479.5 - half3, 479.5, COLOURS["rejected"]) and not near(out, 479.5 - half3, 479.5,
                                                                              COLOURS["accepted"], 1)


def test_predicted_positions_of_every_map_marker(scene):
    image, results, marker_map = scene
    out = debug_frame(image, results, marker_map, np.eye(4))
    # marker 5 at (0, −4, 1) from the camera: az −90°, el atan(1/4) = 14.04°
    # → u = 1920·(0.5 + 0.25) − 0.5 = 1439.5, v = 960·(0.5 − 14.04/180) − 0.5 = 404.6; circle radius 12 px
    el = math.atan2(1.0, 4.0)
    u, v = 1439.5, 960 * (0.5 - el / math.pi) - 0.5
    assert near(out, u + 12, v, COLOURS["predicted"], 2) and near(out, u, v - 12, COLOURS["predicted"], 2)
    assert not near(out, u, v, COLOURS["predicted"], 4)  # a ring around it
    no_pose = debug_frame(image, results, marker_map, None)
    assert not near(no_pose, u + 12, v, COLOURS["predicted"], 2)  # nothing predicted without a pose


def test_seam_and_horizon(scene):
    image, results, marker_map = scene
    level = debug_frame(image, [], marker_map, np.eye(4))
    assert near(level, 0, 200, COLOURS["seam"], 8) and near(level, 1919, 200, COLOURS["seam"], 8)
    assert near(level, 1500, 479.5, COLOURS["horizon"], 2)  # el 0 → v = 479.5
    # camera pitched 10° (REP-103: nose down): map's horizon straight ahead appears at el +10°:
    # v = 960·(0.5 − 10/180) − 0.5 = 426.2; behind (u = 0) at el −10°: v = 532.8; at the sides still 479.5
    pitched = debug_frame(image, [], marker_map, make_T(rpy_to_matrix(0.0, math.radians(10.0), 0.0), np.zeros(3)))
    assert near(pitched, 959.5, 426.2, COLOURS["horizon"], 2) and not near(pitched, 959.5, 479.5,
                                                                           COLOURS["horizon"], 2)
    assert near(pitched, 10, 532.8, COLOURS["horizon"], 3)
    assert near(pitched, 479.5, 479.5, COLOURS["horizon"], 2)


@settings(max_examples=30, deadline=None)
@given(roll=st.floats(-0.5, 0.5), pitch=st.floats(-0.5, 0.5), yaw=st.floats(-math.pi, math.pi))
def test_horizon_bearings_are_level_in_map(roll, pitch, yaw):
    R = rpy_to_matrix(roll, pitch, yaw)
    b = horizon_bearings(R, n=37)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose((b @ R.T)[:, 2], 0.0, atol=1e-12)  # map z of each bearing


def test_small_frames_stay_and_bad_frames_are_refused(scene):
    image, results, _ = scene
    small = image[::4, ::4]
    assert debug_frame(small, results).shape == (480, 960, 3)
    with pytest.raises(DebugImageError, match="2:1"):
        debug_frame(image[:, :100], results)
    jpeg = encode_debug_jpeg(debug_frame(small, results))
    assert decode_jpeg(jpeg).shape == (480, 960)


def test_expected_markers_say_why_each_one_was_not_found_or_not_used(scene):
    """The scene's map and five more markers, the camera at the origin: each status against what was made
    true by hand (found and used; found, rejected; found by the frame search only; found 2° off the map's
    position; facing away; seen edge-on; too small; in view, unseen), and the pixel of marker 5 worked from
    the doc/design.md §2 formula."""
    image, results, marker_map = scene
    found = {o.observation.id: o.observation.centre for o in results}           # 7 and 3, detected in the frame
    extra = [Marker(9, np.array([80.0, 0.0, 0.0]), 0.30, 0.0),                  # 0.3 m at 80 m: 2.3 px at 3840
             Marker(11, np.array([-3.0, 0.0, 0.0]), 0.30, 0.0, np.array([-1.0, 0.0, 0.0])),   # its back to us
             Marker(12, np.array([0.0, -3.0, 0.0]), 0.30, 0.0,                  # turned 80° from the view
                    np.array([math.sin(math.radians(80.0)), math.cos(math.radians(80.0)), 0.0])),
             Marker(13, np.array([0.0, 2.0, 2.0]), 0.30, 0.0),                   # found by a search, not used
             Marker(14, np.array([2.0, -2.0, 0.0]), 0.30, 0.0)]                  # found 2° from the map's position
    full = MarkerMap(list(marker_map) + extra)
    found.update({13: np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0),
                  14: rot_z(math.radians(2.0)) @ np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)})
    used = {7: "", 3: "elevation disagrees with the map (wrong id or moved marker)",
            14: "tracking gate: far from its predicted bearing (moved marker, or the filter is off)"}
    out = {e.id: e for e in expected_markers(full, np.eye(4), 3840, found, used)}
    assert {k: e.status for k, e in out.items()} == {
        7: "found", 3: "found, rejected: elevation disagrees with the map",
        13: "found here, missed by the tracker (outside its window)",
        14: "found 2.0° off the map's position, rejected: tracking gate",
        11: "faces away", 12: "seen edge-on (80°)", 9: "too small to find (2 px)",
        5: "not found: hidden or blurred"}
    el = math.atan2(1.0, 4.0)                                   # marker 5: az −90°, el 14.04°
    assert (out[5].u, out[5].v) == pytest.approx((3840 * 0.75 - 0.5, 1920 * (0.5 - el / math.pi) - 0.5), abs=1e-6)
    assert out[5].range == pytest.approx(math.sqrt(17.0))
    assert out[9].side_px == pytest.approx(2 * math.atan(0.15 / 80.0) / (2 * math.pi / 3840))
    assert [e.id for e in expected_markers(full, np.eye(4), 3840, found, used)][:2] == [7, 13]   # nearest first

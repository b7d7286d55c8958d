"""ROS message ⇄ numpy conversions of the abs_orient node (ros/conversions.py).

Independent truth: tf2's own C++ BufferCore composes and inverts the transforms we write; cv_bridge
and cv2 encode the images we read; genpy serialises the messages we build. Needs the catkin workspace
(the package's generated messages): run with tools/env.sh sourced, as `make test` does.
"""
import math

import cv2
import numpy as np
import pytest
import rospy
import tf2_ros
from cv_bridge import CvBridge
from geometry_msgs.msg import PointStamped, Transform
from hypothesis import given
from hypothesis import strategies as st
from std_msgs.msg import Header

from aruco_abs_orient.camera import Equirect, azel_to_bearing
from aruco_abs_orient.detection import MarkerObservation
from aruco_abs_orient.errors import ConfigurationError
from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.msg import MarkerObservations
from aruco_abs_orient.pipeline import FrameResult, ObservationResult
from aruco_abs_orient.ros import conversions as cv
from aruco_abs_orient.transforms import invert_T, make_T, matrix_to_rpy, rpy_to_matrix

angles = st.floats(-math.pi, math.pi, allow_nan=False)
small_angles = st.floats(-1.4, 1.4, allow_nan=False)
coords = st.floats(-100.0, 100.0, allow_nan=False)
poses = st.builds(lambda r, p, y, x, yy, z: make_T(rpy_to_matrix(r, p, y), [x, yy, z]),
                  angles, small_angles, angles, coords, coords, coords)


def _buffer():
    return tf2_ros.Buffer(debug=False)


@given(poses, poses, st.floats(0.0, 2e9, allow_nan=False))
def test_tf2_composes_and_inverts_our_transforms(a_T_b, b_T_c, t):
    stamp = cv.sec_to_stamp(t)
    buf = _buffer()
    buf.set_transform(cv.matrix_to_transform_stamped(a_T_b, stamp, "a", "b"), "test")
    buf.set_transform(cv.matrix_to_transform_stamped(b_T_c, stamp, "b", "c"), "test")
    a_T_c = cv.transform_to_matrix(buf.lookup_transform("a", "c", stamp).transform)
    np.testing.assert_allclose(a_T_c, a_T_b @ b_T_c, atol=1e-9 * (1 + np.abs(a_T_b @ b_T_c).max()))
    c_T_a = cv.transform_to_matrix(buf.lookup_transform("c", "a", stamp).transform)
    np.testing.assert_allclose(c_T_a, invert_T(a_T_b @ b_T_c), atol=1e-8 * (1 + np.abs(a_T_c).max()))


@given(st.integers(0, 2**32 - 1), st.integers(0, 999_999_999))
def test_stamp_seconds_round_trip_to_the_nanosecond(secs, nsecs):
    t = cv.stamp_to_sec(rospy.Time(secs, nsecs))
    back = cv.sec_to_stamp(t)
    # a float64 holds ~16 digits: 4e9 s keeps ~0.5 µs; the round trip stays within that
    assert abs((back - rospy.Time(secs, nsecs)).to_sec()) <= 1e-6


@pytest.mark.parametrize("field,value", [("translation", float("nan")), ("rotation", float("inf"))])
def test_transform_with_nan_is_refused_naming_the_field(field, value):
    tr = Transform()
    tr.rotation.w = 1.0
    if field == "translation":
        tr.translation.y = value
    else:
        tr.rotation.x = value
    with pytest.raises(cv.ConversionError, match=f"odom->base_link.{field}: NaN or inf"):
        cv.transform_to_matrix(tr, "odom->base_link")


def test_zero_quaternion_is_refused():
    with pytest.raises(cv.ConversionError, match="zero quaternion"):
        cv.transform_to_matrix(Transform())


def test_point_stamped_checks_frame_and_values():
    msg = PointStamped(header=Header(stamp=rospy.Time(12, 500_000_000), frame_id="map"))
    msg.point.x, msg.point.y, msg.point.z = 1.0, -2.0, 0.5
    t, p = cv.point_stamped_to_array(msg, "map")
    assert t == 12.5 and p.tolist() == [1.0, -2.0, 0.5]
    msg.header.frame_id = "odom"
    with pytest.raises(cv.ConversionError, match="frame_id: expected 'map', got 'odom'"):
        cv.point_stamped_to_array(msg, "map")
    msg.header.frame_id = "map"
    msg.point.z = float("nan")
    with pytest.raises(cv.ConversionError, match="point: NaN"):
        cv.point_stamped_to_array(msg, "map")


@pytest.mark.parametrize("encoding", ["mono8", "bgr8", "rgb8", "bgra8", "mono16"])
def test_raw_image_matches_what_cv_bridge_encoded(encoding):
    rng = np.random.default_rng(3)
    h, w = 48, 96
    if encoding.startswith("mono16"):
        img = rng.integers(0, 65535, (h, w), dtype=np.uint16)
        expected = (img / 257.0).round().astype(np.uint8)  # cv_bridge's 16 → 8 bit scaling
    elif encoding == "mono8":
        img = expected = rng.integers(0, 255, (h, w), dtype=np.uint8)
    else:
        img = rng.integers(0, 255, (h, w, len(encoding) - 1 if encoding.endswith("a8") else 3), dtype=np.uint8)
        code = {"bgr8": None, "rgb8": cv2.COLOR_RGB2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY}[encoding]
        expected = img if code is None else cv2.cvtColor(img, code)
    msg = CvBridge().cv2_to_imgmsg(img, encoding)
    out = cv.image_from_raw(msg)
    assert out.dtype == np.uint8 and out.shape == expected.shape
    np.testing.assert_allclose(out.astype(int), expected.astype(int), atol=1)


def test_raw_image_with_row_padding_and_truncated_data():
    img = np.arange(6 * 10, dtype=np.uint8).reshape(6, 10)
    padded = np.zeros((6, 16), np.uint8)
    padded[:, :10] = img
    msg = CvBridge().cv2_to_imgmsg(padded, "mono8")
    msg.width, msg.step = 10, 16
    np.testing.assert_array_equal(cv.image_from_raw(msg), img)
    msg.data = msg.data[:50]
    with pytest.raises(cv.ConversionError, match="image.data: 50 bytes"):
        cv.image_from_raw(msg)
    msg.encoding = "32FC7"
    msg.height = 0
    with pytest.raises(cv.ConversionError, match="empty"):
        cv.image_from_raw(msg)


def test_compressed_image_bytes_decode_to_the_image():
    img = np.tile(np.arange(64, dtype=np.uint8) * 4, (32, 1))
    ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    msg = CvBridge().cv2_to_compressed_imgmsg(img, "jpg")
    data = cv.image_from_compressed(msg)
    assert data == jpg.tobytes()
    assert np.abs(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE).astype(int) - img).max() <= 3
    msg.data = b""
    with pytest.raises(cv.ConversionError, match="empty compressed image"):
        cv.image_from_compressed(msg)


def test_pose_covariance_layout():
    P = np.array([[4e-6, 1e-6, 0], [1e-6, 9e-6, 0], [0, 0, 1e-5]])
    C = np.array(cv.pose_covariance(position_cov=P, yaw_variance=2.5e-5)).reshape(6, 6)
    np.testing.assert_array_equal(C[:3, :3], P)
    assert C[5, 5] == 2.5e-5 and C[3, 3] == C[4, 4] == cv.UNOBSERVED_VARIANCE
    assert np.count_nonzero(C[:3, 3:]) == 0 and np.count_nonzero(C[3:5, 3:5] - np.diag([1e6, 1e6])) == 0
    A = np.diag([1e-4, 2e-4, 3e-4])
    C = np.array(cv.pose_covariance(attitude_cov=A, yaw_variance=9.0)).reshape(6, 6)
    np.testing.assert_array_equal(C[3:, 3:], A)  # full attitude wins over the yaw-only variance
    assert np.all(np.diag(C)[:3] == cv.UNOBSERVED_VARIANCE)
    with pytest.raises(cv.ConversionError, match="negative variance"):
        cv.pose_covariance(yaw_variance=-1.0)
    with pytest.raises(cv.ConversionError, match="position covariance: NaN"):
        cv.pose_covariance(position_cov=np.full((3, 3), np.nan))


def _result(**kw):
    """A FrameResult of the pipeline with the given fields."""
    return FrameResult(stamp=kw.pop("stamp", 0.0), **kw)


def _observation(marker_id, az, el, yaw=float("nan"), yaw_sigma=float("nan"), accepted=False, **kw):
    """A detection at (az, el) as the pipeline returns it (pixel from camera.py's equirect model)."""
    eq = Equirect(960, 480)
    centre = azel_to_bearing(az, el)
    obs = MarkerObservation(id=marker_id, corners=np.tile(centre, (4, 1)), centre=centre,
                            pixel=tuple(float(x) for x in eq.bearing_to_pixel(centre)),
                            corners_px=np.zeros((4, 2)), angular_size=0.02, sigma=3e-4, method="tracked")
    return ObservationResult(obs, yaw=yaw, yaw_sigma=yaw_sigma, accepted=accepted, **kw)


@given(small_angles, small_angles, angles, angles, st.floats(1e-4, 0.1))
def test_orientation_takes_tilt_from_odometry_and_yaw_from_markers(roll, pitch, odom_yaw, yaw, sigma):
    odom_T_base = make_T(rpy_to_matrix(roll * 0.2, pitch * 0.2, odom_yaw), [1.0, 2.0, 0.0])
    msg = cv.orientation_msg(yaw, sigma, odom_T_base, rospy.Time(5), "map")
    q = msg.pose.pose.orientation
    buf = _buffer()  # read the quaternion back through tf2 rather than our own quaternion maths
    tr = cv.matrix_to_transform_stamped(np.eye(4), rospy.Time(5), "map", "base")
    tr.transform.rotation = q
    buf.set_transform(tr, "test")
    R = cv.transform_to_matrix(buf.lookup_transform("map", "base", rospy.Time(5)).transform)[:3, :3]
    r2, p2, y2 = matrix_to_rpy(R)
    assert abs(r2 - roll * 0.2) < 1e-9 and abs(p2 - pitch * 0.2) < 1e-9
    assert abs(math.remainder(y2 - yaw, 2 * math.pi)) < 1e-9
    C = np.array(msg.pose.covariance).reshape(6, 6)
    assert math.isclose(C[5, 5], sigma**2) and C[0, 0] == C[3, 3] == cv.UNOBSERVED_VARIANCE
    assert msg.header.frame_id == "map" and msg.header.stamp == rospy.Time(5)


def test_prism_and_pose_messages_follow_the_result():
    T = make_T(rpy_to_matrix(0.01, -0.02, 1.2), [3.0, -4.0, 0.3])
    P = np.diag([2.5e-5, 2.5e-5, 4e-5])
    r = _result(yaw=1.2, yaw_sigma=0.002, map_T_base=T, base_position_cov=P, initialised=True)
    p = cv.prism_pose_msg(r, rospy.Time(1))
    assert [p.pose.pose.position.x, p.pose.pose.position.y, p.pose.pose.position.z] == [3.0, -4.0, 0.3]
    C = np.array(p.pose.covariance).reshape(6, 6)
    np.testing.assert_array_equal(C[:3, :3], P)
    assert np.all(np.diag(C)[3:] == cv.UNOBSERVED_VARIANCE)
    s = cv.pose_msg(r, rospy.Time(1))
    assert s.pose == p.pose.pose
    empty = _result()
    assert cv.prism_pose_msg(empty, rospy.Time(1)) is None and cv.pose_msg(empty, rospy.Time(1)) is None


def test_observations_message_serialises_with_nan_for_unknowns():
    from io import BytesIO

    obs = [_observation(7, 0.927, 0.2, yaw=0.5, yaw_sigma=0.003, accepted=True, range=4.2, residual=-0.001),
           _observation(3, -2.0, 1.2)]
    msg = cv.observations_msg(obs, rospy.Time(7, 1), "camera")
    buf = BytesIO()
    msg.serialize(buf)
    back = MarkerObservations().deserialize(buf.getvalue())
    assert back.header.frame_id == "camera" and back.header.stamp == rospy.Time(7, 1)
    a, b = back.observations
    assert (a.id, a.method, a.accepted, a.range, a.yaw, a.residual) == (7, "tracked", True, 4.2, 0.5, -0.001)
    assert abs(a.azimuth - 0.927) < 1e-12 and abs(a.elevation - 0.2) < 1e-12
    np.testing.assert_allclose([a.bearing.x, a.bearing.y, a.bearing.z], azel_to_bearing(0.927, 0.2), atol=1e-12)
    # the pixel is camera.py's: back through its model to the same bearing
    np.testing.assert_allclose(Equirect(960, 480).pixel_to_bearing(a.pixel_u, a.pixel_v), azel_to_bearing(0.927, 0.2),
                               atol=1e-9)
    assert b.id == 3 and not b.accepted and all(math.isnan(x) for x in (b.range, b.yaw, b.yaw_sigma, b.residual))


def test_marker_array_places_every_marker_of_the_example_map(request):
    mm = MarkerMap.load(str(request.config.rootpath / "cfg" / "markers_example.yaml"))
    arr = cv.marker_array(mm, rospy.Time(0), seen_ids=[7])
    assert len(arr.markers) == 2 * len(mm)
    ids = [m.id for m in arr.markers]
    assert len(set(ids)) == len(ids)
    cubes = {m.id // 2: m for m in arr.markers if m.type == m.CUBE}
    for m in mm:
        c = cubes[m.id]
        assert [c.pose.position.x, c.pose.position.y, c.pose.position.z] == m.position.tolist()
        assert c.scale.x == m.size and c.header.frame_id == "map"
        assert (c.color.g > 0.8 and c.color.r < 0.5) == (m.id == 7)
    texts = [m.text for m in arr.markers if m.type == m.TEXT_VIEW_FACING]
    assert sorted(texts) == sorted(str(i) for i in mm.ids)


def test_diagnostic_status_levels_and_values():
    from diagnostic_updater import DiagnosticStatusWrapper

    wrapper = DiagnosticStatusWrapper(name="pipeline")  # what a diagnostic_updater task fills
    s = cv.fill_diagnostic(wrapper, "warn", "no prism for 31 s",
                           {"markers seen": 2, "prism age [s]": 31.04, "offset": float("nan")})
    assert s is wrapper and s.level == s.WARN and s.message == "no prism for 31 s" and s.name == "pipeline"
    assert [(kv.key, kv.value) for kv in s.values] == [("markers seen", "2"), ("prism age [s]", "31.04"),
                                                        ("offset", "nan")]
    with pytest.raises(ConfigurationError, match="diagnostic level 'bad'"):
        cv.fill_diagnostic(wrapper, "bad", "", {})


def test_bearing_rays_run_from_the_camera_to_each_accepted_marker():
    """A marker at az +90°, el 30°, 4 m away: its ray ends at 4·(cos 30° cos 90°, cos 30° sin 90°, sin 30°)
    = (0, 3.464, 2.0) m in the camera frame; a rejected marker gets no ray; no range: 3 m."""
    rays = cv.rays_marker_array([_observation(3, math.pi / 2, math.pi / 6, 0.0, 0.01, True, range=4.0),
                                 _observation(8, 0.0, 0.0, 0.0, 0.01, False),
                                 _observation(5, math.pi, 0.0, 0.0, 0.01, True)], rospy.Time(7), "cam")
    lines, *texts = rays.markers
    assert lines.type == lines.LINE_LIST and lines.header.frame_id == "cam" and lines.header.stamp == rospy.Time(7)
    ends = [(p.x, p.y, p.z) for p in lines.points]
    np.testing.assert_allclose(ends, [(0, 0, 0), (0, 4 * math.cos(math.pi / 6), 2.0), (0, 0, 0), (-3.0, 0, 0)],
                               atol=1e-9)
    assert [t.text for t in texts] == ["3", "5"]
    empty = cv.rays_marker_array([_observation(8, 0.0, 0.0, 0.0, 0.01, False)], rospy.Time(8), "cam")
    assert [m.action for m in empty.markers] == [empty.markers[0].DELETEALL]


def test_prism_with_covariance_and_the_corrected_odometry():
    """ms60/prism_with_covariance → (stamp, position, 3×3 covariance), refused in another frame or with a variance
    that is not positive; abs_orient/odometry: the pose, the yaw's variance absolute, step σs on the rest."""
    from geometry_msgs.msg import PoseWithCovarianceStamped

    from aruco_abs_orient.ros.conversions import corrected_odometry_msg, prism_with_covariance

    msg = PoseWithCovarianceStamped()
    msg.header.frame_id, msg.header.stamp = "map", rospy.Time(12, 500000000)
    msg.pose.pose.position.x, msg.pose.pose.position.y = 3.0, 4.0
    cov = np.diag([4e-6, 9e-6, 1e-6])
    C = np.diag([0.0] * 3 + [1e6] * 3)
    C[:3, :3] = cov
    msg.pose.covariance = C.ravel().tolist()
    t, p, c = prism_with_covariance(msg, "map")
    assert t == 12.5 and np.allclose(p, [3, 4, 0]) and np.array_equal(c, cov)
    with pytest.raises(cv.ConversionError, match="frame_id"):
        prism_with_covariance(msg, "odom")
    msg.pose.covariance[0] = 0.0
    with pytest.raises(cv.ConversionError, match="not all positive"):
        prism_with_covariance(msg, "map")
    T = make_T(rpy_to_matrix(0.01, -0.02, 1.2), [1.0, 2.0, 0.3])
    odom = corrected_odometry_msg(T, 1e-8, rospy.Time(5), "map", "base_link")
    assert odom.header.frame_id == "map" and odom.child_frame_id == "base_link"
    P = np.array(odom.pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(np.diag(P), [0.005**2] * 3 + [0.002**2] * 2 + [1e-8])
    q = odom.pose.pose.orientation
    np.testing.assert_allclose(cv.quat_to_matrix([q.x, q.y, q.z, q.w]), T[:3, :3], atol=1e-12)
    assert np.all(np.diag(np.array(odom.twist.covariance).reshape(6, 6)) == 1e6)

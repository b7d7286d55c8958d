"""ROS message ⇄ numpy conversions for the abs_orient node (the node's only message code).

Everything here is a pure function of its arguments: no node, no master, no tf listener, so it is
unit-tested directly (``test/unit/ros/test_conversions.py``). Units: metres, radians, seconds;
covariances in m² / rad². Transforms named ``a_T_b`` are 4×4 matrices mapping b-coordinates into a.

Covariance layout of ``PoseWithCovarianceStamped`` (REP-103): row-major 6×6 over
``(x, y, z, roll, pitch, yaw)``, rotations about the fixed X, Y, Z axes — the same roll/pitch/yaw as
``transforms.rpy_to_matrix``. Parts a message does not measure get :data:`UNOBSERVED_VARIANCE` on the
diagonal (and zero correlation); robot_localization's ``*_config`` masks (``cfg/ekf.yaml``) are what
actually keep them out of the filter.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping, Optional, Sequence, Tuple

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseStamped,
    PoseWithCovarianceStamped,
    Quaternion,
    Transform,
    TransformStamped,
    Vector3,
)
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker as VizMarker
from visualization_msgs.msg import MarkerArray

from ..errors import ConfigurationError, InputFileError
from ..markers import MarkerMap
from ..msg import MarkerObservation, MarkerObservations
from ..transforms import make_T, matrix_to_quat, matrix_to_rpy, quat_to_matrix, rpy_to_matrix

__all__ = [
    "ConversionError",
    "UNOBSERVED_VARIANCE",
    "stamp_to_sec",
    "sec_to_stamp",
    "transform_to_matrix",
    "matrix_to_transform_stamped",
    "matrix_to_pose",
    "point_stamped_to_array",
    "prism_with_covariance",
    "image_from_compressed",
    "image_from_raw",
    "pose_covariance",
    "orientation_msg",
    "prism_pose_msg",
    "pose_msg",
    "corrected_odometry_msg",
    "observations_msg",
    "marker_array",
    "rays_marker_array",
    "compressed_image",
    "bgr_image",
    "fill_diagnostic",
]

UNOBSERVED_VARIANCE = 1.0e6
"""Variance (m² or rad²) written for the parts of a pose a message does not measure."""


class ConversionError(InputFileError):
    """A message that cannot be turned into numbers: the text names the message field."""


def stamp_to_sec(stamp) -> float:
    """A ``rospy.Time``/``genpy.Time`` as float seconds."""
    return stamp.secs + 1e-9 * stamp.nsecs


def sec_to_stamp(t: float) -> rospy.Time:
    """Float seconds (≥ 0) as ``rospy.Time`` (rounded to the nanosecond)."""
    ns = int(round(float(t) * 1e9))
    return rospy.Time(ns // 1_000_000_000, ns % 1_000_000_000)


def _finite(values: Sequence[float], what: str) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ConversionError(f"{what}: NaN or inf in {a.tolist()}")
    return a


def transform_to_matrix(transform: Transform, what: str = "transform") -> np.ndarray:
    """``geometry_msgs/Transform`` → 4×4 ``parent_T_child``. Raises ConversionError for NaN/inf or a
    zero quaternion (``what`` names the transform in the message)."""
    t = _finite([transform.translation.x, transform.translation.y, transform.translation.z],
                what + ".translation")
    q = _finite([transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w],
                what + ".rotation")
    if np.linalg.norm(q) < 1e-6:
        raise ConversionError(f"{what}.rotation: zero quaternion")
    return make_T(quat_to_matrix(q), t)


def _quaternion(R: np.ndarray) -> Quaternion:
    q = matrix_to_quat(R)
    return Quaternion(float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def matrix_to_transform_stamped(a_T_b: np.ndarray, stamp: rospy.Time, parent: str, child: str) -> TransformStamped:
    """4×4 ``parent_T_child`` → ``TransformStamped`` (header.frame_id = parent)."""
    T = np.asarray(a_T_b, dtype=float)
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = parent
    msg.child_frame_id = child
    msg.transform.translation = Vector3(*(float(x) for x in T[:3, 3]))
    msg.transform.rotation = _quaternion(T[:3, :3])
    return msg


def matrix_to_pose(a_T_b: np.ndarray) -> Pose:
    """4×4 ``frame_T_body`` → ``geometry_msgs/Pose`` of the body in the frame."""
    T = np.asarray(a_T_b, dtype=float)
    return Pose(Point(*(float(x) for x in T[:3, 3])), _quaternion(T[:3, :3]))


def point_stamped_to_array(msg, expected_frame: str) -> Tuple[float, np.ndarray]:
    """``geometry_msgs/PointStamped`` → (stamp in s, point (3,) in m). Raises ConversionError when the
    frame is not ``expected_frame`` or a coordinate is NaN/inf."""
    if msg.header.frame_id.lstrip("/") != expected_frame.lstrip("/"):
        raise ConversionError(f"point.header.frame_id: expected {expected_frame!r}, got {msg.header.frame_id!r}")
    p = _finite([msg.point.x, msg.point.y, msg.point.z], "point")
    return stamp_to_sec(msg.header.stamp), p


def prism_with_covariance(msg, expected_frame: str) -> Tuple[float, np.ndarray, np.ndarray]:
    """``ms60/prism_with_covariance`` (``PoseWithCovarianceStamped``) → (stamp s, position (3,) m, covariance 3×3
    m²). Raises ConversionError for another frame, NaN/inf or a position variance that is not positive."""
    if msg.header.frame_id.lstrip("/") != expected_frame.lstrip("/"):
        raise ConversionError(f"prism.header.frame_id: expected {expected_frame!r}, got {msg.header.frame_id!r}")
    p = msg.pose.pose.position
    xyz = _finite([p.x, p.y, p.z], "prism position")
    cov = _finite(msg.pose.covariance, "prism covariance").reshape(6, 6)[:3, :3]
    if np.any(np.diag(cov) <= 0):
        raise ConversionError(f"prism covariance: position variances {np.diag(cov).tolist()} are not all positive")
    return stamp_to_sec(msg.header.stamp), xyz, cov


def image_from_compressed(msg) -> bytes:
    """``sensor_msgs/CompressedImage`` → its encoded bytes (JPEG/PNG; the pipeline decodes them).
    Raises ConversionError for an empty message."""
    data = bytes(msg.data)
    if not data:
        raise ConversionError("image.data: empty compressed image")
    return data


_RAW_DTYPES = {"mono8": 1, "8UC1": 1, "bgr8": 3, "8UC3": 3}


def image_from_raw(msg) -> np.ndarray:
    """``sensor_msgs/Image`` → uint8 grey (H, W) or BGR (H, W, 3) array (a view of the data when it
    is mono8/bgr8; other encodings go through cv_bridge to mono8). Raises ConversionError."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0:
        raise ConversionError(f"image: empty {w}x{h} image")
    channels = _RAW_DTYPES.get(msg.encoding)
    if channels is not None:
        if step < w * channels or len(msg.data) < h * step:
            raise ConversionError(f"image.data: {len(msg.data)} bytes, {w}x{h} {msg.encoding} with step {step} "
                                  f"needs {h * step}")
        a = np.frombuffer(msg.data, dtype=np.uint8, count=h * step).reshape(h, step)[:, :w * channels]
        return a if channels == 1 else a.reshape(h, w, 3)
    from cv_bridge import CvBridge, CvBridgeError

    try:
        return CvBridge().imgmsg_to_cv2(msg, "mono8")
    except (CvBridgeError, TypeError, ValueError) as e:
        raise ConversionError(f"image.encoding {msg.encoding!r}: cannot convert to mono8: {e}") from None


def pose_covariance(position_cov: Optional[np.ndarray] = None,
                    attitude_cov: Optional[np.ndarray] = None,
                    yaw_variance: Optional[float] = None) -> list:
    """Row-major 6×6 covariance over (x, y, z, roll, pitch, yaw) as the 36 floats of a ROS message.

    ``position_cov`` 3×3 m², ``attitude_cov`` 3×3 rad² over (roll, pitch, yaw); when only the yaw is
    known give ``yaw_variance`` (rad²) instead. Missing blocks get :data:`UNOBSERVED_VARIANCE`.
    NaN/inf or a negative variance raises ConversionError.
    """
    C = np.diag([UNOBSERVED_VARIANCE] * 6)
    if position_cov is not None:
        C[:3, :3] = _finite(position_cov, "position covariance").reshape(3, 3)
    if attitude_cov is not None:
        C[3:, 3:] = _finite(attitude_cov, "attitude covariance").reshape(3, 3)
    elif yaw_variance is not None:
        C[5, 5] = float(_finite([yaw_variance], "yaw variance")[0])
    if np.any(np.diag(C) < 0):
        raise ConversionError(f"covariance: negative variance on the diagonal {np.diag(C).tolist()}")
    C = 0.5 * (C + C.T)
    return [float(x) for x in C.ravel()]


def _header(stamp: rospy.Time, frame_id: str) -> Header:
    return Header(stamp=stamp, frame_id=frame_id)


def orientation_msg(yaw: float, yaw_sigma: float, odom_T_base: np.ndarray, stamp: rospy.Time,
                    frame_id: str = "map") -> PoseWithCovarianceStamped:
    """Absolute yaw of base_link in ``frame_id`` (rad, 1-σ rad) as a pose with covariance.

    Roll and pitch are the odometry's (``odom_T_base``; map→odom turns about z only) and are not
    measured: their variance, like the position's, is UNOBSERVED_VARIANCE; the position is zero.
    """
    roll, pitch, _ = matrix_to_rpy(np.asarray(odom_T_base, dtype=float)[:3, :3])
    msg = PoseWithCovarianceStamped()
    msg.header = _header(stamp, frame_id)
    msg.pose.pose = matrix_to_pose(make_T(rpy_to_matrix(roll, pitch, yaw), np.zeros(3)))
    msg.pose.covariance = pose_covariance(yaw_variance=float(yaw_sigma) ** 2)
    return msg


def prism_pose_msg(result, stamp: rospy.Time, frame_id: str = "map") -> Optional[PoseWithCovarianceStamped]:
    """Position of base_link in ``frame_id`` from the prism (lever arm removed), or None when the frame
    had no prism position. Covariance: ``result.base_position_cov`` on (x, y, z), attitude unobserved."""
    if result.base_position_cov is None or result.map_T_base is None:
        return None
    msg = PoseWithCovarianceStamped()
    msg.header = _header(stamp, frame_id)
    msg.pose.pose = matrix_to_pose(result.map_T_base)
    msg.pose.covariance = pose_covariance(position_cov=result.base_position_cov)
    return msg


def pose_with_covariance_msg(map_T_base: np.ndarray, cov: np.ndarray, stamp: rospy.Time,
                             frame_id: str = "map") -> PoseWithCovarianceStamped:
    """A pose (4×4) with its full 6×6 covariance over (x, y, z, roll, pitch, yaw) (m², rad²), e.g. a resection."""
    msg = PoseWithCovarianceStamped()
    msg.header = _header(stamp, frame_id)
    msg.pose.pose = matrix_to_pose(map_T_base)
    C = _finite(cov, "pose covariance").reshape(6, 6)
    msg.pose.covariance = [float(x) for x in (0.5 * (C + C.T)).ravel()]
    return msg


def pose_msg(result, stamp: rospy.Time, frame_id: str = "map") -> Optional[PoseStamped]:
    """The corrected pose ``map_T_base`` of the frame, or None before initialisation."""
    if result.map_T_base is None:
        return None
    return PoseStamped(header=_header(stamp, frame_id), pose=matrix_to_pose(result.map_T_base))


def corrected_odometry_msg(map_T_base: np.ndarray, yaw_variance: float, stamp: rospy.Time, frame_id: str = "map",
                           child_frame_id: str = "base_link", step_sigmas: Tuple[float, float] = (0.005, 0.002)
                           ):
    """``nav_msgs/Odometry`` of base_link in ``frame_id``: the pose ``map_T_base`` (4×4); the yaw's variance
    ``yaw_variance`` (rad², absolute), position and roll/pitch with ``step_sigmas`` (m, rad: what one pose is worth
    relative to the previous one, for a differential input); the twist UNOBSERVED_VARIANCE."""
    from nav_msgs.msg import Odometry

    msg = Odometry(header=_header(stamp, frame_id), child_frame_id=child_frame_id)
    msg.pose.pose = matrix_to_pose(map_T_base)
    position, attitude = step_sigmas
    msg.pose.covariance = pose_covariance(np.eye(3) * position ** 2,
                                          np.diag([attitude ** 2, attitude ** 2, float(yaw_variance)]))
    msg.twist.covariance = [float(x) for x in np.diag([UNOBSERVED_VARIANCE] * 6).ravel()]
    return msg


def observations_msg(observations, stamp: rospy.Time, frame_id: str = "camera") -> MarkerObservations:
    """A frame's per-marker results (``pipeline.ObservationResult``: ``.observation`` the detection,
    ``.yaw/.yaw_sigma/.range/.residual/.accepted``) as the package's ``MarkerObservations``; unknown
    values stay NaN."""
    out = MarkerObservations(header=_header(stamp, frame_id))
    for r in observations:
        o = r.observation
        b = np.asarray(o.centre, dtype=float)
        u, v = o.pixel
        out.observations.append(MarkerObservation(
            id=int(o.id), azimuth=float(o.azimuth), elevation=float(o.elevation),
            bearing=Vector3(float(b[0]), float(b[1]), float(b[2])), pixel_u=float(u), pixel_v=float(v),
            angular_size=float(o.angular_size), bearing_sigma=float(o.sigma), range=float(r.range),
            yaw=float(r.yaw), yaw_sigma=float(r.yaw_sigma), residual=float(r.residual),
            accepted=bool(r.accepted), method=str(o.method)))
    return out


_SEEN = ColorRGBA(0.1, 0.9, 0.2, 1.0)
_UNSEEN = ColorRGBA(0.6, 0.6, 0.6, 0.8)
_TEXT = ColorRGBA(1.0, 1.0, 1.0, 1.0)


def marker_array(marker_map: MarkerMap, stamp: rospy.Time, seen_ids: Iterable[int] = (),
                 namespace: str = "aruco_markers") -> MarkerArray:
    """rviz markers of the marker map: a cube of the marker's size at each surveyed centre (green
    when seen in the last frame, grey otherwise) and its id as text above it."""
    seen = {int(i) for i in seen_ids}
    out = MarkerArray()
    for m in marker_map:
        cube = VizMarker(header=_header(stamp, marker_map.frame_id), ns=namespace, id=2 * m.id,
                         type=VizMarker.CUBE, action=VizMarker.ADD)
        cube.pose.position = Point(*(float(x) for x in m.position))
        cube.pose.orientation.w = 1.0
        cube.scale = Vector3(m.size, m.size, m.size)
        cube.color = _SEEN if m.id in seen else _UNSEEN
        text = VizMarker(header=_header(stamp, marker_map.frame_id), ns=namespace + "_ids", id=2 * m.id + 1,
                         type=VizMarker.TEXT_VIEW_FACING, action=VizMarker.ADD, text=str(m.id))
        text.pose.position = Point(float(m.position[0]), float(m.position[1]), float(m.position[2]) + m.size)
        text.pose.orientation.w = 1.0
        text.scale.z = max(0.15, m.size)
        text.color = _TEXT
        out.markers.extend([cube, text])
    return out


_RAY_ACCEPTED = ColorRGBA(0.1, 0.9, 0.2, 0.9)


def rays_marker_array(observations, stamp: rospy.Time, camera_frame: str = "camera",
                      default_length: float = 3.0, namespace: str = "bearing_rays") -> MarkerArray:
    """rviz bearing rays of a frame's accepted markers: one LINE_LIST in ``camera_frame`` from the camera's
    origin along each accepted marker's centre bearing, as long as its range estimate (m; ``default_length``
    when unknown), and the id as text at its end. An empty frame gives a DELETEALL (the rays vanish)."""
    out = MarkerArray()
    accepted = [r for r in observations if r.accepted]
    if not accepted:
        out.markers.append(VizMarker(header=_header(stamp, camera_frame), ns=namespace, action=VizMarker.DELETEALL))
        return out
    lines = VizMarker(header=_header(stamp, camera_frame), ns=namespace, id=0, type=VizMarker.LINE_LIST,
                      action=VizMarker.ADD)
    lines.pose.orientation.w = 1.0
    lines.scale.x = 0.02
    lines.color = _RAY_ACCEPTED
    for r in accepted:
        length = float(r.range) if math.isfinite(r.range) and r.range > 0 else default_length
        end = np.asarray(r.observation.centre, dtype=float) * length
        lines.points.extend([Point(0.0, 0.0, 0.0), Point(*(float(x) for x in end))])
        text = VizMarker(header=_header(stamp, camera_frame), ns=namespace + "_ids", id=int(r.id),
                         type=VizMarker.TEXT_VIEW_FACING, action=VizMarker.ADD, text=str(r.id))
        text.pose.position = Point(*(float(x) for x in end))
        text.pose.orientation.w = 1.0
        text.scale.z = 0.2
        text.color = _TEXT
        out.markers.append(text)
    out.markers.insert(0, lines)
    return out


def compressed_image(jpeg: bytes, stamp: rospy.Time, frame_id: str) -> CompressedImage:
    """``sensor_msgs/CompressedImage`` of JPEG bytes."""
    return CompressedImage(header=_header(stamp, frame_id), format="jpeg", data=jpeg)


def bgr_image(frame: np.ndarray, stamp: rospy.Time, frame_id: str) -> Image:
    """``sensor_msgs/Image`` (bgr8) of an (H, W, 3) uint8 BGR array."""
    a = np.ascontiguousarray(frame, dtype=np.uint8)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ConversionError(f"image: expected an (H, W, 3) BGR array, got shape {a.shape}")
    h, w = a.shape[:2]
    return Image(header=_header(stamp, frame_id), height=h, width=w, encoding="bgr8", is_bigendian=0,
                 step=3 * w, data=a.tobytes())


_LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN, "error": DiagnosticStatus.ERROR,
           "stale": DiagnosticStatus.STALE}


def _fmt(value) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def fill_diagnostic(status: DiagnosticStatus, level: str, message: str,
                    values: Mapping[str, object]) -> DiagnosticStatus:
    """Set ``status``'s level, message and values (a ``DiagnosticStatus`` or diagnostic_updater's
    ``DiagnosticStatusWrapper``, which a task fills and returns); ``level`` is 'ok', 'warn', 'error' or
    'stale'; values are formatted (floats with 4 significant digits) in the mapping's order. Returns it."""
    if level not in _LEVELS:
        raise ConfigurationError(f"diagnostic level {level!r}: expected one of {sorted(_LEVELS)}")
    status.level, status.message = _LEVELS[level], message
    status.values = [KeyValue(str(k), _fmt(v)) for k, v in values.items()]
    return status

"""Node ``heading_check``: a dual-antenna GNSS heading beside the marker heading, in ``/diagnostics``.

Subscribes ``abs_orient/orientation`` (``geometry_msgs/PoseWithCovarianceStamped``, the marker heading) and
``~gnss_topic`` (``~gnss_msg``: ``Imu``, the receiver's heading in its orientation's yaw, as robot_localization
takes it, or ``QuaternionStamped``, as nmea_navsat_driver publishes an HDT sentence's; in ``~convention``:
``compass`` the baseline's azimuth clockwise from true north, ``enu`` REP 103's yaw).
Publishes ``/diagnostics`` once a second: ``<node name>: GNSS vs markers``, OK when they agree, WARN with the
likely cause when they do not (:mod:`aruco_abs_orient.headingcheck`). The north the marker heading is referred to
comes from the same marker map and ``~north`` as the abs_orient node's (``~markers`` and ``~north``, by default
``/abs_orient/markers`` and ``/abs_orient/north``). Other private params: ``~mounting_yaw_deg`` (the antennas'
baseline in base_link, default 0: along x, rear to front), ``~window_s`` (60), ``~tolerance_deg`` (0.1).
"""

from __future__ import annotations

import math
import sys
import threading

import numpy as np

from ..errors import ConfigurationError
from ..headingcheck import CONVENTIONS, HeadingAgreement, receiver_yaw
from ..markers import MarkerMap
from ..nodeconfig import NodeConfig
from ..north import NorthReference
from ..paramspec import coerce, spec_of
from ..transforms import quat_to_matrix, yaw_of

__all__ = ["main"]

_LEVELS = {"ok": 0, "warn": 1, "waiting": 0}


def main(argv=None) -> int:
    """Node entry point: check until shutdown; 2 (one line) for bad parameters."""
    from . import run_node

    return run_node("heading_check", lambda: _check(argv))


def _yaw(q) -> float:
    """The yaw (rad) of a quaternion message; NaN for a NaN or zero one."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return float(yaw_of(quat_to_matrix([q.x, q.y, q.z, q.w])))


def _check(argv) -> int:
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
    from sensor_msgs.msg import Imu

    from . import exit_without_master

    exit_without_master("heading_check", "live.launch gnss_heading:=<topic>", argv)
    rospy.init_node("heading_check", argv=argv)
    kinds = {"Imu": Imu, "QuaternionStamped": QuaternionStamped}
    kind = kinds.get(rospy.get_param("~gnss_msg", "Imu"))
    if kind is None:
        raise ConfigurationError(f"~gnss_msg: expected one of {tuple(kinds)}, got {rospy.get_param('~gnss_msg')!r}")
    convention = rospy.get_param("~convention", "compass")
    if convention not in CONVENTIONS:
        raise ConfigurationError(f"~convention: expected one of {CONVENTIONS}, got {convention!r}")
    markers = rospy.get_param("~markers", rospy.get_param("/abs_orient/markers", ""))
    if not markers:
        raise ConfigurationError("~markers: the marker map YAML (or run beside abs_orient, whose ~markers is used)")
    marker_map = MarkerMap.load(markers)
    try:  # roslaunch reads the word true as a boolean
        word = coerce(rospy.get_param("~north", rospy.get_param("/abs_orient/north", "grid")),
                      spec_of(NodeConfig, "north"), "grid")
    except ValueError as e:
        raise ConfigurationError(f"~north: {e}") from None
    north = NorthReference.make(word, marker_map.grid, marker_map.origin, "~")
    mounting = math.radians(float(rospy.get_param("~mounting_yaw_deg", 0.0)))
    check = HeadingAgreement(window=float(rospy.get_param("~window_s", 60.0)),
                             tolerance=math.radians(float(rospy.get_param("~tolerance_deg", 0.1))))

    lock = threading.Lock()  # the subscribers' threads and the timer's

    def on_markers(msg: PoseWithCovarianceStamped) -> None:
        yaw = _yaw(msg.pose.pose.orientation)
        if math.isfinite(yaw):
            with lock:
                check.add_markers(msg.header.stamp.to_sec(), yaw)

    def on_receiver(msg) -> None:
        angle = _yaw(msg.orientation if kind is Imu else msg.quaternion)
        if math.isfinite(angle):
            with lock:
                check.add_receiver(msg.header.stamp.to_sec(), receiver_yaw(angle, convention, mounting))

    diagnostics = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)

    def report(_event) -> None:
        with lock:
            verdict = check.summary(north)
        values = {"pairs": verdict.pairs, "mean difference deg": f"{math.degrees(verdict.mean):.4f}",
                  "sigma deg": f"{math.degrees(verdict.sigma):.4f}", "north": north.describe(),
                  "receiver convention": convention, "mounting yaw deg": f"{math.degrees(mounting):.3f}"}
        status = DiagnosticStatus(level=_LEVELS[verdict.level], name=f"{rospy.get_name()}: GNSS vs markers",
                                  message=verdict.message, hardware_id="gnss",
                                  values=[KeyValue(k, str(v)) for k, v in values.items()])
        diagnostics.publish(DiagnosticArray(header=rospy.Header(stamp=rospy.Time.now()), status=[status]))

    rospy.Subscriber("abs_orient/orientation", PoseWithCovarianceStamped, on_markers, queue_size=50)
    rospy.Subscriber(rospy.get_param("~gnss_topic", "gnss/heading"), kind, on_receiver, queue_size=50)
    rospy.Timer(rospy.Duration(1.0), report)
    rospy.loginfo(f"heading_check: receiver headings ({convention}) against the marker heading, {north.describe()}")
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())

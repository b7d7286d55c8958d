"""Relay one tf edge (``odom → base_link`` by default) as ``nav_msgs/Odometry`` (node ``tf_to_odometry``).

robot_localization fuses odometry from topics, not from tf; a recording or a VO that only publishes tf
gets its odometry topic from this relay. Every ``/tf`` message carrying the edge becomes one Odometry
message with the same stamp (never re-stamped), ``header.frame_id`` = parent, ``child_frame_id`` = child,
the pose of the child in the parent and no twist (its variances are UNOBSERVED_VARIANCE; cfg/ekf.yaml
masks the twist out anyway). The pose covariance is
diagonal from ``~position_sigma`` (m, default 0.005) and ``~attitude_sigma`` (rad, default 0.002): what
one VO pose is worth *relative to the previous one*, since the EKF fuses it differentially
(``cfg/ekf.yaml``). A transform with NaN/inf is dropped and counted (logged once per 10 s).

Private params: ``~parent_frame`` (odom), ``~child_frame`` (base_link), ``~position_sigma``,
``~attitude_sigma``. Publishes ``odometry/vo`` (remappable).
"""

from __future__ import annotations

import sys

import numpy as np

from ..errors import ConfigurationError

__all__ = ["odometry_from_transform", "main"]


def odometry_from_transform(transform_stamped, position_sigma: float, attitude_sigma: float):
    """``TransformStamped`` parent→child → ``nav_msgs/Odometry`` of the child in the parent, same stamp.
    Raises ConversionError for NaN/inf."""
    from nav_msgs.msg import Odometry

    from .conversions import UNOBSERVED_VARIANCE, matrix_to_pose, transform_to_matrix

    T = transform_to_matrix(transform_stamped.transform,
                            f"{transform_stamped.header.frame_id}->{transform_stamped.child_frame_id}")
    msg = Odometry()
    msg.header = transform_stamped.header
    msg.child_frame_id = transform_stamped.child_frame_id
    msg.pose.pose = matrix_to_pose(T)
    msg.pose.covariance = [float(x) for x in np.diag([position_sigma**2] * 3 + [attitude_sigma**2] * 3).ravel()]
    msg.twist.covariance = [float(x) for x in np.diag([UNOBSERVED_VARIANCE] * 6).ravel()]
    return msg


def main(argv=None) -> int:
    """Node entry point: relay the transform until shutdown; 2 (one line) for bad parameters."""
    from . import run_node

    return run_node("tf_to_odometry", lambda: _relay(argv))


def _relay(argv) -> int:
    import rospy
    from nav_msgs.msg import Odometry
    from tf2_msgs.msg import TFMessage

    from . import exit_without_master

    exit_without_master("tf_to_odometry", "ekf.launch", argv)
    from .conversions import ConversionError

    rospy.init_node("tf_to_odometry", argv=argv)
    parent = rospy.get_param("~parent_frame", "odom").lstrip("/")
    child = rospy.get_param("~child_frame", "base_link").lstrip("/")
    position_sigma = float(rospy.get_param("~position_sigma", 0.005))
    attitude_sigma = float(rospy.get_param("~attitude_sigma", 0.002))
    if not (position_sigma > 0 and attitude_sigma > 0):
        raise ConfigurationError("~position_sigma and ~attitude_sigma must be positive "
                                 f"(got {position_sigma}, {attitude_sigma})")
    pub = rospy.Publisher("odometry/vo", Odometry, queue_size=50)
    dropped = [0]

    def on_tf(msg: TFMessage) -> None:
        for tr in msg.transforms:
            if tr.header.frame_id.lstrip("/") != parent or tr.child_frame_id.lstrip("/") != child:
                continue
            try:
                pub.publish(odometry_from_transform(tr, position_sigma, attitude_sigma))
            except ConversionError as e:
                dropped[0] += 1
                rospy.logwarn_throttle(10.0, f"tf_to_odometry: dropped {dropped[0]} transform(s): {e}")

    rospy.Subscriber("/tf", TFMessage, on_tf, queue_size=100)
    rospy.loginfo(f"tf_to_odometry: relaying tf {parent} -> {child} to {pub.resolved_name}")
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""tf edge → nav_msgs/Odometry relay (ros/tf_to_odometry.py): same stamp and frames, the pose of the
child in the parent (read back through tf2), the configured covariance; NaN refused."""
import math

import numpy as np
import pytest
import rospy
import tf2_ros
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.ros.conversions import ConversionError, matrix_to_transform_stamped, transform_to_matrix
from aruco_abs_orient.ros.tf_to_odometry import odometry_from_transform
from aruco_abs_orient.transforms import make_T, rpy_to_matrix

angle = st.floats(-math.pi, math.pi, allow_nan=False)


@given(angle, st.floats(-1.5, 1.5), angle, st.floats(-50, 50), st.floats(-50, 50))
def test_odometry_is_the_child_pose_in_the_parent(roll, pitch, yaw, x, y):
    T = make_T(rpy_to_matrix(roll, pitch, yaw), [x, y, 0.3])
    tr = matrix_to_transform_stamped(T, rospy.Time(100, 5), "odom", "base_link")
    odom = odometry_from_transform(tr, 0.005, 0.002)
    assert odom.header.stamp == rospy.Time(100, 5) and odom.header.frame_id == "odom"
    assert odom.child_frame_id == "base_link"
    # the pose, as a transform, is the same edge: check via tf2
    back = matrix_to_transform_stamped(np.eye(4), rospy.Time(100, 5), "odom", "base_link")
    back.transform.translation.x, back.transform.translation.y, back.transform.translation.z = (
        odom.pose.pose.position.x, odom.pose.pose.position.y, odom.pose.pose.position.z)
    back.transform.rotation = odom.pose.pose.orientation
    buf = tf2_ros.Buffer(debug=False)
    buf.set_transform(back, "test")
    got = transform_to_matrix(buf.lookup_transform("odom", "base_link", rospy.Time(100, 5)).transform)
    np.testing.assert_allclose(got, T, atol=1e-9)
    C = np.array(odom.pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(np.diag(C), [0.005**2] * 3 + [0.002**2] * 3)
    assert np.count_nonzero(C - np.diag(np.diag(C))) == 0


def test_nan_is_refused():
    tr = matrix_to_transform_stamped(np.eye(4), rospy.Time(1), "odom", "base_link")
    tr.transform.rotation.z = float("nan")
    with pytest.raises(ConversionError, match="odom->base_link.rotation"):
        odometry_from_transform(tr, 0.005, 0.002)

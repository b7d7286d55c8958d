#!/usr/bin/env python3
"""rostest checker for heading_check.test: the real heading_check node beside a dual-antenna receiver.

A platform at a UTM 32N site (convergence +2.2°, :mod:`aruco_abs_orient.north`) stands, then turns back and forth.
Per namespace the checker publishes the marker heading, ``abs_orient/orientation`` at 10 Hz (true north, 0.02°
noise), and a receiver's ``gnss/heading`` at 5 Hz (``sensor_msgs/Imu``, its orientation's yaw the baseline's
compass azimuth, 0.2° noise): ``honest`` the true azimuth; ``grid_receiver`` a grid azimuth (true − γ) as
nmea_navsat_driver's ``geometry_msgs/QuaternionStamped``;
``turned`` antennas across the platform (the node's ``~mounting_yaw_deg`` 90) but turned 2° further. Each node's
``/diagnostics`` status must end OK for the honest one, WARN naming the convergence for the grid one, WARN naming
the mounting for the turned one."""
import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
from sensor_msgs.msg import Imu

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.north import NorthReference

MOUNTING = {"honest": 0.0, "grid_receiver": 0.0, "turned": math.radians(92.0)}   # where the baseline really is


def true_yaw(t):
    return 0.4 + 0.8 * math.sin(0.3 * max(t - 2.0, 0.0))


class HeadingCheck(unittest.TestCase):
    def test_the_node_tells_the_three_receivers_apart(self):
        import os

        rospy.init_node("rt_heading_check")
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "heading_check_markers.yaml")
        site = MarkerMap.load(path)
        gamma = NorthReference.make("true", site.grid, site.origin).gamma
        kinds = {ns: QuaternionStamped if ns == "grid_receiver" else Imu for ns in MOUNTING}
        pubs = {ns: (rospy.Publisher(f"/{ns}/abs_orient/orientation", PoseWithCovarianceStamped, queue_size=20),
                     rospy.Publisher(f"/{ns}/gnss/heading", kinds[ns], queue_size=20)) for ns in MOUNTING}
        last = {}
        lock = threading.Lock()

        def on_diagnostics(msg):
            with lock:
                for s in msg.status:
                    last[s.name.split("/")[1]] = (s.level, s.message)

        rospy.Subscriber("/diagnostics", DiagnosticArray, on_diagnostics, queue_size=50)
        rng = np.random.default_rng(5)
        t0, k = time.time(), 0
        while time.time() - t0 < 25.0 and not rospy.is_shutdown():
            t = time.time() - t0
            stamp = rospy.Time.now()
            for ns, (orientation, receiver) in pubs.items():
                yaw = true_yaw(t) + rng.normal(0.0, math.radians(0.02))
                msg = PoseWithCovarianceStamped()
                msg.header.stamp, msg.header.frame_id = stamp, "map"
                msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
                orientation.publish(msg)
                if k % 2 == 0:
                    azimuth = math.pi / 2 - true_yaw(t) - MOUNTING[ns] + rng.normal(0.0, math.radians(0.2))
                    if ns == "grid_receiver":
                        azimuth -= gamma
                    rx = kinds[ns]()
                    rx.header.stamp, rx.header.frame_id = stamp, "gnss"
                    q = rx.orientation if kinds[ns] is Imu else rx.quaternion
                    q.z, q.w = math.sin(azimuth / 2), math.cos(azimuth / 2)
                    receiver.publish(rx)
            k += 1
            time.sleep(0.1)
        time.sleep(1.5)
        with lock:
            got = dict(last)
        print(f"[figure] heading_check: {got}", flush=True)
        self.assertEqual(got["honest"][0], 0, got["honest"])
        self.assertTrue(got["honest"][1].startswith("agree"), got["honest"])
        self.assertEqual(got["grid_receiver"][0], 1, got["grid_receiver"])
        self.assertIn("meridian convergence", got["grid_receiver"][1])
        self.assertEqual(got["turned"][0], 1, got["turned"])
        self.assertIn("mounting_yaw_deg", got["turned"][1])


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_heading_check", HeadingCheck)

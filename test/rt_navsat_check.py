#!/usr/bin/env python3
"""rostest checker for navsat_true_north.test: GNSS beside the marker heading through the real navsat_transform_node.

A site in UTM 32N, 3° east of the central meridian (E 731 000, N 5 210 000: meridian convergence +2.2°); the marker
map's origin there, grid UTM32N (the survey grid is the GNSS's own UTM zone: the same scale, so only the north
differs). A robot stands 2 s, then drives a 10 m circle at 1 m/s. The checker publishes, per namespace, what the EKF
beside an abs_orient node publishes on /odometry/filtered: in ``true_north`` the map frame of ``~north: true`` (the
grid turned by −γ about the origin, :meth:`aruco_abs_orient.north.NorthReference.turn_point`, yaw − γ), in
``grid_north`` the grid itself, each with its tf map -> base_link (frames of their own per namespace); and the
receiver's fixes (exact: PROJ's latitude and longitude of the robot's grid position). navsat_transform aligns the
fixes with the first odometry heading it gets. With the true-north heading its odometry/gps is the robot's position in
that map frame within 2 cm; with the grid-north one, the same fixes land γ times the distance from the first fix off
(≥ 0.2 m at 10 m): the error a grid heading fed next to GNSS makes silently."""
import math
import threading
import time
import unittest

import numpy as np
import pyproj
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import NavSatFix, NavSatStatus

from aruco_abs_orient.north import NorthReference

ORIGIN = np.array([731000.0, 5210000.0, 400.0])
GRID = "UTM32N"


STAND = 2.0  # s standing first: navsat_transform takes its datum and heading from a robot at rest, whatever the
# delay between the first fix and the odometry it pairs it with (turning at 0.1 rad/s, a 50 ms delay on a loaded
# host turned its frame by 0.3° and put the fixes 5 cm off at 10 m)


def robot(t):
    """Grid position relative to the origin (m) and grid yaw (rad) at time t (s): standing ``STAND`` s, then a
    10 m circle at 1 m/s."""
    a = 0.1 * max(t - STAND, 0.0)
    return np.array([10.0 * math.cos(a) - 10.0, 10.0 * math.sin(a), 0.0]), a + math.pi / 2


class NavsatCheck(unittest.TestCase):
    def test_true_north_heading_aligns_gnss(self):
        rospy.init_node("rt_navsat_check")
        north = NorthReference.make("true", GRID, ORIGIN)
        proj = pyproj.Proj("EPSG:32632")
        frames = {"true_north": north, "grid_north": NorthReference.make("grid", GRID, ORIGIN)}
        pubs = {ns: (rospy.Publisher(f"/{ns}/odometry/filtered", Odometry, queue_size=10),
                     rospy.Publisher(f"/{ns}/gps/fix", NavSatFix, queue_size=10)) for ns in frames}
        got = {ns: [] for ns in frames}
        lock = threading.Lock()

        def on_gps(ns):
            def cb(msg):
                p = msg.pose.pose.position
                with lock:
                    got[ns].append((msg.header.stamp.to_sec(), np.array([p.x, p.y])))
            return cb

        for ns in frames:
            rospy.Subscriber(f"/{ns}/odometry/gps", Odometry, on_gps(ns), queue_size=100)
        tf = tf2_ros.TransformBroadcaster()
        t0, k = time.time(), 0
        while time.time() - t0 < 12.0 + STAND and not rospy.is_shutdown():
            t = time.time() - t0
            p, yaw = robot(t)
            stamp = rospy.Time.now()
            for ns, ref in frames.items():
                # each namespace its own map and base_link frames (one tf tree): what its EKF would publish
                odom = Odometry()
                odom.header.stamp, odom.header.frame_id, odom.child_frame_id = stamp, f"map_{ns}", f"base_{ns}"
                q = ref.turn_point(p)[0]
                odom.pose.pose.position.x, odom.pose.pose.position.y = q[0], q[1]
                heading = yaw + ref.turn
                odom.pose.pose.orientation.z = math.sin(heading / 2)
                odom.pose.pose.orientation.w = math.cos(heading / 2)
                odom.pose.covariance = list(np.diag([1e-4] * 6).ravel())
                pubs[ns][0].publish(odom)
                tr = TransformStamped()
                tr.header, tr.child_frame_id = odom.header, odom.child_frame_id
                tr.transform.translation.x, tr.transform.translation.y = q[0], q[1]
                tr.transform.rotation = odom.pose.pose.orientation
                tf.sendTransform(tr)
                if k % 4 == 0:  # 5 Hz fixes
                    lon, lat = proj(ORIGIN[0] + p[0], ORIGIN[1] + p[1], inverse=True)
                    fix = NavSatFix(latitude=lat, longitude=lon, altitude=ORIGIN[2])
                    fix.header.stamp, fix.header.frame_id = stamp, f"base_{ns}"  # the antenna at base_link
                    fix.status.status, fix.position_covariance_type = NavSatStatus.STATUS_FIX, 2
                    fix.position_covariance = [0.0001, 0, 0, 0, 0.0001, 0, 0, 0, 0.0001]
                    pubs[ns][1].publish(fix)
            k += 1
            time.sleep(0.05)
        errors = {}
        for ns, ref in frames.items():
            with lock:
                rows = list(got[ns])
            self.assertGreater(len(rows), 20, f"{ns}: {len(rows)} odometry/gps messages")
            e = []
            for stamp, q in rows:
                truth = ref.turn_point(robot(stamp - t0)[0])[0][:2]  # wall clock: rospy.Time.now() is time.time()
                e.append(np.linalg.norm(q - truth))
            errors[ns] = np.array(e)[len(e) // 2:]  # from 7 s on (5 s of driving): 5-12 m from the first fix
            print(f"[figure] navsat {ns}: odometry/gps vs the robot in map, max {errors[ns].max():.3f} m, "
                  f"median {np.median(errors[ns]):.3f} m (meridian convergence {math.degrees(north.gamma):.3f} deg)",
                  flush=True)
        self.assertLess(errors["true_north"].max(), 0.02)
        self.assertGreater(np.median(errors["grid_north"]), 0.2)


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_navsat_check", NavsatCheck)

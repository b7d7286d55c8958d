#!/usr/bin/env python3
"""Checker of abs_orient_bad_inputs.test: bad inputs while running → the node keeps running, reports
on /diagnostics, recovers, and its map->odom stays within 0.3° / 3 cm of the truth."""
import math
import sys
import threading
import time
import unittest

import rospy
import rostest
import rt_abs_orient_scene as scene
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from aruco_abs_orient.ros.conversions import transform_to_matrix
from aruco_abs_orient.transforms import wrap_angle, yaw_of

STATUS = "abs_orient: pipeline"


class LiveFeedCase(unittest.TestCase):
    """The live-fed scene, the node's diagnostics and map->odom; subclasses add the tests."""

    raw = False  # feed sensor_msgs/Image instead of JPEG

    def setUp(self):
        rospy.init_node("rt_abs_orient_live")
        self.tf = tf2_ros.Buffer(debug=False)
        self.listener = tf2_ros.TransformListener(self.tf)
        self.lock = threading.Lock()
        self.status = None
        self.status_count = 0
        rospy.Subscriber("/diagnostics", DiagnosticArray, self._on_diag)
        base_T_camera, base_T_prism = scene.lever_arms(self.tf)
        self.feed = scene.Feed(scene.render_frames(base_T_camera), base_T_prism, rate=10.0, raw=self.raw)
        self.feed.start()

    def tearDown(self):
        self.feed.stop.set()
        self.feed.join(5)

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name == STATUS:
                with self.lock:
                    self.status = s
                    self.status_count += 1

    def wait_status(self, predicate, timeout, what):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not rospy.is_shutdown():
            with self.lock:
                s = self.status
            if s is not None and predicate(s):
                return s
            time.sleep(0.1)
        self.fail(f"{what}: not within {timeout} s; last status: {self.status}")

    def values(self, s):
        return {kv.key: kv.value for kv in s.values}

    def map_odom_error(self):
        """(yaw error in degrees, position error in m) of the latest map->odom vs the truth."""
        tr = self.tf.lookup_transform("map", "odom", rospy.Time(0))
        T = transform_to_matrix(tr.transform)
        dyaw = math.degrees(abs(float(wrap_angle(yaw_of(T[:3, :3]) - yaw_of(scene.MAP_T_ODOM[:3, :3])))))
        return dyaw, float(((T[:3, 3] - scene.MAP_T_ODOM[:3, 3]) ** 2).sum() ** 0.5)

    def map_odom_age(self):
        """s (wall clock = ROS time here) since the stamp of the newest map->odom."""
        latest = self.tf.get_latest_common_time("map", "odom")
        return (rospy.Time.now() - latest).to_sec()

    def assert_map_odom_right(self):
        dyaw, dpos = self.map_odom_error()
        self.assertLess(dyaw, 0.3, "map->odom yaw error (deg)")
        self.assertLess(dpos, 0.03, "map->odom position error (m)")

    def bad_phase(self, seconds, needle, **inputs):
        """Switch the feed to bad inputs, expect a WARN naming them, switch back, expect recovery (OK)."""
        start = time.monotonic()
        for k, v in inputs.items():
            setattr(self.feed, k, v)
        s = self.wait_status(lambda s: s.level == DiagnosticStatus.WARN and needle in s.message, seconds + 3,
                             f"diagnostics warn '{needle}'")
        time.sleep(max(0.0, start + seconds - time.monotonic()))
        if not inputs.get("nan_tf"):  # odometry still flows: map->odom keeps coming at its newest stamp
            self.assertLess(self.map_odom_age(), 0.5, f"map->odom not re-published during '{needle}'")
        self.feed.image, self.feed.nan_tf, self.feed.prism = "good", False, True
        self.wait_status(lambda s: s.level == DiagnosticStatus.OK, 10, f"recovery after '{needle}'")
        self.assert_map_odom_right()
        return s



class BadInputs(LiveFeedCase):
    def test_bad_inputs_while_running(self):
        self.wait_status(lambda s: s.level == DiagnosticStatus.OK, 40, "initialised and OK")
        self.assert_map_odom_right()
        rospy.loginfo("initialised: map->odom error %.3f deg, %.3f m", *self.map_odom_error())

        s = self.bad_phase(2.0, "corrupt images", image="corrupt")
        self.assertGreater(int(self.values(s)["bad images"]), 0)

        # marker 1 becomes id 40: its tracking view ignores it; the sweeping search tile (once around in
        # 72 frames = 7.2 s at 10 Hz) finds and rejects it
        s = self.bad_phase(8.0, "unknown ids", image="unknown")
        self.assertGreater(int(self.values(s)["unknown marker ids"]), 0)

        self.bad_phase(2.0, "tf", nan_tf=True)

        s = self.bad_phase(3.0, "no prism for", prism=False)
        self.assertGreater(float(self.values(s)["prism age [s]"]), 1.0)

        # dynamic_reconfigure: a node parameter, a pipeline and a tracking parameter, applied while running
        from dynamic_reconfigure.client import Client

        client = Client("abs_orient", timeout=10)
        applied = client.update_configuration({"time_offset": 0.05, "fusion_gate": 6.0, "gate_deg": 2.0})
        self.assertEqual((applied["time_offset"], applied["fusion_gate"], applied["gate_deg"]), (0.05, 6.0, 2.0))
        s = self.wait_status(lambda s: self.values(s)["time offset [s]"] == "0.05", 5, "time offset from reconfigure")
        self.assertEqual(self.values(s)["parameters refused"], "0", "fusion_gate or gate_deg refused by the pipeline")

        # still alive and reporting
        n = self.status_count
        time.sleep(2.5)
        self.assertGreater(self.status_count, n, "diagnostics stopped: the node died")
        self.assert_map_odom_right()


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_abs_orient_bad_inputs", BadInputs, sys.argv)

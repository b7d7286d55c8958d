#!/usr/bin/env python3
"""rostest checker of synthetic_bag.test: a generated bag played with ``rosbag play --clock``
carries ``odom → base_link`` on /tf equal to the scenario's drift model.

1. Unless ``~bag_dir`` names a directory that already holds a generated scenario, generates the
   ``~preset`` scenario (default ``tiny``, ~3 s) into a temporary directory — the checker makes
   its own input, so the .test file needs no set-up step.
2. Subscribes to /tf, /tf_static and /clock, then runs ``rosbag play --clock`` on the bag as a
   subprocess and waits (wall clock) for it to finish.
3. Checks: every image's ``odom → base_link`` arrived, each equal to
   ``Scenario.from_hidden(hidden.yaml).odom_T_base(stamp − camera_time_offset)`` within 1e-5;
   the latched /tf_static carries the NOMINAL ``base_link → camera`` and ``base_link → prism``;
   /clock ran up to the end of the bag.
"""
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from rosgraph_msgs.msg import Clock
from tf2_msgs.msg import TFMessage

from aruco_abs_orient.synthetic.scenario import Scenario
from aruco_abs_orient.transforms import make_T, quat_to_matrix
from aruco_abs_orient.tum import read_tum


def _matrix(tr) -> np.ndarray:
    q, p = tr.rotation, tr.translation
    return make_T(quat_to_matrix([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z])


class SyntheticBagTfCheck(unittest.TestCase):
    def setUp(self):
        rospy.init_node("rt_synthetic_tf_check")
        self.tmp = None
        bag_dir = rospy.get_param("~bag_dir", "")
        if bag_dir and os.path.exists(os.path.join(bag_dir, "scenario.bag")):
            self.dir = bag_dir
        else:
            from aruco_abs_orient.synthetic.bag import generate
            from aruco_abs_orient.synthetic.scenario import PRESETS

            self.tmp = tempfile.mkdtemp(prefix="rt_synthetic_")
            self.dir = self.tmp
            generate(PRESETS[rospy.get_param("~preset", "tiny")], self.dir, progress=False)

    def tearDown(self):
        if self.tmp:
            shutil.rmtree(self.tmp, ignore_errors=True)

    def test_odom_tf_matches_drift_model(self):
        scenario = Scenario.from_hidden(os.path.join(self.dir, "hidden.yaml"))
        n_images = read_tum(os.path.join(self.dir, "truth.tum")).stamps.size
        lock = threading.Lock()
        odom, static, clock = [], [], []

        def on_tf(msg):
            with lock:
                for tr in msg.transforms:
                    if (tr.header.frame_id, tr.child_frame_id) == ("odom", "base_link"):
                        odom.append((tr.header.stamp.to_sec(), _matrix(tr.transform)))

        def on_static(msg):
            with lock:
                static.extend((tr.header.frame_id, tr.child_frame_id, _matrix(tr.transform))
                              for tr in msg.transforms)

        def on_clock(msg):
            with lock:
                clock.append(msg.clock.to_sec())

        rospy.Subscriber("/tf", TFMessage, on_tf, queue_size=1000)
        rospy.Subscriber("/tf_static", TFMessage, on_static, queue_size=10)
        rospy.Subscriber("/clock", Clock, on_clock, queue_size=1000)
        # -d: wait after advertising so that the subscriptions above are connected before playback
        play = subprocess.Popen(["rosbag", "play", "--clock", "-q", "-d", "1.5",
                                 os.path.join(self.dir, "scenario.bag")],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
        try:
            output, _ = play.communicate(timeout=120)
        finally:
            if play.poll() is None:
                play.kill()
                play.wait()
        self.assertEqual(play.returncode, 0, f"rosbag play failed:\n{output}")
        time.sleep(0.5)  # the last messages in flight
        with lock:
            odom = sorted(odom, key=lambda x: x[0])
            static = list(static)
            clock = list(clock)

        self.assertEqual(len(odom), n_images, f"{len(odom)} odom->base_link on /tf for {n_images} images")
        stamps = np.array([o[0] for o in odom])
        expected = scenario.odom_T_base(stamps - scenario.config.camera_time_offset)
        got = np.array([o[1] for o in odom])
        err = np.abs(got - expected).max()
        self.assertLess(err, 1e-5, f"odom->base_link differs from the drift model by {err}")
        np.testing.assert_allclose(stamps, scenario.camera_stamps, atol=2e-6)

        edges = {(parent, child): T for parent, child, T in static}
        self.assertIn(("base_link", "camera"), edges, "no latched base_link->camera on /tf_static")
        self.assertIn(("base_link", "prism"), edges, "no latched base_link->prism on /tf_static")
        np.testing.assert_allclose(edges[("base_link", "camera")], scenario.base_T_camera_nominal, atol=1e-9)
        np.testing.assert_allclose(edges[("base_link", "prism")], scenario.base_T_prism, atol=1e-9)

        self.assertTrue(clock, "no /clock from rosbag play --clock")
        self.assertGreater(max(clock), stamps[-1] - 0.5, "simulated time did not reach the end of the bag")


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_synthetic_tf_check", SyntheticBagTfCheck, sys.argv)

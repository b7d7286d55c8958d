#!/usr/bin/env python3
"""rostest checker for ms60.test: serves the simulated MS60 on TCP, listens to ms60/prism and
checks rate (≥ 19 Hz), positions and stamps against the simulator's truth."""
import json
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped
from std_msgs.msg import String

from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig


class Ms60DriverCheck(unittest.TestCase):
    def test_rate_values_stamps(self):
        rospy.init_node("rt_ms60_check")
        port = int(rospy.get_param("~port"))
        seconds = float(rospy.get_param("~seconds", 8.0))
        sim = Ms60Simulator(SimConfig(), seed=7)
        sim.serve_tcp(port)
        lock = threading.Lock()
        prisms, statuses, diags = [], [], []

        def on_prism(msg):
            with lock:
                prisms.append((msg.header.stamp.to_sec(), msg.header.frame_id, msg.point.x, msg.point.y, msg.point.z))

        rospy.Subscriber("ms60/prism", PointStamped, on_prism, queue_size=100)
        rospy.Subscriber("ms60/status", String, lambda m: statuses.append(json.loads(m.data)))
        rospy.Subscriber("/diagnostics", DiagnosticArray, diags.append)
        try:
            deadline = time.time() + 30.0
            while not prisms and time.time() < deadline and not rospy.is_shutdown():
                time.sleep(0.05)
            self.assertTrue(prisms, "no ms60/prism message within 30 s")
            time.sleep(1.0)  # steady state
            with lock:
                start = len(prisms)
            t0 = time.time()
            time.sleep(seconds)
            with lock:
                window = prisms[start:]
                received = list(prisms)
            elapsed = time.time() - t0
        finally:
            sim.close()
        rate = len(window) / elapsed
        self.assertGreaterEqual(rate, 19.0, f"ms60/prism at {rate:.2f} Hz")
        stamps = np.array([p[0] for p in received])
        self.assertTrue(np.all(np.diff(stamps) > 0), "stamps not strictly increasing")
        self.assertTrue(all(p[1] == "map" for p in received))
        truth_t = np.array([r.time_s for r in sim.truth if r.rc == 0])
        truth_p = np.array([r.position for r in sim.truth if r.rc == 0])
        errors_ms, pos_err = [], []
        for t, _, x, y, z in received:
            i = int(np.argmin(np.abs(truth_t - t)))
            errors_ms.append(abs(truth_t[i] - t) * 1e3)
            pos_err.append(np.linalg.norm(truth_p[i] - (x, y, z)))
        errors_ms = np.array(errors_ms)
        rospy.loginfo(f"rt_ms60_check: {rate:.2f} Hz, stamp error median {np.median(errors_ms):.2f} ms, "
                      f"max {errors_ms.max():.2f} ms, position error max {max(pos_err) * 1e3:.3f} mm")
        self.assertLess(float(np.percentile(errors_ms, 95)), 2.0)
        self.assertLess(max(pos_err), 1e-5)
        self.assertTrue(statuses and statuses[-1]["state"] == "locked", f"status {statuses[-1:]}")
        self.assertTrue(any(s.name.startswith("ms60_driver") for d in diags for s in d.status))


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_ms60_check", Ms60DriverCheck, sys.argv)

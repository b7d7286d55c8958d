#!/usr/bin/env python3
"""rostest checker for ms60_reaim.test: two strict simulated MS60s tracking a prism that drives at 1 m/s 5 m from the
instrument (11° a second across its sight: a turn aimed where the prism is when the turn starts misses it), against
the direction PowerSearch sweeps; tf map -> base_link published as the robot's fused pose (the truth 3 cm off, 30
Hz, stamped now) and base_link -> prism static (the prism is base_link's origin here). The prism is hidden for 2 s
in both; the driver that predicts from tf (namespace predict) turns the telescope to where the prism will be when
the turn ends (AUT_MakePositioning), fine-adjusts and locks in: its positions resume within the simulator's
positioning, two fine adjustments, the lock-in and 0.5 s of its reappearance; the one without (namespace search)
sweeps with PowerSearch, later. Both times are printed as [figure] lines."""
import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped, TransformStamped

from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig
from aruco_abs_orient.ros.ms60_node import status_values


def track(t):
    a = -0.2 * t  # 1 m/s along a circle of 5 m about the station at the map's origin
    return np.array([5.0 * math.sin(a), 5.0 * math.cos(a), 1.5])


class Link:
    def __init__(self, ns):
        self.ns = ns
        self.lock = threading.Lock()
        self.arrivals, self.status = [], {}
        rospy.Subscriber(f"/{ns}/ms60/prism", PointStamped, self._on_prism, queue_size=100)
        rospy.Subscriber(f"/{ns}/ms60/status", DiagnosticStatus, self._on_status)

    def _on_prism(self, _msg):
        with self.lock:
            self.arrivals.append(time.time())

    def _on_status(self, msg):
        self.status = status_values(msg)

    def first_after(self, t):
        with self.lock:
            return next((a for a in self.arrivals if a > t), None)


class Reaim(unittest.TestCase):
    def test_resume_after_a_pillar(self):
        rospy.init_node("rt_ms60_reaim")
        ports = [int(p) for p in rospy.get_param("~ports").split(",")]
        sims = [Ms60Simulator(SimConfig(), track=track, seed=11 + k) for k in range(2)]
        t_boot = sims[0].t_boot
        for sim, port in zip(sims, ports):
            sim.t_boot = t_boot  # one prism for both instruments
            sim.serve_tcp(port)
        links = [Link("predict"), Link("search")]
        stop = threading.Event()
        static = tf2_ros.StaticTransformBroadcaster()
        lever = TransformStamped()
        lever.header.frame_id, lever.child_frame_id, lever.transform.rotation.w = "base_link", "prism", 1.0
        static.sendTransform(lever)
        broadcaster = tf2_ros.TransformBroadcaster()

        def fused_pose():
            while not stop.is_set() and not rospy.is_shutdown():
                p = track(time.time() - t_boot) + [0.03, 0.0, 0.0]
                tr = TransformStamped()
                tr.header.stamp, tr.header.frame_id, tr.child_frame_id = rospy.Time.now(), "map", "base_link"
                tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z = p
                tr.transform.rotation.w = 1.0
                broadcaster.sendTransform(tr)
                time.sleep(1.0 / 30)

        threading.Thread(target=fused_pose, daemon=True).start()
        try:
            deadline = time.time() + 40.0
            while time.time() < deadline and not all(len(link.arrivals) > 20 for link in links):
                time.sleep(0.1)
            self.assertTrue(all(len(link.arrivals) > 20 for link in links), [len(link.arrivals) for link in links])
            for sim in sims:
                sim.set_prism_visible(False)
            time.sleep(2.0)
            t_back = time.time()
            for sim in sims:
                sim.set_prism_visible(True)
            deadline = t_back + 15.0
            while time.time() < deadline and not all(link.first_after(t_back) for link in links):
                time.sleep(0.05)
            time.sleep(1.2)  # a status after the relock
        finally:
            stop.set()
            for sim in sims:
                sim.close()
        c = SimConfig()
        resumed = {link.ns: link.first_after(t_back) for link in links}
        for ns, first in resumed.items():
            print(f"[figure] ms60_reaim {ns}: positions resumed "
                  f"{'never' if first is None else f'{first - t_back:.2f} s'} after the prism reappeared", flush=True)
        predict, search = links[0].status, links[1].status
        self.assertGreaterEqual(predict.get("reaims", 0), 1, predict)
        self.assertGreaterEqual(predict.get("reaims_found", 0), 1, predict)
        self.assertEqual(search.get("reaims", 0), 0, search)
        self.assertIsNotNone(resumed["predict"])
        self.assertLess(resumed["predict"] - t_back, c.positioning_s + 2 * c.fine_adjust_s + c.lock_in_s + 0.5)
        if resumed["search"] is not None:
            self.assertGreater(resumed["search"], resumed["predict"] + 0.5)


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_ms60_reaim", Reaim)

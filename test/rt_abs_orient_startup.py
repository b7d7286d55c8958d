#!/usr/bin/env python3
"""Checker of abs_orient_startup.test: bad marker maps / calibrations (and a map of 2 markers with
``~markers_only``, a tunable out of its range in the node's ``~filter`` namespace) → one line, exit 2; a good
calibration → the two lever arms on /tf_static, equal to the file (read back through tf2); a params file loaded
into the node's namespace (``rosparam load``, what ``<rosparam command="load">`` does) reaches the node."""
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros

from aruco_abs_orient.ros.conversions import transform_to_matrix
from aruco_abs_orient.transforms import matrix_to_rpy

BAD_MAPS = {
    "missing.yaml": None,  # not written: cannot read
    "syntax.yaml": "markers: [ {id: 3, position: [1, 2, 3]\n",
    "no_position.yaml": "size: 0.19\nmarkers:\n  - {id: 3}\n",
    "bad_dictionary.yaml": "dictionary: DICT_9X9_7\nsize: 0.19\nmarkers:\n  - {id: 3, position: [1, 2, 3]}\n",
    "negative_size.yaml": "size: -0.19\nmarkers:\n  - {id: 3, position: [1, 2, 3]}\n",
}
EXPECTED = {"missing.yaml": "cannot read", "syntax.yaml": "not valid YAML", "no_position.yaml": "markers[0].position",
            "bad_dictionary.yaml": "dictionary", "negative_size.yaml": "size"}


SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scripts")
MARKERS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "cfg", "markers_example.yaml")


def run_node(executable, name, params, timeout=30):
    """Run scripts/<executable> (what rosrun runs) with private params; wait for it to exit."""
    args = [os.path.join(SCRIPTS, executable), f"__name:={name}"] + [f"_{k}:={v}" for k, v in params.items()]
    return subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout)


class Startup(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("rt_abs_orient_startup")
        cls.dir = tempfile.mkdtemp(prefix="rt_startup_")

    def _write(self, name, text):
        path = os.path.join(self.dir, name)
        if text is not None:
            with open(path, "w") as f:
                f.write(text)
        return path

    def _assert_one_fatal_line(self, proc, *needles):
        self.assertEqual(proc.returncode, 2, proc.stdout)
        self.assertNotIn("Traceback", proc.stdout)
        lines = [ln for ln in proc.stdout.splitlines() if ln.strip()]
        fatal = [ln for ln in lines if "FATAL" in ln]
        self.assertEqual(len(fatal), 1, proc.stdout)
        for needle in needles:
            self.assertIn(needle, fatal[0])

    def test_marker_map_that_fails_to_load(self):
        for i, (name, text) in enumerate(BAD_MAPS.items()):
            with self.subTest(map=name):
                path = self._write(name, text)
                proc = run_node("abs_orient", f"abs_orient_bad_{i}", {"markers": path})
                self._assert_one_fatal_line(proc, path, EXPECTED[name])

    def test_markers_only_with_fewer_than_three_markers(self):
        path = self._write("two.yaml", "size: 0.19\nmarkers:\n  - {id: 3, position: [1, 2, 1]}\n"
                                       "  - {id: 7, position: [4, -2, 1.5]}\n")
        proc = run_node("abs_orient", "abs_orient_two_markers", {"markers": path, "markers_only": "true"})
        self._assert_one_fatal_line(proc, path, "at least 3 markers", "it has 2")

    def test_no_marker_map_given(self):
        proc = run_node("abs_orient", "abs_orient_no_map", {})
        self._assert_one_fatal_line(proc, "~markers")

    def test_a_tunable_out_of_range_in_its_namespace(self):
        rospy.set_param("/abs_orient_params_bad/filter", {"gate_chi2_yaw": 2000.0})
        proc = run_node("abs_orient", "abs_orient_params_bad", {"markers": MARKERS})
        self._assert_one_fatal_line(proc, "~filter/gate_chi2_yaw: expected a number in [0.01, 1000], got 2000.0")

    def test_a_params_file_loaded_into_the_namespace_reaches_the_node(self):
        path = self._write("params.yaml", "tracking:\n  gate_deg: 2.5\nfilter:\n  gate_chi2_yaw: 12.0\n")
        subprocess.run(["rosparam", "load", path, "/abs_orient_params"], check=True, timeout=30)
        args = [os.path.join(SCRIPTS, "abs_orient"), "__name:=abs_orient_params", f"_markers:={MARKERS}"]
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:  # dynamic_reconfigure's view of the running node's tunables: its ~<name>, from the ~section values
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and rospy.get_param("/abs_orient_params/gate_chi2_yaw", None) != 12.0:
                time.sleep(0.2)
            self.assertEqual(rospy.get_param("/abs_orient_params/gate_chi2_yaw", None), 12.0)
            self.assertEqual(rospy.get_param("/abs_orient_params/gate_deg"), 2.5)
            self.assertIsNone(proc.poll())
        finally:
            proc.send_signal(signal.SIGINT)   # as roslaunch stops it
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)

    def test_calibration_that_fails_to_load(self):
        path = self._write("calib_bad.yaml",
                           "base_link_to_camera: {xyz: [0, 0, .nan]}\nbase_link_to_prism: {xyz: [0, 0, 1]}\n")
        proc = run_node("static_tfs", "static_tfs_bad", {"calibration": path})
        self._assert_one_fatal_line(proc, path, "base_link_to_camera.xyz")
        path = self._write("calib_no_prism.yaml", "base_link_to_camera: {xyz: [0, 0, 0.4]}\n")
        proc = run_node("static_tfs", "static_tfs_no_prism", {"calibration": path})
        self._assert_one_fatal_line(proc, path, "base_link_to_prism: missing")

    def test_calibration_is_published_on_tf_static(self):
        path = self._write("calib.yaml", "base_link_to_camera: {xyz: [0.1, -0.02, 0.45], rpy_deg: [0.5, -1.0, 2.0]}\n"
                                         "base_link_to_prism: {xyz: [-0.05, 0.0, 0.62]}\n")
        args = [os.path.join(SCRIPTS, "static_tfs"), "__name:=lever_arms", f"_calibration:={path}"]
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            buf = tf2_ros.Buffer(debug=False)
            tf2_ros.TransformListener(buf)
            cam = buf.lookup_transform("base_link", "camera", rospy.Time(0), rospy.Duration(20.0))
            prism = buf.lookup_transform("base_link", "prism", rospy.Time(0), rospy.Duration(5.0))
        finally:
            proc.terminate()
            proc.wait(10)
        T = transform_to_matrix(cam.transform)
        np.testing.assert_allclose(T[:3, 3], [0.1, -0.02, 0.45], atol=1e-12)
        np.testing.assert_allclose(np.degrees(matrix_to_rpy(T[:3, :3])), [0.5, -1.0, 2.0], atol=1e-9)
        P = transform_to_matrix(prism.transform)
        np.testing.assert_allclose(P[:3, 3], [-0.05, 0.0, 0.62], atol=1e-12)
        self.assertTrue(math.isclose(abs(prism.transform.rotation.w), 1.0))


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_abs_orient_startup", Startup, sys.argv)

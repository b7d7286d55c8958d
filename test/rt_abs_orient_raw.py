#!/usr/bin/env python3
"""Checker of abs_orient_raw.test: with raw mono8 images the node initialises and map->odom is right."""
import sys

import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from rt_abs_orient_bad_inputs import LiveFeedCase


class RawImages(LiveFeedCase):
    raw = True

    def test_raw_images(self):
        s = self.wait_status(lambda s: s.level == DiagnosticStatus.OK, 40, "initialised and OK")
        self.assertGreater(int(self.values(s)["images processed"]), 0)
        self.assert_map_odom_right()


if __name__ == "__main__":
    rostest.rosrun("aruco_abs_orient", "rt_abs_orient_raw", RawImages, sys.argv)

"""The ROS 1 nodes (the only part of the package that imports rospy) and what they share."""

from __future__ import annotations

import sys
from typing import List, Optional


def exit_without_master(node: str, launch: str, argv: Optional[List[str]] = None) -> None:
    """Before ``rospy.init_node``: without a reachable ROS master (``__master:=`` in ``argv`` or
    ``$ROS_MASTER_URI``) print one line naming where it looked and ``launch`` (the launch file that
    starts one), and exit with status 1 — instead of rospy's traceback or endless registration retries."""
    import rosgraph

    master = rosgraph.get_master_uri(argv=argv)
    if not rosgraph.is_master_online(master):
        print(f"{node}: no ROS master at {master}: start roscore or roslaunch aruco_abs_orient {launch}",
              file=sys.stderr)
        sys.exit(1)

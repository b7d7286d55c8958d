"""The ROS 1 nodes (the only part of the package that imports rospy) and what they share."""

from __future__ import annotations

import sys
from typing import Callable, List, Optional

from ..errors import run


def run_node(node: str, main: Callable[[], Optional[int]],
             report: Optional[Callable[[str, int], int]] = None) -> int:
    """:func:`aruco_abs_orient.errors.run` for a node: an error of the package (a bad parameter or file) is one
    FATAL line ``<node>: <message>`` in the node's log (``report(message, status)`` instead, when given) and the
    exit status 2 (1: the input gives no answer)."""

    def fatal(message: str, status: int) -> int:
        import rospy

        rospy.logfatal(f"{node}: {message}")
        return status

    return run(node, main, report or fatal)


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

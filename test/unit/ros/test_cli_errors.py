"""The node scripts without a ROS master: one line naming where they looked, exit status 1, no traceback."""
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rosgraph")

SCRIPTS = Path(__file__).resolve().parents[3] / "scripts"


def _dead_master_uri():
    """A local URI with nothing listening (a port the OS just handed out and took back)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}"


def _run(script, args, env_uri):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), ROS_MASTER_URI=env_uri)
    return subprocess.run([sys.executable, str(SCRIPTS / script)] + args, env=env, capture_output=True, text=True,
                          timeout=60)


@pytest.mark.parametrize("script, args, launch", [
    ("ms60_driver", [], "ms60.launch"),
    ("ms60_driver", ["_port:=loop://", "_rate:=10"], "ms60.launch"),  # private params: rospy's set_param traceback
    ("abs_orient", [], "live.launch"),  # rospy would retry the registration for ever
    ("abs_orient", ["_markers:=markers.yaml"], "live.launch"),
    ("static_tfs", ["_calibration:=calibration.yaml"], "live.launch"),
    ("tf_to_odometry", [], "ekf.launch"),
])
def test_no_master_is_one_line_and_status_1(script, args, launch):
    uri = _dead_master_uri()
    proc = _run(script, args, uri)
    assert proc.returncode == 1, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr == f"{script}: no ROS master at {uri}: start roscore or roslaunch aruco_abs_orient {launch}\n"


def test_master_remapping_on_the_command_line_is_the_one_checked():
    env_uri, arg_uri = _dead_master_uri(), _dead_master_uri()
    proc = _run("abs_orient", [f"__master:={arg_uri}"], env_uri)
    assert proc.returncode == 1 and f"no ROS master at {arg_uri}:" in proc.stderr and "Traceback" not in proc.stderr

"""Runs every rostest in test/*.test (a real roscore, real nodes) as one pytest case each.

`catkin_make run_tests` exits 0 on failures (doc/design.md §15), so the rostests run from here and their
result is rostest's own exit status (without --text, which makes it always 0). Needs the workspace
of `make setup` sourced (tools/env.sh).
"""
import os
import shutil
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROSTESTS = sorted(p.name for p in HERE.glob("*.test"))


@pytest.mark.rostest
@pytest.mark.parametrize("name", ROSTESTS)
def test_rostest(name, tmp_path):
    if shutil.which("rostest") is None or "ROS_PACKAGE_PATH" not in os.environ:
        pytest.fail("rostest or the catkin workspace is missing: run via `make test` (tools/env.sh)")
    if "ekf" in (HERE / name).read_text() and subprocess.run(["rospack", "find", "robot_localization"],
                                                             stdout=subprocess.DEVNULL,
                                                             stderr=subprocess.DEVNULL).returncode != 0:
        pytest.fail(f"{name} needs the real robot_localization, which is not installed: `make setup` builds it with "
                    "../shared/tools/build-robot-localization (or $AAO_SHARED/tools/…); on a ROS distro "
                    "apt install ros-$ROS_DISTRO-robot-localization")
    env = dict(os.environ, ROS_HOSTNAME="localhost", ROS_HOME=str(tmp_path / "ros_home"))
    env.pop("ROS_MASTER_URI", None)
    proc = subprocess.run(
        ["rostest", "aruco_abs_orient", name],
        env=env, cwd=str(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, timeout=600,
    )
    assert proc.returncode == 0, f"rostest {name} failed (exit {proc.returncode}):\n{proc.stdout[-6000:]}"

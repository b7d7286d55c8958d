"""postprocess.launch as a user runs it (issue 20): real roscore, real roslaunch, a rendered bag.

- relative bag:=, markers:= and record:= are resolved against the directory roslaunch is started in
  (nodes run in ~/.ros);
- the replay ends with one line (frames, poses) and no red ``REQUIRED process has died``; exit status 0;
- /use_sim_time is gone again from a roscore that was running before the launch;
- a missing bag is one line naming the full path tried.
Needs tools/env.sh (ROS). About 40 s.
"""
import os
import shutil
import socket
import subprocess
import time

import pytest

from aruco_abs_orient.ros.replay import process_parent, summary_line


def test_summary_line_says_what_the_node_did_and_why_there_is_no_pose():
    diag = {"images received": "300", "images processed": "240", "images dropped": "60", "message": "tracking 2"}
    line = summary_line("/data/run1.bag", 20.0, {"pose": 157, "orientation": 120, "filtered": None}, diag)
    assert line.startswith("replay: run1.bag played to its end (20.0 s): abs_orient processed 240 of 300 images")
    assert "(60 dropped while it was busy: a smaller rate:= gives it more time)" in line
    assert "published 157 poses and 120 marker yaws" in line and "EKF" not in line and "no pose" not in line
    idle = {"images received": "300", "images processed": "100", "images dropped": "0",
            "message": "initialising (needs a standstill with the prism and a marker)", "last error": "-"}
    line = summary_line("run1.bag", None, {"pose": 0, "orientation": 0, "filtered": 12}, idle)
    assert "the EKF 12 odometry/filtered" in line and "dropped" not in line
    assert line.endswith("no pose because: initialising (needs a standstill with the prism and a marker)")
    assert "reported nothing" in summary_line("run1.bag", 1.0, {"pose": 0}, None)


def test_process_parent_reads_proc():
    assert process_parent(os.getpid()) == os.getppid()
    assert process_parent(2 ** 22 + 12345) is None


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def roscore():
    port = _free_port()
    env = {**os.environ, "ROS_MASTER_URI": f"http://localhost:{port}"}
    core = subprocess.Popen(["roscore", "-p", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=env, start_new_session=True)
    try:
        for _ in range(100):
            if subprocess.run(["rosparam", "list"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL).returncode == 0:
                break
            time.sleep(0.2)
        yield env
    finally:
        os.killpg(core.pid, 2)
        core.wait(timeout=30)


def _launch(cwd, env, *args):
    """roslaunch started in ``cwd`` as from a shell (which sets $PWD there)."""
    return subprocess.run(["roslaunch", "aruco_abs_orient", "postprocess.launch", *args], cwd=str(cwd),
                          env={**env, "PWD": str(cwd)},
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=240)


def _sim_time_set(env) -> bool:
    return subprocess.run(["rosparam", "get", "/use_sim_time"], env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL).returncode == 0


def test_relative_paths_one_line_at_the_end_and_the_master_left_as_it_was(scenario_factory, roscore, tmp_path):
    scen = scenario_factory("tiny")
    site = tmp_path / "site"
    site.mkdir()
    shutil.copy(scen.bag, tmp_path / "run1.bag")
    shutil.copy(scen.markers, site / "markers.yaml")
    (tmp_path / "results").mkdir()
    assert not _sim_time_set(roscore)
    proc = _launch(tmp_path, roscore, "bag:=run1.bag", "markers:=site/markers.yaml", "record:=results/out.bag",
                   "delay:=1.0")
    out = proc.stdout
    assert proc.returncode == 0, out
    ends = [line for line in out.splitlines() if "replay: run1.bag played to its end" in line]
    assert len(ends) == 1, out
    assert "abs_orient processed" in ends[0] and "poses" in ends[0]
    assert "REQUIRED process" not in out and "has died" not in out, out
    assert (tmp_path / "results" / "out.bag").exists()  # record:= relative to the caller, not ~/.ros
    assert not _sim_time_set(roscore), "postprocess.launch left /use_sim_time on a master it did not start"


def test_a_missing_bag_names_the_full_path(roscore, tmp_path):
    (tmp_path / "markers.yaml").write_text("dictionary: DICT_4X4_50\nsize: 0.19\nmarkers:\n"
                                           "  - {id: 1, position: [1.0, 2.0, 1.0]}\n")
    proc = _launch(tmp_path, roscore, "bag:=missing.bag", "markers:=markers.yaml")
    assert f"replay: no bag file {tmp_path / 'missing.bag'}" in proc.stdout, proc.stdout
    assert not _sim_time_set(roscore)


def test_a_launch_with_its_own_master_ends_cleanly_and_leaves_its_master_alone(scenario_factory, tmp_path):
    """roslaunch starts the master itself (no roscore): the master ends with the launch, nothing to restore."""
    scen = scenario_factory("tiny")
    port = _free_port()
    env = {**os.environ, "ROS_MASTER_URI": f"http://localhost:{port}", "PWD": str(tmp_path)}
    proc = subprocess.run(["roslaunch", "-p", str(port), "aruco_abs_orient", "postprocess.launch",
                           f"bag:={scen.bag}", f"markers:={scen.markers}", "delay:=1.0"], cwd=str(tmp_path), env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout
    assert "auto-starting new master" in proc.stdout and "played to its end" in proc.stdout
    assert "removed /use_sim_time" not in proc.stdout and "has died" not in proc.stdout, proc.stdout

"""postprocess.launch as a user runs it (issue 20): real roscore, real roslaunch, a rendered bag.

- relative bag:=, markers:= and record:= are resolved against the directory roslaunch is started in
  (nodes run in ~/.ros); record:= into a directory that does not exist creates it;
- the replay ends with one line (frames, poses, the image topic) and no red ``REQUIRED process has died``;
  exit status 0;
- /use_sim_time is gone again from a roscore that was running before the launch;
- a missing bag is one line naming the full path tried;
- a run that did not do its job ends with the replay's line saying why and its exit status 1 (roslaunch's own
  status is always 0, ros_comm #919): a marker map that does not fit (the node's ERROR, and no map->odom after
  it in the recorded bag), a node stopped on a configuration error (not respawned; the playback stops at
  once), a recorder that died.
Needs tools/env.sh (ROS). About 70 s.
"""
import os
import re
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from aruco_abs_orient.ros.replay import process_parent, static_transforms_before, summary_line


def test_summary_line_says_what_the_node_did_and_why_there_is_no_pose():
    diag = {"images received": "300", "images processed": "240", "images dropped": "60", "message": "tracking 2",
            "image topic": "/camera/image/compressed", "level": "ok"}
    line = summary_line("/data/run1.bag", 20.0, {"pose": 157, "orientation": 120, "filtered": None}, diag)
    assert line.startswith("replay: run1.bag played to its end (20.0 s): abs_orient processed 240 of 300 images "
                           "on /camera/image/compressed")
    assert "(60 dropped while it was busy: a smaller rate:= gives it more time)" in line
    assert "published 157 poses and 120 marker yaws" in line and "EKF" not in line and "no pose" not in line
    idle = {"images received": "300", "images processed": "100", "images dropped": "0",
            "message": "initialising (needs a standstill with the prism and a marker)", "last error": "-"}
    line = summary_line("run1.bag", None, {"pose": 0, "orientation": 0, "filtered": 12}, idle)
    assert "the EKF 12 odometry/filtered" in line and "dropped" not in line
    assert line.endswith("no pose because: initialising (needs a standstill with the prism and a marker)")
    assert "reported nothing" in summary_line("run1.bag", 1.0, {"pose": 0}, None)
    none = dict(diag, **{"images received": "0", "images processed": "0", "images dropped": "0"})
    line = summary_line("run1.bag", 20.0, {"pose": 0}, none, image_topics=["/theta/image/compressed"])
    assert ("no image arrived on /camera/image/compressed: the bag's images are on /theta/image/compressed "
            "(image_topic:= names the base topic)") in line
    wrong = dict(diag, level="error", message="the marker map does not fit this recording: …; map->odom not published")
    line = summary_line("run1.bag", 20.0, {"pose": 12}, wrong, ["the recorder (/recorder) is not running"])
    assert line.endswith("; abs_orient reports an error: the marker map does not fit this recording: …; map->odom not "
                         "published; the recorder (/recorder) is not running")


def test_process_parent_reads_proc():
    assert process_parent(os.getpid()) == os.getppid()
    assert process_parent(2 ** 22 + 12345) is None


def test_the_static_transforms_before_the_start_are_the_last_per_frame_from_every_node(tmp_path):
    """A bag whose /tf_static comes from two nodes and is updated once before the start and once after it:
    playing from the start, the replay publishes what a subscriber would hold then."""
    import rosbag
    import rospy
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    def tf(child, x):
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = "base_link", child
        t.transform.translation.x, t.transform.rotation.w = x, 1.0
        return TFMessage(transforms=[t])

    t0 = 1700000000.0
    written = [("/robot", 0.0, "/tf_static", [tf("camera", 0.1), tf("prism", -0.25)]),
               ("/imu_driver", 1.0, "/tf_static", [tf("imu", 0.3)]),
               ("/robot", 2.0, "/tf", [tf("odom_child", 9.0)]),
               ("/robot", 3.0, "/tf_static", [tf("camera", 0.12)]),
               ("/robot", 10.0, "/tf_static", [tf("camera", 0.5)])]
    path = str(tmp_path / "static.bag")
    with rosbag.Bag(path, "w") as bag:
        for node, dt, topic, msgs in written:
            for m in msgs:
                header = {"callerid": node, "latching": "1" if topic == "/tf_static" else "0", "topic": topic,
                          "type": m._type, "md5sum": m._md5sum, "message_definition": m._full_text}
                bag.write(topic, m, rospy.Time.from_sec(t0 + dt), connection_header=header)
    got = [(t.child_frame_id, round(t.transform.translation.x, 6)) for t in static_transforms_before(path, 5.0)]
    assert got == [("camera", 0.12), ("prism", -0.25), ("imu", 0.3)]
    assert [t.child_frame_id for t in static_transforms_before(path, 0.5)] == ["camera", "prism"]


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
    assert not _sim_time_set(roscore)
    proc = _launch(tmp_path, roscore, "bag:=run1.bag", "markers:=site/markers.yaml", "record:=results/out.bag",
                   "delay:=1.0")  # results/ does not exist: made by record:=
    out = proc.stdout
    assert proc.returncode == 0, out
    ends = [line for line in out.splitlines() if "replay: run1.bag played to its end" in line]
    assert len(ends) == 1, out
    assert "abs_orient processed" in ends[0] and "images on /camera/image/compressed" in ends[0] and "poses" in ends[0]
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


def _failed(out: str) -> str:
    """The replay's last line of a run that failed, after checking roslaunch shows its exit status 1."""
    assert re.search(r"REQUIRED process \[replay-\d+\] has died!\nprocess has died \[pid \d+, exit code 1,", out), out
    lines = [ln for ln in out.replace("\r", "\n").splitlines() if "replay: run1.bag " in ln]
    assert len(lines) == 1, out
    return lines[0]


def test_a_map_that_does_not_fit_is_an_error_and_no_map_odom_follows(scenario_factory, roscore, tmp_path):
    """The scenario's map shifted by 10 m: the node's map check says so (ERROR on /diagnostics), nothing of
    map->odom is published after it (read back from the recorded bag, recorded into a new directory), and the
    replay's last line says it, with exit status 1."""
    import rosbag

    scen = scenario_factory("tiny", n_markers=10, marker_distance=(2.0, 5.0), duration=10.0)  # as test_process's
    shutil.copy(scen.bag, tmp_path / "run1.bag")
    data = yaml.safe_load(Path(scen.markers).read_text())
    for m in data["markers"]:
        m["position"][0] += 10.0
    (tmp_path / "shifted.yaml").write_text(yaml.safe_dump(data))
    offset = yaml.safe_load(Path(scen.hidden).read_text())["camera_time_offset"]
    proc = _launch(tmp_path, roscore, "bag:=run1.bag", "markers:=shifted.yaml", f"time_offset:={offset}",
                   "record:=new/dir/out.bag", "delay:=1.0")
    line = _failed(proc.stdout)
    assert "abs_orient reports an error: the marker map does not fit this recording: " in line, line
    assert re.search(r"the map looks shifted by \(\+(9\.9\d|10\.0\d), ", line), line
    with rosbag.Bag(str(tmp_path / "new" / "dir" / "out.bag")) as bag:
        refused = [t.to_sec() for _, m, t in bag.read_messages(["/diagnostics"]) for s in m.status
                   if s.name == "abs_orient: map check" and s.level == s.ERROR]
        sent = [tr.header.stamp.to_sec() for _, m, _ in bag.read_messages(["/tf"]) for tr in m.transforms
                if tr.child_frame_id == "odom"]
    assert refused, "no ERROR of the map check recorded"
    late = [s for s in sent if s > refused[0] + 0.5]  # stamps are future-dated by 0.1 s; one in flight
    assert not late, (refused[0], late)


def test_a_configuration_error_stops_the_replay_at_once_and_is_not_respawned(scenario_factory, roscore, tmp_path):
    scen = scenario_factory("tiny")
    shutil.copy(scen.bag, tmp_path / "run1.bag")
    t0 = time.monotonic()
    proc = _launch(tmp_path, roscore, "bag:=run1.bag", f"markers:={scen.markers}", "calibration:=missing.yaml",
                   "delay:=1.0")
    line = _failed(proc.stdout)
    assert re.search(r"replay: run1\.bag stopped after \d+ s: abs_orient cannot run: configuration error: "
                     r"~calibration: .*missing\.yaml: cannot read", line), line
    assert "restarting process" not in proc.stdout and proc.stdout.count("[FATAL]") == 1, proc.stdout
    assert time.monotonic() - t0 < 40  # the 8 s bag was not played to its end


def test_a_recorder_that_dies_is_named_in_the_last_line(scenario_factory, roscore, tmp_path):
    import xmlrpc.client

    import rosgraph

    scen = scenario_factory("tiny")
    shutil.copy(scen.bag, tmp_path / "run1.bag")
    args = ["roslaunch", "aruco_abs_orient", "postprocess.launch", "bag:=run1.bag", f"markers:={scen.markers}",
            "record:=out/run1_out.bag", "delay:=2.0", "start:=4"]
    with subprocess.Popen(args, cwd=str(tmp_path), env={**roscore, "PWD": str(tmp_path)}, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True) as launch:
        master = rosgraph.Master("/test_replay", master_uri=roscore["ROS_MASTER_URI"])
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                pid = xmlrpc.client.ServerProxy(master.lookupNode("/recorder")).getPid("/test_replay")[2]
                break
            except Exception:
                time.sleep(0.2)
        os.kill(int(pid), 9)
        out = launch.communicate(timeout=120)[0]
    line = _failed(out)
    assert "the recorder (/recorder) is not running: it died or never started (see its lines above): " in line, line
    assert line.endswith("out/run1_out.bag is incomplete or missing"), line

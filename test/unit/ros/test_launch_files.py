"""The launch files as roslaunch itself loads them (its XML loader, args, includes, $(find), $(eval)):
exactly one owner of map->odom in every mode, the right nodes and parameters. Needs tools/env.sh."""
import os
from pathlib import Path

import pytest
import roslaunch.config
import roslaunch.core
import roslaunch.xmlloader

ROOT = Path(__file__).resolve().parents[3]


def load(name, **args):
    config = roslaunch.config.ROSLaunchConfig()
    loader = roslaunch.xmlloader.XmlLoader()
    loader.ignore_unset_args = False  # as roslaunch's own command line does
    loader.load(str(ROOT / "launch" / name), config, verbose=False,
                                         argv=["roslaunch"] + [f"{k}:={v}" for k, v in args.items()])
    return config


def nodes(config):
    return {(n.package, n.type): n for n in config.nodes}


def map_odom_owners(config):
    """Nodes configured to broadcast map->odom: abs_orient with publish_tf true, the EKF with publish_tf true."""
    owners = []
    for n in config.nodes:
        ns = "/" + n.name
        if (n.package, n.type) == ("aruco_abs_orient", "abs_orient") and config.params[ns + "/publish_tf"].value:
            owners.append(n.name)
        if ((n.package, n.type) == ("robot_localization", "ekf_localization_node")
                and config.params[ns + "/publish_tf"].value and config.params[ns + "/world_frame"].value == "map"):
            owners.append(n.name)
    return owners


@pytest.mark.parametrize("use_ekf", ["true", "false"])
def test_live_launch_has_one_map_odom_owner(use_ekf):
    c = load("live.launch", markers="/m.yaml", calibration="/c.yaml", use_ekf=use_ekf, port="socket://localhost:1")
    assert map_odom_owners(c) == (["ekf_map"] if use_ekf == "true" else ["abs_orient"])
    n = nodes(c)
    assert ("aruco_abs_orient", "static_tfs") in n and c.params["/lever_arms/calibration"].value == "/c.yaml"
    assert ("aruco_abs_orient", "ms60_driver") in n
    # the EKF takes the node's abs_orient/odometry, and the VO's yaw changes relayed from tf
    assert (("aruco_abs_orient", "tf_to_odometry") in n) == (use_ekf == "true")
    assert c.params["/abs_orient/markers"].value == "/m.yaml"


@pytest.mark.parametrize("name", ["live.launch", "postprocess.launch"])
@pytest.mark.parametrize("markers_only", ["false", "true"])
def test_a_robots_own_odometry_reaches_the_ekf(name, markers_only):
    """odom_topic with odom_from_tf:=false: the EKF listens to the robot's topic and nothing relays tf onto it."""
    c = load(name, markers="/m.yaml", bag="/b.bag", use_ms60="false", use_ekf="true", markers_only=markers_only,
             odom_from_tf="false", odom_topic="wheels/odom")
    assert c.params["/ekf_map/" + ("odom0" if markers_only == "true" else "odom2")].value == "wheels/odom"
    assert ("aruco_abs_orient", "tf_to_odometry") not in nodes(c)
    c = load(name, markers="/m.yaml", bag="/b.bag", use_ms60="false", use_ekf="true", markers_only=markers_only)
    assert c.params["/ekf_map/" + ("odom0" if markers_only == "true" else "odom2")].value == "odometry/vo"
    assert ("aruco_abs_orient", "tf_to_odometry") in nodes(c)


def test_live_launch_without_calibration_or_ms60():
    c = load("live.launch", markers="/m.yaml", use_ms60="false")
    n = nodes(c)
    assert ("aruco_abs_orient", "static_tfs") not in n and ("aruco_abs_orient", "ms60_driver") not in n
    assert map_odom_owners(c) == ["abs_orient"]


@pytest.mark.parametrize("use_ekf", ["true", "false"])
def test_postprocess_launch(use_ekf, tmp_path):
    c = load("postprocess.launch", bag="/data/run.bag", markers="/m.yaml", use_ekf=use_ekf, time_offset="0.367",
             record=str(tmp_path / "out.bag"), rate="2.0")
    assert map_odom_owners(c) == (["ekf_map"] if use_ekf == "true" else ["abs_orient"])
    assert c.params["/use_sim_time"].value is True
    n = nodes(c)
    replay = n[("aruco_abs_orient", "replay")]
    assert replay.required and c.params["/replay/bag"].value == "/data/run.bag"
    assert c.params["/replay/rate"].value == 2.0 and c.params["/replay/loop"].value is False
    rec = n[("rosbag", "record")]
    assert f"--output-name={tmp_path / 'out.bag'}" in rec.args and "/odometry/filtered" in rec.args
    assert c.params["/abs_orient/time_offset"].value == 0.367


def test_postprocess_launch_loop_and_no_record():
    c = load("postprocess.launch", bag="/b.bag", markers="/m.yaml", loop="true")
    assert c.params["/replay/loop"].value is True and ("rosbag", "record") not in nodes(c)


def test_relative_paths_are_resolved_against_the_callers_directory(monkeypatch, tmp_path):
    """roslaunch runs nodes in ~/.ros: a relative path must be made absolute from where roslaunch started."""
    monkeypatch.setenv("PWD", str(tmp_path))
    c = load("postprocess.launch", bag="run1.bag", markers="site/markers.yaml", calibration="site/cal.yaml",
             record="results/out.bag")
    assert c.params["/replay/bag"].value == f"{tmp_path}/run1.bag"
    assert c.params["/abs_orient/markers"].value == f"{tmp_path}/site/markers.yaml"
    assert c.params["/abs_orient/calibration"].value == f"{tmp_path}/site/cal.yaml"
    assert f"--output-name={tmp_path}/results/out.bag" in nodes(c)[("rosbag", "record")].args
    c = load("live.launch", markers="site/markers.yaml", calibration="site/cal.yaml", use_ms60="false")
    assert c.params["/lever_arms/calibration"].value == f"{tmp_path}/site/cal.yaml"
    assert c.params["/abs_orient/markers"].value == f"{tmp_path}/site/markers.yaml"
    c = load("abs_orient.launch", markers="/abs/markers.yaml")
    assert c.params["/abs_orient/markers"].value == "/abs/markers.yaml"
    assert c.params["/abs_orient/calibration"].value == ""


def test_ekf_launch_loads_the_package_config():
    c = load("ekf.launch")
    ekf = "/ekf_map/"
    assert c.params[ekf + "world_frame"].value == "map"
    # the node's corrected odometry: its motion differentially, its yaw absolutely; the prism pose: x, y, z
    assert c.params[ekf + "odom0"].value == c.params[ekf + "odom1"].value == "abs_orient/odometry"
    assert c.params[ekf + "odom0_differential"].value is True and c.params[ekf + "odom1_differential"].value is False
    assert c.params[ekf + "odom0_config"].value[:6] == [True] * 5 + [False]
    assert c.params[ekf + "odom1_config"].value[:6] == [False] * 5 + [True]
    assert c.params[ekf + "pose0_config"].value[:6] == [True] * 3 + [False] * 3
    assert os.path.basename(c.params[ekf + "pose0"].value) == "prism_pose"
    assert ekf + "pose1" not in c.params  # the marker yaws are in the node's yaw already
    assert len(c.params[ekf + "process_noise_covariance"].value) == 225
    assert len(c.params[ekf + "initial_estimate_covariance"].value) == 225
    # the VO relayed from tf: its yaw changes only, differentially (the node's odometry has its motion)
    assert c.params[ekf + "odom2"].value == "odometry/vo" and ("aruco_abs_orient", "tf_to_odometry") in nodes(c)
    assert c.params[ekf + "odom2_differential"].value is True
    assert c.params[ekf + "odom2_config"].value == [False] * 5 + [True] + [False] * 9
    assert ekf + "odom3" not in c.params
    c = load("ekf.launch", odom_from_tf="false", odom_topic="wheels/odom")  # a robot's own odometry topic
    assert c.params[ekf + "odom2"].value == "wheels/odom" and ("aruco_abs_orient", "tf_to_odometry") not in nodes(c)
    c = load("ekf.launch", markers_only="true")  # no prism: the relayed odometry and the resections
    assert c.params[ekf + "odom0"].value == "odometry/vo" and ("aruco_abs_orient", "tf_to_odometry") in nodes(c)


def test_north_true_reaches_the_node_as_the_word():
    """roslaunch would read north:=true as a boolean; the node's ~north is the string."""
    for name in ("abs_orient.launch", "live.launch", "postprocess.launch"):
        c = load(name, markers="/m.yaml", bag="/b.bag", use_ms60="false", north="true")
        assert c.params["/abs_orient/north"].value == "true", name


def test_live_launch_starts_the_heading_check_with_a_receiver():
    assert ("aruco_abs_orient", "heading_check") not in nodes(load("live.launch", markers="/m.yaml", use_ms60="false"))
    c = load("live.launch", markers="/m.yaml", use_ms60="false", gnss_heading="gps/heading", gnss_mounting_yaw_deg="90")
    assert ("aruco_abs_orient", "heading_check") in nodes(c)
    assert c.params["/heading_check/gnss_topic"].value == "gps/heading"
    assert c.params["/heading_check/convention"].value == "compass"
    assert c.params["/heading_check/gnss_msg"].value == "Imu"
    assert c.params["/heading_check/mounting_yaw_deg"].value == 90.0


def test_abs_orient_launch_requires_markers():
    with pytest.raises(roslaunch.core.RLException, match="markers"):
        load("abs_orient.launch")


@pytest.mark.parametrize("name,args", [("live.launch", {"use_ms60": "false"}),
                                       ("postprocess.launch", {"bag": "/b.bag"})])
def test_rviz_starts_with_the_package_config_only_when_asked(name, args):
    assert ("rviz", "rviz") not in nodes(load(name, markers="/m.yaml", **args))
    rviz = nodes(load(name, markers="/m.yaml", rviz="true", **args))[("rviz", "rviz")]
    config = rviz.args.split("-d ", 1)[1].strip()
    assert Path(config).resolve() == (ROOT / "rviz" / "abs_orient.rviz").resolve()  # the workspace links here


def test_the_ekf_future_dates_map_odom_as_the_node_does():
    """cfg/ekf.yaml's transform_time_offset = abs_orient's ~transform_tolerance: whichever owns map->odom, a
    consumer sees it valid equally far ahead."""
    ekf = load("ekf.launch").params["/ekf_map/transform_time_offset"].value
    node = load("abs_orient.launch", markers="/m.yaml").params["/abs_orient/transform_tolerance"].value
    assert ekf == node == 0.1

"""ms60_driver parameter validation (no ROS master needed) and the status JSON."""
import json
import math
import os
import re

import numpy as np
import pytest

pytest.importorskip("rospy")
from aruco_abs_orient.geocom.tracker import TrackerError, TrackerStats  # noqa: E402
from aruco_abs_orient.ros.ms60_node import config_from_params, output_from_params, stats_to_json  # noqa: E402


def test_defaults_and_full_station():
    config, frame = config_from_params({})
    assert (config.url, config.baud, config.rate_hz, frame) == ("/dev/ttyUSB0", 115200, 20.0, "map")
    assert config.station is None and config.prism_constant_m is None
    config, _ = config_from_params({"port": "socket://127.0.0.1:5025", "prism_constant_mm": -34.4,
                                    "min_latency_ms": 2, "station": {"x": 1, "y": 2.5, "z": 3,
                                                                     "instrument_height": 1.6, "orientation_deg": 90}})
    assert config.station == (1.0, 2.5, 3.0, 1.6)
    assert config.prism_constant_m == pytest.approx(-0.0344)
    assert config.orientation_rad == pytest.approx(math.pi / 2) and config.min_latency_s == pytest.approx(0.002)
    assert config.byte_timing is False and config.motion_timeout_s == 30.0   # socket://: no serial byte timing
    assert config_from_params({})[0].byte_timing is True and config_from_params({})[0].turn_rate_deg_s == 90.0
    assert config_from_params({"turn_rate_deg_s": 180})[0].turn_rate_deg_s == 180.0
    assert config_from_params({"port": "socket://h:1", "byte_timing": True})[0].byte_timing is True


@pytest.mark.parametrize("params, name", [
    ({"port": ""}, "~port"), ({"port": 5}, "~port"), ({"baud": 115201}, "~baud"), ({"baud": "fast"}, "~baud"),
    ({"baud": 9600.5}, "~baud"), ({"rate": 0}, "~rate"), ({"rate": float("nan")}, "~rate"),
    ({"timeout": -1}, "~timeout"), ({"prism_constant_mm": 5000}, "~prism_constant_mm"),
    ({"frame_id": ""}, "~frame_id"), ({"station": {"x": 1}}, "~station"), ({"station": {"q": 1}}, "~station"),
    ({"station": 3}, "~station"), ({"station": {"x": 1, "y": 2, "z": "a"}}, "~station/z"),
    ({"min_latency_ms": -1}, "~min_latency_ms"), ({"rate": True}, "~rate"),
    ({"motion_timeout": 1.0}, "~motion_timeout"), ({"byte_timing": "yes"}, "~byte_timing"),
    ({"accuracy": {"angle_arcsec": -1}}, "~accuracy/angle_arcsec"), ({"accuracy": {"mm": 1}}, "~accuracy"),
    ({"accuracy": {"distance_mm": "x"}}, "~accuracy/distance_mm"), ({"accuracy": 3}, "~accuracy"),
    ({"turn_rate_deg_s": 0}, "~turn_rate_deg_s"),
])
def test_bad_parameters_name_themselves(params, name):
    with pytest.raises(TrackerError, match=name.replace("~", "~?")):
        config_from_params(params)


def test_accuracy_class_and_the_covariance_message():
    """~accuracy/* set the class (MS60 tracking by default); ms60/prism_with_covariance carries the position and
    its 3×3 covariance, the orientation unobserved."""
    from geometry_msgs.msg import PointStamped

    from aruco_abs_orient.geocom.accuracy import MS60_TRACKING, polar_covariance
    from aruco_abs_orient.ros.ms60_node import prism_with_covariance

    assert config_from_params({})[0].accuracy == MS60_TRACKING
    config, _ = config_from_params({"accuracy": {"distance_mm": 1, "distance_ppm": 2.0, "angle_arcsec": 0.5,
                                                 "prism_mm": 1.5}})
    assert tuple(config.accuracy) == (1.0, 2.0, 0.5, 1.5)
    point = PointStamped()
    point.header.frame_id, point.point.x, point.point.y, point.point.z = "map", 30.0, 40.0, 1.0
    cov = polar_covariance([0, 0, 0], [30, 40, 1], config.accuracy)
    msg = prism_with_covariance(point, cov)
    C = np.array(msg.pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(C[:3, :3], cov)
    assert np.all(np.diag(C)[3:] == 1e6) and msg.pose.pose.position.y == 40.0 and msg.header.frame_id == "map"


def test_status_json_and_the_status_message_that_carries_it():
    from diagnostic_msgs.msg import DiagnosticStatus

    from aruco_abs_orient.ros.ms60_node import _diagnostics, status_values

    stats = TrackerStats("locked", 10, 2, 19.8, {1284: 1}, {1285: 3}, 1, 0, 0, 0, 1, 5, 1, 1.5, -40e-6, "MS60")
    d = json.loads(stats_to_json(stats))
    assert d["state"] == "locked" and d["warnings"] == {"1284": 1} and d["clock_drift_ppm"] == pytest.approx(-40.0)
    # ms60/status: a DiagnosticStatus whose key/values read as they are (no escaped JSON) and parse back to the same
    msg = _diagnostics(DiagnosticStatus(name="ms60_driver: prism tracking"), stats, 20.0)
    shown = {kv.key: kv.value for kv in msg.values}
    assert shown["state"] == "locked" and shown["rate_hz"] == "19.8" and shown["warnings"] == '{"1284": 1}'
    assert status_values(msg) == d and msg.level == DiagnosticStatus.OK and msg.message == "locked, 19.8 Hz"


@pytest.fixture
def master():
    """A real ROS master on a free port (rosmaster --core), its URI."""
    import os
    import socket
    import subprocess
    import time

    import rosgraph

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(["rosmaster", "--core", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=dict(os.environ, ROS_HOSTNAME="localhost"))
    uri = f"http://localhost:{port}/"
    try:
        deadline = time.time() + 20
        while not rosgraph.Master("/test", master_uri=uri).is_online():
            assert time.time() < deadline and proc.poll() is None, "rosmaster did not start"
            time.sleep(0.1)
        yield uri
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _start_driver(uri, tmp_path, port, *params):
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[3] / "scripts" / "ms60_driver"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), ROS_MASTER_URI=uri, ROS_HOSTNAME="localhost",
               ROS_HOME=str(tmp_path))
    return subprocess.Popen([sys.executable, str(script), f"_port:={port}", *params], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.parametrize("sim_time", [True, False])
def test_sim_time_left_on_the_master_is_refused_in_one_line(master, tmp_path, sim_time):
    """postprocess.launch can leave /use_sim_time true on a running master: the driver then ends at
    start-up with one line and status 2 (it used to crash in its thread and stay up, silent). With
    /use_sim_time false it runs (here against the simulator, publishing its status)."""
    import subprocess

    import rosgraph

    from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig
    from aruco_abs_orient.ros.ms60_node import SIM_TIME_MESSAGE

    rosgraph.Master("/test", master_uri=master).setParam("/use_sim_time", sim_time)
    sim = Ms60Simulator(SimConfig(), seed=1)
    proc = _start_driver(master, tmp_path, f"socket://127.0.0.1:{sim.serve_tcp(0)}")
    try:
        out, err = proc.communicate(timeout=8)
    except subprocess.TimeoutExpired:
        proc.terminate()
        out, err = proc.communicate(timeout=10)
    finally:
        sim.close()
    if sim_time:
        assert proc.returncode == 2, err
        lines = [line for line in (out + err).splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].endswith(SIM_TIME_MESSAGE) and "Traceback" not in err
    else:
        assert proc.returncode in (0, -15), err   # ran until terminated
        assert "Traceback" not in err and sim.requests > 10


@pytest.mark.parametrize("params,message", [
    ({"origin": [2600000, 1200000]}, "~origin: expected [E, N, H]"),
    ({"origin": "2600000 1200000 400"}, "~origin: expected [E, N, H]"),
    ({"log": 3}, "~log: expected a file path")])
def test_bad_origin_or_log_names_itself(params, message):
    with pytest.raises(TrackerError, match=re.escape(message)):
        output_from_params(params)


def test_origin_is_subtracted_from_what_is_published_and_the_log_keeps_full_coordinates(master, tmp_path):
    """An instrument set up in LV95 (E 2 600 000): with ~origin, ms60/prism carries values below 10⁴ m and
    the ~log CSV the full coordinates; log − origin = published, to 0.01 mm (the log's resolution)."""
    import subprocess
    import time

    from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig, builtin_track
    from aruco_abs_orient.offline.prism import read_prism

    origin = np.array([2600000.0, 1200000.0, 400.0])
    sim = Ms60Simulator(SimConfig(), track=lambda t: origin + [123.0, 45.0, 6.0] + builtin_track(t), seed=2)
    log = tmp_path / "prism_log.csv"
    proc = _start_driver(master, tmp_path, f"socket://127.0.0.1:{sim.serve_tcp(0)}", "_origin:=[2600000.0, "
                         "1200000.0, 400.0]", f"_log:={log}")
    try:
        echo = subprocess.run(["rostopic", "echo", "-p", "-n", "20", "/ms60/prism"], capture_output=True, text=True,
                              timeout=60, env=dict(os.environ, ROS_MASTER_URI=master, ROS_HOSTNAME="localhost"))
        time.sleep(0.5)
    finally:
        proc.terminate()
        proc.communicate(timeout=10)
        sim.close()
    rows = [line.split(",") for line in echo.stdout.splitlines() if line and not line.startswith("%")]
    published = {round(int(r[2]) * 1e-9, 6): np.array([float(x) for x in r[4:7]]) for r in rows}
    assert len(published) >= 10, echo.stdout + echo.stderr  # of 20 echoed (a loaded machine drops some)
    assert all(np.all(np.abs(p) < 1e4) for p in published.values())
    logged = read_prism(str(log))
    full = {round(t, 6): p for t, p in zip(logged.stamps, logged.positions)}
    assert np.all(logged.positions[:, 0] > 2.6e6)
    common = sorted(set(published) & set(full))
    assert len(common) >= 10
    for t in common:
        np.testing.assert_allclose(full[t] - origin, published[t], atol=1e-5)


def test_prediction_parameters_and_extrapolation():
    """~predict, ~prism_frame, ~predict_max_age; the predicted position: the newest pose moved on at the velocity
    of the two newest, none when the newest is stale or from the future."""
    from aruco_abs_orient.ros.ms60_node import extrapolate, prediction_from_params

    assert prediction_from_params({}) == (True, "prism", 1.0)
    assert prediction_from_params({"predict": False, "prism_frame": "prism_360", "predict_max_age": 0.5}) == (
        False, "prism_360", 0.5)
    for params, name in (({"predict": "yes"}, "~predict"), ({"prism_frame": ""}, "~prism_frame"),
                         ({"predict_max_age": 0}, "~predict_max_age")):
        with pytest.raises(TrackerError, match=name):
            prediction_from_params(params)
    older, newer = (10.0, np.array([1.0, 2.0, 1.5])), (10.2, np.array([1.2, 2.0, 1.5]))  # 1 m/s east
    np.testing.assert_allclose(extrapolate(older, newer, 10.5, 1.0), [1.5, 2.0, 1.5])
    assert extrapolate(older, newer, 11.3, 1.0) is None and extrapolate(older, newer, 10.1, 1.0) is None
    np.testing.assert_allclose(extrapolate(newer, newer, 10.4, 1.0), newer[1])  # one pose: no velocity

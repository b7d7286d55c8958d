"""`aruco-abs-orient process --no-prism --imu-topic` on a rendered bag (issue 15): detection, resection and the
IMU's tilt read back from the bag with rosbags, against the generator's truth."""
import json

import numpy as np

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.offline.cli import main as cli_main
from aruco_abs_orient.synthetic.scenario import Scenario
from aruco_abs_orient.transforms import wrap_angle, yaw_of
from aruco_abs_orient.tum import read_tum

# big markers at 960 px (plumbing scale): the "tiny" preset's hall with 8 markers, an IMU at 50 Hz, a VO whose
# tilt drifts 3°/min, no boresight error (a tight IMU tilt turns an uncalibrated camera rotation into yaw)
SCENARIO = {"n_markers": 8, "imu_rate": 50.0, "vo_tilt_drift_deg_per_min": 3.0, "duration": 6.0, "boresight_deg": 0.0}


def test_process_no_prism_with_an_imu_gives_the_pose_from_the_markers(scenario_factory, tmp_path, capsys):
    scen = scenario_factory("tiny", **SCENARIO)
    sc = Scenario.from_hidden(scen.hidden)
    out = tmp_path / "run"
    code = cli_main(["process", scen.bag, "--markers", scen.markers, "--out", str(out), "--quiet", "--no-prism",
                     "--imu-topic", "/imu/data", "--time-offset", str(sc.config.camera_time_offset)])
    assert code == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "markers only (no prism)"
    assert summary["imu_samples"] > 250
    assert set(summary["tilt_sources"]) == {"imu"}
    assert summary["pipeline_stats"].get("resection_accepted", 0) > 10
    traj = read_tum(str(out / "trajectory.tum"))
    assert len(traj.stamps) > 0.5 * summary["frames"]
    truth = sc.map_T_base(traj.stamps)
    est = traj.transforms
    heading = np.degrees(np.abs(wrap_angle(yaw_of(est[:, :3, :3]) - yaw_of(truth[:, :3, :3]))))
    position = np.linalg.norm(est[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(heading ** 2)) < 0.3       # 960 px, big markers: the plumbing, not the accuracy
    assert np.sqrt(np.mean(position ** 2)) < 0.05


def test_process_no_prism_refuses_a_map_of_two_markers_in_one_line(scenario_factory, tmp_path, capsys):
    scen = scenario_factory("tiny", **SCENARIO)
    full = MarkerMap.load(scen.markers)
    two = tmp_path / "two.yaml"
    MarkerMap(list(full)[:2], full.dictionary, full.frame_id).save(str(two))
    code = cli_main(["process", scen.bag, "--markers", str(two), "--out", str(tmp_path / "o"), "--no-prism"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "at least 3 markers" in err[0], err

"""Split recordings (issue 21): the files of a `rosbag record --split` recording are one recording; a file
that starts while the robot drives (every split after the first) gives poses on its own.

The splits are written by Debian's rosbag (the tool that writes them on a robot) from a rendered
scenario; the truth is the scenario's.
"""
import json
import math
import os

import numpy as np
import pytest
import yaml

from aruco_abs_orient.evaluation import yaw_ape
from aruco_abs_orient.offline.cli import main as cli_main
from aruco_abs_orient.transforms import yaw_of
from aruco_abs_orient.tum import read_tum

rosbag = pytest.importorskip("rosbag", reason="Debian's rosbag writes the split files")


@pytest.fixture(scope="module")
def split(scenario_factory, tmp_path_factory):
    """The ci scenario cut at its middle into run_0.bag and run_1.bag; /tf_static repeated in the second
    (as `rosbag record --split --repeat-latched` does)."""
    scen = scenario_factory("ci")
    d = tmp_path_factory.mktemp("split")
    with rosbag.Bag(scen.bag) as whole:
        t_mid = 0.5 * (whole.get_start_time() + whole.get_end_time())
        static = list(whole.read_messages(topics=["/tf_static"], raw=True))
        with rosbag.Bag(str(d / "run_0.bag"), "w") as b0, rosbag.Bag(str(d / "run_1.bag"), "w") as b1:
            for topic, raw, t in static:
                b1.write(topic, raw, t, raw=True)
            for topic, raw, t in whole.read_messages(raw=True):
                (b0 if t.to_sec() < t_mid else b1).write(topic, raw, t, raw=True)
    with open(scen.hidden) as f:
        offset = str(yaml.safe_load(f)["camera_time_offset"])
    return scen, d, offset, t_mid


def _process(args, out, scen, offset):
    rc = cli_main(["process", *args, "--markers", scen.markers, "--out", str(out), "--quiet", "--time-offset", offset])
    with open(os.path.join(out, "summary.json")) as f:
        return rc, json.load(f), read_tum(os.path.join(out, "trajectory.tum"))


def test_the_files_of_a_split_recording_are_one_recording(split, tmp_path):
    scen, d, offset, _ = split
    _, whole, t_whole = _process([scen.bag], tmp_path / "whole", scen, offset)
    # in reverse order on the command line, and as a quoted glob: the same recording, in time order
    rc, parts, t_parts = _process([str(d / "run_1.bag"), str(d / "run_0.bag")], tmp_path / "parts", scen, offset)
    assert rc == 0 and parts["frames"] == whole["frames"] and parts["frames_with_pose"] == whole["frames_with_pose"]
    np.testing.assert_allclose(t_parts.stamps, t_whole.stamps)
    np.testing.assert_allclose(t_parts.positions, t_whole.positions, atol=1e-9)
    assert len(parts["bag"]) == 2
    rc, globbed, _ = _process([str(d / "run_*.bag")], tmp_path / "glob", scen, offset)
    assert rc == 0 and globbed["frames_with_pose"] == whole["frames_with_pose"]


def test_a_split_that_starts_while_driving_gives_poses(split, tmp_path):
    scen, d, offset, t_mid = split
    rc, s, est = _process([str(d / "run_1.bag")], tmp_path / "second", scen, offset)
    assert rc == 0 and s["no_pose_reason"] == ""
    ref = read_tum(scen.truth)
    assert s["frames_with_pose"] >= 0.95 * s["frames"] - 15          # from its first second on
    ape = yaw_ape(est.stamps, yaw_of(est.rotations), ref.stamps, yaw_of(ref.rotations))
    assert math.degrees(ape.stats.rmse) <= 0.15, ape.stats
    assert s["filter"]["initialised_at"] - (t_mid - float(offset)) < 1.5


def test_a_glob_that_matches_nothing_is_named(split, tmp_path, capsys):
    scen, d, offset, _ = split
    rc = cli_main(["process", str(d / "nope_*.bag"), "--markers", scen.markers, "--out", str(tmp_path), "--quiet"])
    assert rc == 2 and "nope_*.bag: no bag file matches" in capsys.readouterr().err

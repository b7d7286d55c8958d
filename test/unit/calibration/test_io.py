"""calibration.io: the calibration YAML and launch snippet written, and read back (static_tfs's reader)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from aruco_abs_orient.calibration import (
    CalibrationError,
    launch_snippet,
    load_calibration,
    static_tf_yaml,
    write_static_tf_yaml,
)
from aruco_abs_orient.transforms import make_T, rot_x, rot_y, rot_z, rpy_to_matrix

from .common import NOMINAL_CAMERA, PRISM, run, simulate


def test_yaml_round_trip_through_static_tfs(tmp_path):
    truth = np.radians([0.3, -0.2, 0.5])
    cal = run(simulate(truth, duration=40.0, seed=4))
    path = tmp_path / "calibration.yaml"
    write_static_tf_yaml(str(path), cal, NOMINAL_CAMERA, PRISM)
    text = path.read_text()
    assert text.startswith("# written by aruco-abs-orient calibrate\n")
    loaded = load_calibration(str(path))
    true_T = make_T(rpy_to_matrix(*truth) @ NOMINAL_CAMERA[:3, :3], NOMINAL_CAMERA[:3, 3])
    dR = loaded["camera"][:3, :3].T @ true_T[:3, :3]
    assert math.degrees(math.acos(min(1.0, (np.trace(dR) - 1) / 2))) < 0.04
    np.testing.assert_allclose(loaded["camera"][:3, 3], NOMINAL_CAMERA[:3, 3], atol=1e-5)
    np.testing.assert_allclose(loaded["prism"], PRISM, atol=1e-6)
    data = yaml.safe_load(text)
    assert set(data) == {"base_link_to_camera", "base_link_to_prism"}
    assert static_tf_yaml(cal, NOMINAL_CAMERA, PRISM) == text


def test_readout_written_and_read_back(tmp_path):
    """A calibration with a readout writes camera_readout_ms; load_calibration gives it back in s (0 when
    absent, as in the file of test_yaml_round_trip_through_static_tfs); a bad value names the key."""
    cal = run(simulate(np.radians([0.3, -0.2, 0.5]), duration=40.0, seed=4))
    cal.readout, cal.readout_sigma, cal.readout_estimated = 0.0287, 0.0009, True
    path = tmp_path / "calibration.yaml"
    write_static_tf_yaml(str(path), cal, NOMINAL_CAMERA, PRISM)
    data = yaml.safe_load(path.read_text())
    assert data["camera_readout_ms"] == pytest.approx(28.7)
    assert float(load_calibration(str(path))["readout"]) == pytest.approx(0.0287)
    assert cal.report_dict()["readout_ms"] == pytest.approx(28.7)
    del data["camera_readout_ms"]
    path.write_text(yaml.safe_dump(data))
    assert float(load_calibration(str(path))["readout"]) == 0.0
    data["camera_readout_ms"] = -3
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match="camera_readout_ms"):
        load_calibration(str(path))


def test_launch_snippet_uses_tf2_argument_order():
    cal = run(simulate(np.radians([0.3, -0.2, 0.5]), duration=40.0, seed=6))
    text = launch_snippet(cal, NOMINAL_CAMERA, PRISM)
    line = next(x for x in text.splitlines() if 'name="camera_tf"' in x)
    args = line.split('args="')[1].split('"')[0].split()
    assert args[6:] == ["base_link", "camera"]
    x, y, z, yaw, pitch, roll = (float(a) for a in args[:6])
    # rebuild with tf2's convention (yaw about z, then pitch about y, then roll about x)
    R = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
    np.testing.assert_allclose(R, cal.apply(NOMINAL_CAMERA)[:3, :3], atol=1e-5)
    np.testing.assert_allclose([x, y, z], NOMINAL_CAMERA[:3, 3], atol=1e-6)

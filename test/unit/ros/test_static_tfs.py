"""Calibration YAML → lever-arm transforms (ros/static_tfs.py): values, conventions, error messages."""
import math

import numpy as np
import pytest

from aruco_abs_orient.calibration import CalibrationError, load_calibration
from aruco_abs_orient.transforms import transform_points


def _write(tmp_path, text):
    p = tmp_path / "calibration.yaml"
    p.write_text(text)
    return str(p)


def test_calibration_maps_child_coordinates_into_base_link(tmp_path):
    path = _write(tmp_path, "base_link_to_camera: {xyz: [0.1, 0.0, 0.45], rpy_deg: [0, 0, 90]}\n"
                            "base_link_to_prism: {xyz: [-0.05, 0.02, 0.62]}\n")
    arms = load_calibration(path)
    # hand-checked: the camera's +x axis (its image centre) points along base_link +y after a 90° yaw,
    # and the camera origin sits at xyz
    np.testing.assert_allclose(transform_points(arms["camera"], [1.0, 0.0, 0.0]), [0.1, 1.0, 0.45], atol=1e-12)
    np.testing.assert_allclose(transform_points(arms["camera"], [0.0, 0.0, 0.0]), [0.1, 0.0, 0.45], atol=1e-12)
    np.testing.assert_allclose(arms["prism"], np.array([[1, 0, 0, -0.05], [0, 1, 0, 0.02], [0, 0, 1, 0.62],
                                                        [0, 0, 0, 1]]), atol=1e-12)


def test_rpy_is_z_y_x(tmp_path):
    path = _write(tmp_path, "base_link_to_camera: {xyz: [0, 0, 0], rpy_deg: [90, 0, 90]}\n"
                            "base_link_to_prism: {xyz: [0, 0, 1]}\n")
    R = load_calibration(path)["camera"][:3, :3]
    # R = Rz(90)·Rx(90): camera y → (Rx: z) → (Rz: z); camera z → (Rx: -y) → (Rz: +x)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    assert math.isclose(np.linalg.det(R), 1.0)


@pytest.mark.parametrize("text,message", [
    ("base_link_to_prism: {xyz: [0, 0, 1]}\n", "base_link_to_camera: missing"),
    ("base_link_to_camera: {xyz: [0, 0]}\nbase_link_to_prism: {xyz: [0, 0, 1]}\n", "base_link_to_camera.xyz: expected"),
    ("base_link_to_camera: {xyz: [0, 0, 1], rpy_deg: [0, .inf, 0]}\nbase_link_to_prism: {xyz: [0, 0, 1]}\n",
     "base_link_to_camera.rpy_deg"),
    ("base_link_to_camera: {xyz: [0, 0, 1]}\nbase_link_to_prism: {xyz: [true, 0, 1]}\n", "base_link_to_prism.xyz"),
    ("- 1\n- 2\n", "expected a mapping"),
    ("a: [\n", "not valid YAML"),
])
def test_errors_name_the_file_and_key(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(CalibrationError) as e:
        load_calibration(path)
    assert str(e.value).startswith(path) and message in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(str(tmp_path / "nope.yaml"))


def test_reads_what_the_calibration_tool_writes(tmp_path):
    """calibration.write_static_tf_yaml → load_calibration: the calibrated camera mounting, the prism arm."""
    from aruco_abs_orient.calibration import Calibration, write_static_tf_yaml
    from aruco_abs_orient.transforms import make_T, rpy_to_matrix

    z3 = np.zeros(3)
    calib = Calibration(boresight_rpy=np.radians([0.2, -0.1, 0.35]), boresight_sigma=np.radians([0.01] * 3),
                        lever_arm_delta=np.array([0.004, -0.002, 0.001]), lever_arm_sigma=np.full(3, 0.001),
                        lever_arm_estimated=True, cov=np.eye(6), residual_rms_before=0.01, residual_rms_after=0.002,
                        residual_median_before=0.01, residual_median_after=0.002, heading_rms=0.01,
                        variance_factors={}, n_observations=10, n_used=10, n_markers=3, n_heading=5,
                        moving_time=10.0, iterations=3, used=np.ones(10, bool), residuals_before=z3,
                        residuals_after=z3)
    nominal = make_T(rpy_to_matrix(0.0, 0.0, math.radians(90.0)), [0.1, 0.0, 0.8])
    prism = make_T(np.eye(3), [-0.25, 0.05, 1.1])
    path = str(tmp_path / "calibration.yaml")
    write_static_tf_yaml(path, calib, nominal, prism)
    arms = load_calibration(path)
    np.testing.assert_allclose(arms["camera"], calib.apply(nominal), atol=1e-6)  # 5 decimals in the file
    np.testing.assert_allclose(arms["prism"], prism, atol=1e-9)

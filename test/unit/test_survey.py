"""survey.py and `aruco-abs-orient markers`: CSV / GSI-8 / GSI-16 import round trips, corner-point markers
with noise (centre, normal, planarity and size checks), bad input named by file, line and point."""
import math

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.offline.cli import main
from aruco_abs_orient.survey import (
    SurveyError,
    SurveyPoint,
    format_gsi,
    marker_from_corners,
    marker_map_from_points,
    read_csv_points,
    read_gsi,
    read_points,
)

LV95 = np.array([2600000.0, 1200000.0, 400.0])


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _corners(centre, normal_yaw, tilt, spin, size):
    """Four corners (ArUco order seen from the front) of a square of side ``size`` whose face normal is
    horizontal at ``normal_yaw``, tilted by ``tilt`` about its horizontal in-plane axis, turned by ``spin``."""
    n = np.array([math.cos(normal_yaw), math.sin(normal_yaw), 0.0])
    right = np.array([-math.sin(normal_yaw), math.cos(normal_yaw), 0.0])  # seen from the front: right
    R = _rot(right, tilt)
    n, up = R @ n, R @ np.array([0.0, 0.0, 1.0])
    S = _rot(n, spin)
    right, up = S @ right, S @ up
    h = size / 2
    return np.array([centre - h * right + h * up, centre + h * right + h * up, centre + h * right - h * up,
                     centre - h * right - h * up]), n


def test_a_hand_written_gsi16_block_reads_as_its_numbers(tmp_path):
    # E 2 600 123.456 m in mm units (0), N 1 200 456.78912 m in 1/100 mm (8), H 412.3456 m in 1/10 mm (6)
    text = ("*110001+000000000000M7.1 81..00+0000002600123456 82..08+0000120045678912 83..06-0000000004123456\n"
            "*110002+0000000000000012 21.102+0000000012345678 22.102+0000000009000000\n")  # angles only: skipped
    path = tmp_path / "s.gsi"
    path.write_text(text)
    pts = read_gsi(str(path))
    assert [p.name for p in pts] == ["M7.1"]
    np.testing.assert_allclose(pts[0].xyz, [2600123.456, 1200456.78912, -412.3456], rtol=0, atol=1e-9)
    assert pts[0].where == f"{path}:1"


@pytest.mark.parametrize("gsi16,unit,offset,atol", [
    (True, "8", LV95, 0.5e-5), (True, "0", LV95, 0.5e-3), (False, "0", np.zeros(3), 0.5e-3),
    (False, "6", np.zeros(3), 0.5e-4)])
def test_gsi_round_trip(tmp_path, gsi16, unit, offset, atol):
    rng = np.random.default_rng(3)
    xyz = offset + rng.uniform([-80, -80, -5], [80, 80, 5], (12, 3))
    names = [str(i) for i in range(12)]
    path = tmp_path / "p.gsi"
    path.write_text(format_gsi(list(zip(names, xyz)), gsi16=gsi16, unit=unit))
    pts = read_points(str(path))  # detected as GSI
    assert [p.name for p in pts] == names
    np.testing.assert_allclose([p.xyz for p in pts], xyz, rtol=0, atol=atol)


def test_csv_round_trip_through_the_marker_map_with_an_origin(tmp_path):
    rng = np.random.default_rng(5)
    xyz = np.round(LV95 + rng.uniform(-50, 50, (6, 3)), 5)  # as written: 1/100 mm
    path = tmp_path / "p.csv"
    rows = "".join(f"M{i};{p[0]:.5f};{p[1]:.5f};{p[2]:.5f}\n" for i, p in enumerate(xyz))
    path.write_text("# LV95, surveyed from station S1\nid;E;N;H\n" + rows)
    mm = marker_map_from_points(read_points(str(path)), "DICT_4X4_50", 0.19, origin=LV95.tolist())
    np.testing.assert_allclose(mm.positions(), xyz - LV95, atol=1e-8)  # ROS works relative to the origin
    out = tmp_path / "m.yaml"
    mm.save(str(out))
    doc = yaml.safe_load(out.read_text())
    assert doc["origin"] == LV95.tolist()
    np.testing.assert_allclose([m["position"] for m in doc["markers"]], xyz, atol=1e-6)  # full coordinates
    back = MarkerMap.load(str(out))
    np.testing.assert_allclose(back.positions(), xyz - LV95, atol=1e-6)
    np.testing.assert_allclose(back.to_full(back.positions()), xyz, atol=1e-6)


@settings(max_examples=40)
@given(st.floats(-math.pi, math.pi), st.floats(-0.5, 0.5), st.floats(-0.3, 0.3), st.integers(0, 2**31 - 1))
def test_corner_points_with_noise_give_centre_and_normal(yaw, tilt, spin, seed):
    rng = np.random.default_rng(seed)
    centre = LV95 + rng.uniform(-20, 20, 3)
    corners, normal = _corners(centre, yaw, tilt, spin, 0.19)
    noisy = corners + rng.normal(0, 0.001, corners.shape)  # reflectorless, 1 mm
    m = marker_from_corners(7, [SurveyPoint(f"7.{k + 1}", p, f"s.csv:{k + 1}") for k, p in enumerate(noisy)],
                            0.19, 0.01, 0.002)
    assert np.linalg.norm(m.position - centre) < 0.004
    assert math.degrees(math.acos(min(1.0, float(np.dot(m.normal, normal))))) < 3.0  # 1 mm over 19 cm: ~0.5°
    assert m.visible_from(centre + 2 * normal) and not m.visible_from(centre - 2 * normal)


def test_a_corner_off_the_square_is_named(tmp_path):
    corners, _ = _corners(np.array([5.0, 2.0, 1.5]), 0.4, 0.0, 0.0, 0.19)
    corners[2] += np.array([0.0, 0.0, 0.03])  # 3 cm off: a wrong target
    path = tmp_path / "c.csv"
    path.write_text("".join(f"3.{k + 1},{p[0]},{p[1]},{p[2]}\n" for k, p in enumerate(corners)))
    with pytest.raises(SurveyError, match=r"c\.csv:3: point 3\.3: .* expected within 10\.0 mm"):
        marker_map_from_points(read_csv_points(str(path)), "DICT_4X4_50", 0.19)


def test_a_marker_of_another_size_is_rejected():
    corners, _ = _corners(np.zeros(3), 0.0, 0.0, 0.0, 0.30)
    pts = [SurveyPoint(f"4.{k + 1}", p, f"x:{k + 1}") for k, p in enumerate(corners)]
    with pytest.raises(SurveyError, match=r"mean side 300\.0 mm"):
        marker_from_corners(4, pts, 0.19, 0.01, 0.002)
    assert marker_from_corners(4, pts, 0.30, 0.01, 0.002).size == 0.30


def test_gsi_with_an_unknown_word_index_names_file_line_and_word(tmp_path):
    path = tmp_path / "bad.gsi"
    xyz = "81..00+0000000000001000 82..00+0000000000002000 83..00+0000000000000500"
    path.write_text(f"*110001+0000000000000001 {xyz}\n"
                    f"*110002+0000000000000002 {xyz.replace('82..00', '99..00')}\n")
    with pytest.raises(SurveyError, match=r"bad\.gsi:2: word '99\.\.00\+0000000000002000': unknown word index 99"):
        read_gsi(str(path))


def test_duplicate_point_ids_name_both_lines(tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("id,E,N,H\n1,0,0,0\n2,1,0,0\n1,2,0,0\n")
    with pytest.raises(SurveyError, match=r"dup\.csv:4: point id '1' already at .*dup\.csv:2"):
        read_csv_points(str(path))


def test_markers_command_writes_the_map_with_normals(tmp_path, capsys):
    rows = ["12,2600010.000,1200005.000,401.500"]
    corners, normal = _corners(LV95 + [3.0, -4.0, 1.2], 1.0, 0.1, 0.05, 0.19)
    rows += [f"8.{k + 1},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}" for k, p in enumerate(corners)]
    survey = tmp_path / "survey.csv"
    survey.write_text("\n".join(rows) + "\n")
    out = tmp_path / "markers.yaml"
    assert main(["markers", str(survey), "--size", "0.19", "--dictionary", "DICT_5X5_100", "--origin",
                 *map(str, LV95), "--out", str(out)]) == 0
    assert "2 marker(s) (1 from their corners" in capsys.readouterr().out
    mm = MarkerMap.load(str(out))
    assert mm.dictionary == "DICT_5X5_100" and mm.ids == [8, 12] and mm[12].normal is None
    np.testing.assert_allclose(mm[8].normal, normal, atol=2e-3)
    np.testing.assert_allclose(mm[8].position, [3.0, -4.0, 1.2], atol=1e-4)
    bad = tmp_path / "bad.gsi"
    bad.write_text("*110001+0000000000000001 77..00+0000000000001000\n*110001+000000000000000\n")
    assert main(["markers", str(bad), "--size", "0.19", "--out", str(tmp_path / "x.yaml")]) == 2
    assert f"{bad}:2: word" in capsys.readouterr().err

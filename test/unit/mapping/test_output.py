"""The mapping's files: the markers YAML read back by the MarkerMap every command uses (positions, covariance, σ
of the worst axis, normals; the surveyor's fields beside them), the report's table and the plan."""

from __future__ import annotations

import math

import numpy as np
import yaml

from aruco_abs_orient.camera import SINGLE_CENTRE
from aruco_abs_orient.mapping import MappedMarker, MappingResult
from aruco_abs_orient.mapping.compare import compare_maps
from aruco_abs_orient.mapping.output import mapped_map, mapped_yaml, plot_plan, report_markdown
from aruco_abs_orient.markers import MarkerMap


def _result() -> MappingResult:
    rot = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    cov = rot @ np.diag([3e-3, 1e-3, 0.5e-3]) ** 2 @ rot.T          # 3 mm along (0.8, 0.6, 0)
    markers = {
        4: MappedMarker(4, np.array([1.0, 2.0, 1.5]), cov, np.array([0.0, -1.0, 0.0]), math.radians(0.4), views=120,
                        baseline=9.5, ranges=(2.5, 8.0), redundancy=231.0, test=1.1, test_limit=2.5),
        9: MappedMarker(9, np.array([-3.0, 0.5, 2.0]), np.eye(3) * 1e-6, None, views=80, baseline=6.0,
                        ranges=(3.0, 6.0), redundancy=150.0, test=0.9, test_limit=2.6,
                        control=(np.array([-3.001, 0.5, 2.0]), 0.4, True)),
        12: MappedMarker(12, np.full(3, np.nan), np.full((3, 3), np.nan), views=4, status="refused",
                         reason="seen in 4 images (need ≥ 10): drive past it"),
        15: MappedMarker(15, np.array([2.0, -4.0, 1.0]), np.eye(3) * 4e-6, views=60, status="left out",
                         reason="it disagrees with the other markers"),
    }
    return MappingResult(markers, np.zeros(3), np.full(3, np.nan), 0.03, float("nan"), 0.0, float("nan"),
                         SINGLE_CENTRE, {"markers": 1.0}, "vo_yaw", 500, 480,
                         drive=np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 0.0, 0.0]]))


def test_the_yaml_is_a_marker_map_with_the_surveyors_fields(tmp_path):
    res = _result()
    mm = mapped_map(res, 0.19, "DICT_4X4_50", origin=[2600000.0, 1200000.0, 400.0], sizes={9: 0.3})
    assert mm.ids == [4, 9]                                         # refused and left out are not in the map
    path = tmp_path / "markers.yaml"
    path.write_text(mapped_yaml(res, mm, "run.bag"))
    back = MarkerMap.load(str(path))
    assert np.allclose(back[4].position, [1.0, 2.0, 1.5]) and back[9].size == 0.3 and back[4].size == 0.19
    assert np.allclose(back[4].covariance, res.markers[4].cov, atol=1e-12)
    assert back[4].sigma == np.float64(0.003) or abs(back[4].sigma - 0.003) < 1e-9   # the worst axis
    assert np.allclose(back[4].normal, [0, -1, 0]) and back[9].normal is None
    doc = yaml.safe_load(path.read_text())
    assert doc["origin"] == [2600000.0, 1200000.0, 400.0] and doc["markers"][0]["position"][0] == 2600001.0
    four = doc["markers"][0]
    # √(0.8² 9 + 0.6² 1), √(0.6² 9 + 0.8² 1)
    assert four["ellipsoid_3sigma_mm"] == [9.0, 3.0, 1.5] and four["sigma_mm"] == [2.47, 1.97, 0.5]
    assert np.allclose(np.abs(four["ellipsoid_axes"][0]), [0.8, 0.6, 0.0])
    assert four["normal_sigma_deg"] == 0.4 and four["views"] == 120 and four["range_m"] == [2.5, 8.0]
    assert doc["markers"][1]["control"] == {"survey": [2599996.999, 1200000.5, 402.0], "difference_sigma": 0.4,
                                            "used": True}
    head = path.read_text().splitlines()
    assert head[0].startswith("# written by aruco-abs-orient map from run.bag: 2 markers")
    assert any(line.startswith("# marker 12 refused: seen in 4 images") for line in head)
    assert any(line.startswith("# marker 15 left out: it disagrees") for line in head)
    assert not compare_maps(back, mm).moves[0].moved                # read back: the same map


def test_the_report_and_the_plan(tmp_path):
    res = _result()
    mm = mapped_map(res, 0.19, "DICT_4X4_50")
    text = report_markdown(res, "run.bag", "plan.png", compare_maps(mm, mm), elapsed=3.2)
    assert "2 markers placed, 1 refused (seen too little), 1 left out" in text and "3.2 s" in text
    row = next(line for line in text.splitlines() if line.startswith("| 4 |"))
    assert "| mapped | 120 | 2.5–8.0 | 9.5 | 2.5 / 2.0 / 0.5 | 9.0 / 3.0 / 1.5 | 0.40 | 231 | 1.10 (≤ 2.50) |" in row
    nine = next(line for line in text.splitlines() if line.startswith("| 9 |"))
    assert "control: 0.4 σ from its survey, used" in nine
    assert "![the map from above](plan.png)" in text and "## Compared with the old map" in text
    png = plot_plan(res, str(tmp_path / "plan.png"), "markers.yaml")
    with open(png, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10000

"""markers.py: the marker map YAML of doc/design.md §3, its validation (file and field named) and round trip."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.markers import Marker, MarkerMap, MarkerMapError
from aruco_abs_orient.transforms import rotvec_to_matrix

GOOD = """dictionary: DICT_4X4_50
size: 0.19
frame_id: map
markers:
  - {id: 3, position: [12.031, 4.210, 1.352]}
  - {id: 7, position: [3.5, -2.0, 1.1], size: 0.30, sigma: 0.004}
"""


def test_the_design_example_loads_with_defaults_and_overrides(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(GOOD)
    mm = MarkerMap.load(str(path))
    assert mm.ids == [3, 7] and len(mm) == 2 and 3 in mm and 4 not in mm
    assert mm.dictionary == "DICT_4X4_50" and mm.frame_id == "map"
    assert mm[3].size == 0.19 and mm[7].size == 0.30
    assert mm[3].sigma == 0.002 and mm[7].sigma == 0.004  # survey σ: default and per marker
    np.testing.assert_allclose(mm.positions(), [[12.031, 4.210, 1.352], [3.5, -2.0, 1.1]])


def test_save_load_round_trip(tmp_path):
    src = tmp_path / "a.yaml"
    src.write_text(GOOD)
    mm = MarkerMap.load(str(src))
    mm.save(str(tmp_path / "b.yaml"))
    back = MarkerMap.load(str(tmp_path / "b.yaml"))
    assert back.ids == mm.ids and back.dictionary == mm.dictionary
    for m in mm:
        assert back[m.id].size == m.size and back[m.id].sigma == m.sigma
        np.testing.assert_allclose(back[m.id].position, m.position)
    (tmp_path / "g.yaml").write_text("grid: LV95\norigin: [2600000, 1200000, 500]\n" + GOOD)
    assert MarkerMap.load(str(tmp_path / "g.yaml")).to_dict()["grid"] == "LV95"


@pytest.mark.parametrize("text,message", [
    ("markers: [", "not valid YAML"),
    ("- 1\n- 2\n", "expected a mapping"),
    ("size: 0.2\nmarkers: []\n", "markers: expected a non-empty list"),
    ("size: 0.2\nmarkers:\n  - {id: -1, position: [0, 0, 0]}\n", r"markers\[0\]\.id: expected a non-negative integer"),
    ("size: 0.2\nmarkers:\n  - {id: true, position: [0, 0, 0]}\n", r"markers\[0\]\.id"),
    ("size: 0.2\nmarkers:\n  - {id: 1, position: [0, 0]}\n", r"markers\[0\]\.position: expected \[x, y, z\]"),
    ("size: 0.2\nmarkers:\n  - {id: 1, position: [0, .nan, 0]}\n", r"markers\[0\]\.position"),
    ("markers:\n  - {id: 1, position: [0, 0, 0]}\n", r"markers\[0\]\.size: no size here and no top-level"),
    ("size: -0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0]}\n", "size: expected a positive number"),
    ("size: 0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0]}\n  - {id: 1, position: [1, 0, 0]}\n",
     "id 1 appears twice"),
    ("dictionary: DICT_9X9_1\nsize: 0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0]}\n",
     "dictionary: unknown ArUco dictionary 'DICT_9X9_1'"),
    ("grid: CH1903\nsize: 0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0]}\n", "grid: unknown grid 'CH1903'"),
    ("size: 0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0], covariance_mm2: [1, 0, 0, 1, 0]}\n",
     r"markers\[0\]\.covariance_mm2: expected \[xx, xy, xz, yy, yz, zz\] in mm²"),
    ("size: 0.2\nmarkers:\n  - {id: 1, position: [0, 0, 0], covariance_mm2: [1, 2, 0, 1, 0, 1]}\n",
     r"markers\[0\]\.covariance_mm2: not positive definite"),
])
def test_bad_maps_name_the_file_and_the_field(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MarkerMapError, match=message) as e:
        MarkerMap.load(str(path))
    assert str(e.value).startswith(str(path))


def test_a_mapped_maps_covariance_and_fields_for_the_surveyor(tmp_path):
    """``aruco-abs-orient map``'s per-marker covariance is read (mm² → m²) and written back; its other fields are
    accepted."""
    path = tmp_path / "mapped.yaml"
    path.write_text(GOOD.replace("{id: 3, position: [12.031, 4.210, 1.352]}",
                                 "{id: 3, position: [12.031, 4.210, 1.352], sigma: 0.003, covariance_mm2: [9, 1, 0, 4, "
                                 "0, 1], views: 120, ellipsoid_3sigma_mm: [9.1, 5.9, 3.0], redundancy: 231.5}"))
    mm = MarkerMap.load(str(path))
    np.testing.assert_allclose(mm[3].covariance, [[9e-6, 1e-6, 0], [1e-6, 4e-6, 0], [0, 0, 1e-6]])
    assert mm[7].covariance is None
    mm.save(str(tmp_path / "back.yaml"))
    back = MarkerMap.load(str(tmp_path / "back.yaml"))
    np.testing.assert_allclose(back[3].covariance, mm[3].covariance)


def test_missing_file_is_named():
    with pytest.raises(MarkerMapError, match="/nope/m.yaml: cannot read"):
        MarkerMap.load("/nope/m.yaml")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0005, 0.05), min_size=3, max_size=3), st.lists(st.floats(-1, 1), min_size=6, max_size=6),
       st.floats(0.5, 40.0))
def test_the_sigma_a_bearing_sees_is_the_widest_spread_across_its_sight_line(axes, angles, distance):
    """sigma_across: the larger 1-σ of the covariance over the directions across the sight line from the point,
    found here by trying 3600 of them; a covariance elongated along the sight line gives its width only."""
    R = rotvec_to_matrix(np.array(angles[:3]) * math.pi)
    C = R @ np.diag(np.square(axes)) @ R.T
    sight = np.array(angles[3:]) + [0.0, 0.0, 1e-3]
    sight /= np.linalg.norm(sight)
    m = Marker(1, np.array([3.0, -2.0, 1.5]), 0.19, max(axes), None, C)
    point = m.position - distance * sight
    e1 = np.cross(sight, [1.0, 0.0, 0.0] if abs(sight[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(sight, e1)
    phi = np.linspace(0.0, math.pi, 3600, endpoint=False)
    u = np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2)
    widest = math.sqrt(np.einsum("ni,ij,nj->n", u, C, u).max())
    assert m.sigma_across(point) == pytest.approx(widest, rel=1e-5)
    assert m.sigma_across(point) <= max(axes) * (1 + 1e-9)
    along = Marker(1, m.position, 0.19, 0.03, None, 0.03 ** 2 * np.outer(sight, sight) + 0.002 ** 2 * np.eye(3))
    assert along.sigma_across(point) == pytest.approx(0.002)


def test_without_a_covariance_or_a_sight_line_the_sigma_is_the_surveys():
    m = Marker(1, np.array([1.0, 2.0, 3.0]), 0.19, 0.004)
    assert m.sigma_across([0.0, 0.0, 0.0]) == 0.004
    mapped = m._replace(covariance=np.diag([1e-4, 1e-6, 1e-6]))
    assert mapped.sigma_across(None) == 0.004 and mapped.sigma_across(m.position) == 0.004

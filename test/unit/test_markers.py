"""markers.py: the marker map YAML of doc/design.md §3, its validation (file and field named) and round trip."""
import numpy as np
import pytest

from aruco_abs_orient.markers import MarkerMap, MarkerMapError

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

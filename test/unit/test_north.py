"""north.py: the meridian convergence of LV95/LV03, UTM and Gauss-Krüger, closed form against PROJ (pyproj) and
against the geodesic azimuth of a grid-north step (an independent truth: no convergence formula involved), and
NorthReference's contract."""
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.north import NorthError, NorthReference, convergence, convergence_closed_form, parse_grid

# (grid, E range, N range): each grid's area, to its edges (UTM zones ±3° wide, GK ±1.5°, Switzerland)
AREAS = [("UTM32N", (200000, 800000), (4500000, 6500000)), ("UTM 33S", (200000, 800000), (5500000, 8000000)),
         ("EPSG:25832", (200000, 800000), (5000000, 6200000)), ("GK3", (3400000, 3600000), (5250000, 6100000)),
         ("EPSG:31468", (4400000, 4600000), (5250000, 6000000)), ("LV95", (2480000, 2840000), (1070000, 1300000)),
         ("LV03", (480000, 840000), (70000, 300000))]


@st.composite
def grid_points(draw):
    name, (e0, e1), (n0, n1) = draw(st.sampled_from(AREAS))
    return parse_grid(name), draw(st.floats(e0, e1)), draw(st.floats(n0, n1))


def test_hand_checked_values():
    """γ ≈ Δλ·sin φ to first order: UTM 32N at 12.0°E, 47.0°N (3° east of 9°E): 2.194°, the higher orders add
    0.03°; 3° west of it the same negative; south of the equator the sign turns."""
    import pyproj

    for lon, lat, zone in ((12.0, 47.0, "UTM32N"), (6.0, 47.0, "UTM32N"), (18.0, -30.0, "UTM33S")):
        e, n = pyproj.Proj(f"EPSG:{parse_grid(zone).epsg}")(lon, lat)
        gamma = math.degrees(convergence_closed_form(parse_grid(zone), e, n))
        first_order = (lon - (9.0 if zone == "UTM32N" else 15.0)) * math.sin(math.radians(lat))
        assert gamma == pytest.approx(first_order, abs=0.05)
        assert math.copysign(1, gamma) == math.copysign(1, first_order)


@given(grid_points())
def test_closed_form_is_proj(point):
    """Without pyproj the node computes what PROJ computes, within 1e-8 rad, anywhere in each grid."""
    grid, e, n = point
    gamma, source = convergence(grid, e, n)
    assert source.startswith("pyproj")
    assert convergence_closed_form(grid, e, n) == pytest.approx(gamma, abs=1e-8)


@given(grid_points())
def test_geodesic_truth(point):
    """A step of 10 m along grid north, turned into latitude and longitude by PROJ and measured on the ellipsoid
    (pyproj.Geod's inverse geodesic): its true azimuth is γ (grid north is γ clockwise from true north)."""
    import pyproj

    grid, e, n = point
    proj = pyproj.Proj(f"EPSG:{grid.epsg}")
    lon0, lat0 = proj(e, n - 5.0, inverse=True)
    lon1, lat1 = proj(e, n + 5.0, inverse=True)
    geod = pyproj.CRS(f"EPSG:{grid.epsg}").get_geod()
    azimuth, _, _ = geod.inv(lon0, lat0, lon1, lat1)
    assert math.radians(azimuth) == pytest.approx(convergence_closed_form(grid, e, n), abs=2e-7)


def test_names_and_errors():
    assert parse_grid("utm 32n").epsg == 32632 and parse_grid("EPSG:32733").false_northing == 1e7
    assert parse_grid("lv95").kind == "swiss" and parse_grid("GK4").false_easting == 4.5e6
    for bad in ("UTM61N", "GK7", "EPSG:4326", "Mercator", ""):
        with pytest.raises(NorthError, match="grid"):
            parse_grid(bad)
    with pytest.raises(NorthError, match="central meridian"):
        convergence(parse_grid("UTM32N"), 2600000.0, 1200000.0)  # LV95 coordinates given as UTM
    with pytest.raises(NorthError, match="Bern"):
        convergence(parse_grid("LV95"), 600000.0, 5200000.0)


def test_north_reference():
    """True north needs the grid and the origin; grid north states γ when it can; the turn is −γ for true."""
    with pytest.raises(NorthError, match="~north: true north needs the marker map's 'grid'"):
        NorthReference.make("true", None, [2600000.0, 1200000.0, 500.0], "~")
    with pytest.raises(NorthError, match="needs the map's 'origin'"):
        NorthReference.make("true", "LV95", None)
    with pytest.raises(NorthError, match="expected 'grid' or 'true'"):
        NorthReference.make("magnetic", "LV95", [2600000.0, 1200000.0, 0.0])
    assert NorthReference.make("grid", None, None).turn == 0.0
    grid = NorthReference.make("grid", "UTM32N", [731000.0, 5210000.0, 400.0])
    true = NorthReference.make("true", "UTM32N", [731000.0, 5210000.0, 400.0])
    assert grid.turn == 0.0 and grid.gamma == true.gamma
    assert math.degrees(true.turn) == pytest.approx(-2.2235, abs=1e-4)
    assert "true north (UTM32N, meridian convergence at the origin +2.2235°" in true.describe()
    assert "true heading = grid heading - 2.2235°" in grid.describe()


@pytest.mark.parametrize("grid, origin", [("LV95", [2820000.0, 1180000.0, 450.0]),     # far east of Bern: +2.0°
                                          ("UTM32N", [750000.0, 5350000.0, 300.0]),   # 3.4° east of 9°E: +2.5°
                                          ("UTM33S", [230000.0, 6200000.0, 50.0])])   # west of 15°E, south: +1.9°
def test_heading_referred_to_true_north_agrees_with_a_geodesic_truth(grid, origin):
    """The node's ~north: true path (NorthReference.turn_map for the marker map, turn_point for each prism position)
    in front of the real pipeline on an exact world (test_pipeline's: base_link 3-5 m from four markers, the map
    written in full grid coordinates around ``origin``): the heading it gives is the true one, within 0.01°. The
    truth: base_link's forward direction, a 1 m step from its grid position, turned into latitude and longitude by
    PROJ and measured on the ellipsoid (pyproj.Geod): its azimuth α, true ENU yaw 90° − α."""
    import pyproj

    from aruco_abs_orient.markers import MarkerMap
    from aruco_abs_orient.pipeline import AbsOrientPipeline, PipelineParams

    from .test_pipeline import BASE, BASE_T_CAMERA, BASE_T_PRISM, MARKERS, ODOM_T_BASE, PRISM, YAW, observation

    o = np.array(origin)
    data = {"size": 0.19, "origin": origin, "grid": grid,
            "markers": [{"id": i, "position": (o + p).tolist()} for i, p in MARKERS.items()]}
    north = NorthReference.make("true", grid, origin)
    pipe = AbsOrientPipeline(north.turn_map(MarkerMap.from_dict(data)), BASE_T_CAMERA, BASE_T_PRISM, PipelineParams())
    for t in np.arange(0.0, 3.01, 0.1):
        pipe.add_prism(float(t), *north.turn_point(PRISM, np.eye(3) * 1e-6))
    for t in (1.0, 1.1, 1.2):  # the bearings are the camera's, whatever the map's frame
        res = pipe.process_observations(t, [observation(i) for i in MARKERS], ODOM_T_BASE)
    assert res.initialised
    heading = float(res.yaw)
    proj = pyproj.Proj(f"EPSG:{parse_grid(grid).epsg}")
    e, n = o[0] + BASE[0], o[1] + BASE[1]
    lon0, lat0 = proj(e, n, inverse=True)
    lon1, lat1 = proj(e + math.cos(YAW), n + math.sin(YAW), inverse=True)
    azimuth, _, _ = pyproj.CRS(f"EPSG:{parse_grid(grid).epsg}").get_geod().inv(lon0, lat0, lon1, lat1)
    true_yaw = math.radians(90.0 - azimuth)
    assert abs(math.degrees(north.gamma)) > 1.5  # far from the central meridian
    assert abs(math.degrees(math.remainder(heading - true_yaw, 2 * math.pi))) < 0.01
    assert abs(math.degrees(math.remainder(heading - YAW, 2 * math.pi))) > 1.5  # grid north would be this far off
    # and the position, in the turned frame, is base_link's turned about the origin
    np.testing.assert_allclose(res.map_T_base[:3, 3], north.turn_point(BASE)[0], atol=1e-6)

"""mapcheck.py: does the marker map fit the recording? Against the generator's worlds without rendering: exact
bearings of the markers each camera pose sees (``Scenario.marker_bearings``, 0.02° noise, the unpublished 0.3°
boresight error left in), the scenario's drifting odometry and its noisy, gappy prism track. The right map fits
(whatever the seed, layout, drift or time-offset error); a map rotated by 90° or 5°, shifted by 10 m, in
millimetres, with a wrong origin, or another site's, does not, each named as what it is. About 10 s."""
import math
import re
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.mapcheck import (
    DOES_NOT_FIT,
    FITS,
    UNDETERMINED,
    MapCheckParams,
    RollingMapCheck,
    Sightings,
    SightingSample,
    check_map,
)
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario


def _scenario(preset="ci", **changes) -> Scenario:
    return Scenario(replace(PRESETS[preset], **changes))


def _sightings(scen: Scenario, time_error: float = 0.0, every: int = 2, until=None) -> Sightings:
    """What a run sees: every ``every``-th frame's markers (true time; the prism looked up ``time_error`` s off)."""
    c = scen.config
    t = c.start_time + np.arange(0.0, c.duration if until is None else until, 1.0 / c.fps)[::every]
    frame, ids, u = scen.marker_bearings(t, noise=math.radians(0.02), rng=np.random.default_rng(c.seed))
    return Sightings(t[frame] + time_error, ids, u, scen.odom_T_base(t)[frame, :3, :3])


def _check(scen: Scenario, map_xyz=None, sightings=None, origin=None):
    map_xyz = {m.id: m.position for m in scen.markers} if map_xyz is None else map_xyz
    return check_map(_sightings(scen) if sightings is None else sightings, (scen.prism.stamps, scen.prism.positions),
                     map_xyz, scen.base_T_camera_nominal, scen.base_T_prism[:3, 3], origin=origin)


def _rotated(map_xyz, deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {i: np.array([c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]]) for i, p in map_xyz.items()}


@settings(max_examples=10)
@given(seed=st.integers(0, 10_000), preset=st.sampled_from(["ci", "ci-realistic", "tiny"]), world=st.sampled_from([
    {}, {"n_markers": 5, "marker_distance": (3.0, 10.0)}, {"vo_yaw_drift_deg_per_min": -10.0},
    {"track_radii": (6.0, 4.0), "marker_height": (0.0, 3.0)}, {"roll_pitch_deg": 0.0, "speed": 1.5}]),
    time_error=st.sampled_from([0.0, 0.3, -0.73]))
def test_the_right_map_fits_whatever_the_world_and_a_wrong_time_offset(seed, preset, world, time_error):
    """A wrong --time-offset (here up to the 0.73 s of a wrong sign) is the self-checks' finding, not the map's."""
    scen = _scenario(preset, seed=seed, **world)
    v = _check(scen, sightings=_sightings(scen, time_error))
    assert v.status == FITS, v.message
    assert v.details["median_off_deg"] < 0.5 and "\n" not in v.message


@pytest.mark.parametrize("seed", [3, 5])
@pytest.mark.parametrize("change,expected", [
    (lambda m, o: (_rotated(m, 90.0), o), r"the map looks rotated by \+(8[89]|9[01])\.\d° about z around its origin "
                                          r"\(E and N exchanged"),
    (lambda m, o: (_rotated(m, 5.0), o), r"the map looks rotated by \+[456]\.\d° about z"),
    (lambda m, o: ({i: p + [10.0, 0.0, 0.0] for i, p in m.items()}, o), r"the map looks shifted by \(\+10\.0\d, "),
    (lambda m, o: ({i: p * 1000.0 for i, p in m.items()}, o), r"the map looks scaled by (99\d|100\d|101\d)(\.\d)? "
                                                               r"\(millimetres written as metres\?\)"),
    (lambda m, o: ({i: p - [2600000.0, 1200000.0, 400.0] for i, p in m.items()}, [2600000.0, 1200000.0, 400.0]),
     r"2863\.6 km off: a wrong origin \(the map's, \(2600000, 1200000, 400\), and the MS60 driver's ~origin"),
    (lambda m, o: (dict(zip(m, (x.position for x in _scenario(seed=99).markers))), o), r"another site's map"),
], ids=["rotated 90", "rotated 5", "shifted 10 m", "mm for m", "wrong origin", "another site"])
@pytest.mark.parametrize("preset", ["ci", "ci-realistic"])  # level odometry; tilted 1.5° (its tilt is estimated)
def test_a_wrong_map_is_refused_by_name(seed, change, expected, preset):
    scen = _scenario(preset, seed=seed)
    wrong, origin = change({m.id: m.position.copy() for m in scen.markers}, None)
    v = _check(scen, wrong, origin=origin)
    assert v.status == DOES_NOT_FIT, v.message
    assert v.message.startswith("the marker map does not fit this recording: markers ")
    assert re.search(expected, v.message), v.message


def test_one_moved_marker_is_left_to_the_self_checks_and_named():
    scen = _scenario(seed=3)
    m = {x.id: x.position.copy() for x in scen.markers}
    moved = sorted(m)[2]
    m[moved] = m[moved] + [1.0, 0.0, 0.0]
    v = _check(scen, m)
    assert v.status == FITS, v.message
    assert f"marker {moved} is seen 1.0" in v.message and "moved or wrongly surveyed" in v.message


def test_standing_still_a_wrong_map_is_refused_but_not_named():
    """From one place the markers cannot be placed: the bearings between them say the map is wrong, not how."""
    scen = _scenario(seed=3, standstill=6.0)
    still = _sightings(scen, until=5.0)
    assert np.ptp(scen.prism_position(still.time), axis=0).max() < 0.05
    right = _check(scen, sightings=still)
    assert right.status == FITS, right.message
    v = _check(scen, _rotated({x.id: x.position for x in scen.markers}, 90.0), sightings=still)
    assert v.status == DOES_NOT_FIT and "too few sightings from different places to say how" in v.message, v.message


def test_too_few_sightings_give_no_verdict():
    scen = _scenario(seed=3)
    s = _sightings(scen)
    few = Sightings(*(a[len(s.time) // 2:len(s.time) // 2 + 10] for a in s))
    v = _check(scen, sightings=few)
    assert v.status == UNDETERMINED and "not checked yet: 10 sighting(s)" in v.message
    assert _check(scen, {999: np.zeros(3)}).status == UNDETERMINED  # no marker of the map seen


def test_the_rolling_check_of_a_node_keeps_its_window():
    scen = _scenario(seed=5)
    s = _sightings(scen)
    rolling = RollingMapCheck({m.id: m.position for m in scen.markers}, scen.base_T_camera_nominal,
                              scen.base_T_prism[:3, 3], window=8.0, params=MapCheckParams(min_sightings=20))
    assert rolling.check().status == UNDETERMINED
    for t, p in zip(scen.prism.stamps, scen.prism.positions):
        rolling.add_prism(t, p)
    for row in zip(*s):
        rolling.add_sighting(*row)
    assert rolling.check().status == FITS
    assert len(rolling._sightings) < len(s.time) and rolling._sightings[0][0] >= s.time[-1] - 8.0


def test_a_long_run_is_sampled_evenly_in_bounded_memory():
    sample = SightingSample(size=100)
    for k in range(100_000):  # an hour's sightings, one per 36 ms
        sample.add(0.036 * k, k % 7, [1.0, 0.0, 0.0], np.eye(3))
    s = sample.sightings()
    assert 100 <= len(s.time) < 200 and s.time[0] == 0.0 and s.time[-1] > 0.9 * 0.036 * 100_000
    assert np.ptp(np.diff(s.time)) < 1e-6  # evenly spaced

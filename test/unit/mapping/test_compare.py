"""Two maps compared: a marker knocked between two recordings is found (the generator's ``moved_marker``: the
same site, one marker 5 cm off), the others are not; the test's arithmetic against hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest

from aruco_abs_orient.mapping import map_markers
from aruco_abs_orient.mapping.compare import compare_maps
from aruco_abs_orient.mapping.model import chi2_quantile
from aruco_abs_orient.mapping.output import mapped_map
from aruco_abs_orient.markers import Marker, MarkerMap

from .common import recording, scenario
from .test_network import SMALL_LOOP


def _mapped(sc):
    rec, corners = recording(sc)
    res = map_markers(rec, corners, size=sc.config.marker_size, readout=sc.config.rolling_shutter_readout)
    return mapped_map(res, sc.config.marker_size, sc.config.dictionary)


def test_a_marker_knocked_between_two_recordings_is_reported():
    first = scenario("demo", **dict(SMALL_LOOP, seed=3))
    second = scenario("demo", **dict(SMALL_LOOP, seed=3, moved_marker=(0.03, 0.0, -0.04)))
    knocked = first.markers.ids[0]
    old, new = _mapped(first), _mapped(second)
    assert knocked in old and knocked in new
    comp = compare_maps(new, old)
    assert [m.id for m in comp.moved] == [knocked], [(m.id, m.distance, m.chi) for m in comp.moves]
    move = comp.moved[0]
    assert abs(move.distance - 0.05) < 0.01 and np.allclose(move.shift, [0.03, 0.0, -0.04], atol=0.01), move
    assert comp.lines()[0].startswith(f"marker {knocked} moved ")


def _map(points, sigma=0.002, cov=None, origin=None):
    return MarkerMap([Marker(i, np.array(p, dtype=float), 0.19, sigma, None, cov) for i, p in points.items()],
                     origin=origin)


def test_the_move_is_held_to_both_maps_sigma():
    old = _map({1: [0, 0, 0], 2: [5, 0, 1], 3: [0, 5, 1]})
    # 2 mm σ each: the difference of two maps has σ 2.83 mm per axis; the 0.1 % limit is √16.3 = 4.03 σ = 11.4 mm
    new = _map({1: [0.011, 0, 0], 2: [5, 0.0118, 1], 4: [1, 1, 1]})
    comp = compare_maps(new, old)
    assert [m.id for m in comp.moves] == [1, 2] and [m.id for m in comp.moved] == [2]
    assert comp.only_new == [4] and comp.only_old == [3]
    assert comp.moves[0].chi == pytest.approx(0.011 / (0.002 * np.sqrt(2)), rel=1e-9)
    # a map's own covariance: long along x, tight across
    loose = _map({1: [0, 0, 0]}, cov=np.diag([0.02, 0.001, 0.001]) ** 2)
    assert not compare_maps(_map({1: [0.03, 0, 0]}), loose).moved
    assert compare_maps(_map({1: [0, 0.01, 0]}), loose).moved


def test_origins_are_taken_into_account_and_a_common_shift_is_suspected():
    old = _map({1: [10, 0, 0], 2: [0, 10, 0], 3: [10, 10, 0]}, origin=[2600000.0, 1200000.0, 400.0])
    new = _map({1: [9.9, 0, 0], 2: [-0.1, 10, 0], 3: [9.9, 10, 0]}, origin=[2600000.1, 1200000.0, 400.0])
    assert not compare_maps(new, old).moved                        # the same places in full coordinates
    shifted = _map({1: [10.02, 0, 0], 2: [0.02, 10, 0], 3: [10.02, 10, 0]}, origin=old.origin)
    lines = compare_maps(shifted, old).lines("site.yaml")
    assert len(lines) == 5 and "total station's set-up" in lines[3] and "site.yaml" in lines[-1]


@pytest.mark.parametrize("dof, alpha, table", [(2, 0.001, 13.82), (3, 0.001, 16.27), (3, 0.05, 7.815),
                                                (10, 0.01, 23.21), (100, 0.001, 149.4)])
def test_chi2_quantile_matches_the_table(dof, alpha, table):
    assert chi2_quantile(dof, alpha) == pytest.approx(table, rel=0.03)

"""The dual-antenna check (aruco_abs_orient.headingcheck) on drives whose true heading is known: a platform turning
at random, the marker heading (grid or true north, 0.02° noise) at 10 Hz, a receiver's true-north azimuth (0.2°
noise, correlated in time as multipath is) at 5 Hz, sites at random convergences. Honest receivers agree; one set
to grid azimuths is named by the convergence; an antenna baseline turned from where the parameter says is named as
such."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.errors import ConfigurationError
from aruco_abs_orient.headingcheck import HeadingAgreement, receiver_yaw
from aruco_abs_orient.north import NorthReference
from aruco_abs_orient.transforms import wrap_angle

DEG = math.radians(1.0)


def test_receiver_conventions():
    assert receiver_yaw(0.0, "compass") == pytest.approx(math.pi / 2)          # north: ENU yaw 90°
    assert receiver_yaw(math.pi / 2, "compass") == pytest.approx(0.0)          # east
    assert receiver_yaw(math.radians(225.0), "compass") == pytest.approx(math.radians(-135.0))   # south-west
    assert receiver_yaw(0.3, "enu") == pytest.approx(0.3)
    # antennas across the platform, left to right (baseline at -90° in base_link): heading east → base_link north
    assert receiver_yaw(math.pi / 2, "compass", -math.pi / 2) == pytest.approx(math.pi / 2)
    with pytest.raises(ConfigurationError, match="convention"):
        receiver_yaw(0.0, "degrees")


def drive(seed, gamma, north, receiver_offset=0.0, seconds=60.0):
    """A HeadingAgreement fed one drive; returns it and the NorthReference of the marker heading."""
    rng = np.random.default_rng(seed)
    ref = NorthReference(north, None, gamma, "test")
    check = HeadingAgreement()
    rate = rng.uniform(-0.3, 0.3)
    turn = rng.uniform(-math.pi, math.pi)

    def true_yaw(t):
        return turn + rate * t + 0.5 * math.sin(0.2 * t)

    bias = 0.0
    t_rx = np.arange(0.03, seconds, 0.2)
    marker_t = np.arange(0.0, seconds, 0.1)
    marker_yaw = [true_yaw(t) + (gamma if north == "grid" else 0.0) + rng.normal(0, 0.02 * DEG) for t in marker_t]
    j = 0
    for t in t_rx:
        while j < len(marker_t) and marker_t[j] <= t + 0.1:
            check.add_markers(marker_t[j], marker_yaw[j])
            j += 1
        bias = 0.9 * bias + math.sqrt(1 - 0.81) * rng.normal(0, 0.1 * DEG)          # multipath, ~2 s
        azimuth = math.pi / 2 - true_yaw(t) + receiver_offset + bias + rng.normal(0, 0.15 * DEG)
        check.add_receiver(t, receiver_yaw(float(wrap_angle(azimuth)), "compass"))
    return check, ref


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), gamma_deg=st.floats(-3.0, 3.0), north=st.sampled_from(["grid", "true"]))
def test_an_honest_receiver_agrees_whatever_the_north(seed, gamma_deg, north):
    check, ref = drive(seed, math.radians(gamma_deg), north)
    verdict = check.summary(ref)
    assert verdict.level == "ok", verdict.message
    assert verdict.pairs >= 250 and abs(verdict.mean) < 0.1 * DEG and 0.005 * DEG < verdict.sigma < 0.1 * DEG


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), gamma_deg=st.floats(0.6, 3.0), sign=st.sampled_from([-1, 1]),
       north=st.sampled_from(["grid", "true"]))
def test_a_receiver_set_to_grid_azimuths_is_named_by_the_convergence(seed, gamma_deg, sign, north):
    gamma = sign * math.radians(gamma_deg)
    # a grid azimuth is the true one minus γ clockwise: the receiver reports azimuth − γ
    check, ref = drive(seed, gamma, north, receiver_offset=-gamma)
    verdict = check.summary(ref)
    assert verdict.level == "warn" and "meridian convergence" in verdict.message, verdict.message
    assert abs(abs(verdict.mean) - abs(gamma)) < 0.1 * DEG


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), offset_deg=st.floats(0.4, 5.0), sign=st.sampled_from([-1, 1]))
def test_a_baseline_turned_from_its_parameter_is_named(seed, offset_deg, sign):
    check, ref = drive(seed, math.radians(0.1), "true", receiver_offset=sign * math.radians(offset_deg))
    verdict = check.summary(ref)
    assert verdict.level == "warn" and "mounting_yaw_deg" in verdict.message, verdict.message
    assert abs(verdict.mean + sign * math.radians(offset_deg)) < 0.1 * DEG   # azimuth + x is yaw − x


def test_pairs_wait_for_the_marker_heading_and_gaps_pair_nothing():
    check = HeadingAgreement(min_pairs=3, max_gap=0.5)
    ref = NorthReference("true", None, 0.0, "test")
    check.add_receiver(0.5, 0.0)                              # before any marker heading: never bracketed
    check.add_markers(1.0, 0.1)
    check.add_markers(2.0, 0.2)                               # a gap of 1 s: nothing paired inside it
    check.add_receiver(1.5, 0.15)
    check.add_receiver(2.1, 0.3)                              # after the last marker heading: waits for the next
    assert check.summary(ref).pairs == 0
    check.add_markers(2.2, 0.4)                               # brackets 2.1 (halfway: 0.3, difference 0)
    assert check.summary(ref).level == "waiting" and check.summary(ref).pairs == 1
    check.add_receiver(2.5, 0.5)                              # waits...
    check.add_receiver(3.0, 0.0)                              # more than max_gap after the last: never bracketed
    assert len(check._waiting) == 1
    check.add_markers(2.1, 9.0)                               # older than the last: ignored
    check.add_markers(3.6, 1.8)                               # ...1.4 s on: too far apart to bracket it
    assert len(check._waiting) == 0
    check.add_markers(3.7, 1.9)
    for t in (3.62, 3.65, 3.68):
        check.add_receiver(t, 1.8 + (t - 3.6))
    verdict = check.summary(ref)
    assert verdict.level == "ok" and verdict.pairs == 4 and abs(verdict.mean) < 1e-9, verdict

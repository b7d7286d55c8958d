"""prismbuffer.py against hand-checked numbers: interpolation, the extrapolation limit and its σ, late samples,
the horizon, and the covariance of the samples around a time."""
import math

import numpy as np
import pytest

from aruco_abs_orient.prismbuffer import PrismBuffer

PRISM = np.array([1.0, 2.0, 1.0])


def test_prism_buffer_interpolates_linearly_between_samples():
    buf = PrismBuffer()
    buf.add(10.0, [0.0, 0.0, 0.0])
    buf.add(11.0, [1.0, 2.0, 0.0])
    p, extra = buf.at(10.25, max_gap=1.5, max_extrapolation=0.2)
    assert np.allclose(p, [0.25, 0.5, 0.0]) and extra == 0.0
    p, extra = buf.at(10.0, max_gap=1.5, max_extrapolation=0.2)  # on a sample
    assert np.allclose(p, [0.0, 0.0, 0.0]) and extra == 0.0
    assert buf.at(10.5, max_gap=0.99, max_extrapolation=0.2) is None  # the samples are 1 s apart: a gap
    assert buf.at(9.99, max_gap=1.5, max_extrapolation=0.2) is None   # before the first sample


def test_prism_buffer_extrapolates_only_up_to_its_limit_with_a_growing_sigma():
    buf = PrismBuffer()
    buf.add(10.0, [0.0, 0.0, 0.0])
    buf.add(11.0, [1.0, 2.0, 0.0])  # velocity (1, 2, 0) m/s, |v| = √5
    p, extra = buf.at(11.1, max_gap=1.5, max_extrapolation=0.15)
    assert np.allclose(p, [1.1, 2.2, 0.0])
    assert extra == pytest.approx(0.5 * math.sqrt(5.0) * 0.1)  # half the distance extrapolated
    assert buf.at(11.16, max_gap=1.5, max_extrapolation=0.15) is None
    one = PrismBuffer()
    one.add(3.0, [1.0, 1.0, 1.0])  # one sample: no velocity, only its own time
    assert np.allclose(one.at(3.0, 1.0, 0.15)[0], [1.0, 1.0, 1.0])
    assert one.at(3.05, 1.0, 0.15) is None


def test_prism_buffer_keeps_late_samples_in_order_and_forgets_past_its_horizon():
    buf = PrismBuffer(horizon=5.0)
    for t in (0.0, 2.0, 4.0):
        buf.add(t, [t, 0.0, 0.0])
    buf.add(3.0, [30.0, 0.0, 0.0])  # late: goes between 2 and 4
    buf.add(4.0, [99.0, 0.0, 0.0])  # same stamp as the newest: ignored
    assert buf.t == [0.0, 2.0, 3.0, 4.0]
    assert np.allclose(buf.at(3.5, 2.0, 0.0)[0], [17.0, 0.0, 0.0])  # halfway from 30 to 4
    buf.add(6.5, [6.5, 0.0, 0.0])  # keeps samples from 6.5 − 5 = 1.5 s on
    assert buf.t == [2.0, 3.0, 4.0, 6.5]
    buf.clear()
    assert buf.at(4.0, 2.0, 1.0) is None


def test_prism_buffer_cov_is_the_larger_of_the_samples_around_and_unknown_when_one_is():
    far = np.diag([0.0005, 0.003, 0.0005]) ** 2      # 100 m north of the instrument: 3 mm along, 0.5 mm across
    near = np.diag([0.003, 0.00003, 0.00003]) ** 2   # 5 m east of it
    buf = PrismBuffer()
    buf.add(1.0, PRISM, near)
    buf.add(2.0, PRISM, far)
    assert np.array_equal(buf.cov_at(1.5), far) and np.array_equal(buf.cov_at(1.0), far)
    buf.add(3.0, PRISM)
    assert buf.cov_at(2.5) is None

"""Instrument clock fit: lower envelope against simulated latency, spikes, drift and wraps."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.geocom.clock import ClockError, InstrumentClock, lower_envelope_line


def simulate(clock, n, rate_hz, offset_s, drift, min_latency, jitter, rng, spikes=0.0, t0_ms=5000.0, wrap=2**32):
    """Feed ``n`` replies; returns (unwrapped ms, true host time) of each."""
    out = []
    for i in range(n):
        t_inst_ms = t0_ms + i * 1000.0 / rate_hz
        true_host = offset_s + (t_inst_ms / 1000.0) * (1 + drift)
        latency = min_latency + rng.uniform(0, 2 * jitter) + (0.3 if rng.random() < spikes else 0.0)
        tx = 0.008
        t_ms = clock.add(int(round(t_inst_ms)) % wrap, true_host + latency + tx, tx)
        out.append((t_ms, true_host))
    return out


def test_envelope_line_hand_checked():
    # points on y = 1 + 0.5x plus lifted ones: the envelope is the line itself
    pts = [(0.0, 1.0), (1.0, 1.9), (2.0, 2.0), (3.0, 3.0), (4.0, 3.0)]
    a, b = lower_envelope_line(pts, max_slope=10.0)
    assert a == pytest.approx(1.0) and b == pytest.approx(0.5)
    a, b = lower_envelope_line(pts, max_slope=0.1)
    assert b == pytest.approx(0.1) and all(y >= a + b * x - 1e-12 for x, y in pts)


@settings(max_examples=25)
@given(st.floats(-1e5, 1e5), st.floats(-50e-6, 50e-6), st.integers(0, 2**31))
def test_stamps_within_2ms_with_10ms_jitter_and_spikes(offset_s, drift, seed):
    rng = np.random.default_rng(seed)
    clock = InstrumentClock(min_latency_s=0.002)
    fed = simulate(clock, 1200, 20.0, offset_s, drift, 0.002, 0.010, rng, spikes=0.05)
    errors = [abs(clock.to_host(t_ms) - true) for t_ms, true in fed[-400:]]
    assert max(errors) < 0.002
    assert clock.drift == pytest.approx(drift, abs=20e-6)


def test_reception_time_stamping_would_be_far_worse():
    rng = np.random.default_rng(1)
    clock = InstrumentClock(min_latency_s=0.002)
    fed = simulate(clock, 600, 20.0, 100.0, 20e-6, 0.002, 0.010, rng)
    ours = np.mean([abs(clock.to_host(t) - true) for t, true in fed[-200:]])
    assert ours < 0.001  # naive reception stamps are ≥ 10 ms late on average here


def test_counter_wrap_is_unwrapped():
    rng = np.random.default_rng(2)
    wrap = 100_000  # 100 s counter so the test crosses it
    clock = InstrumentClock(min_latency_s=0.002, wrap_ms=wrap)
    fed = simulate(clock, 800, 20.0, 50.0, 0.0, 0.002, 0.010, rng, t0_ms=wrap - 10_000, wrap=wrap)
    ms = [t for t, _ in fed]
    assert all(b > a for a, b in zip(ms, ms[1:]))
    assert ms[-1] > wrap
    assert max(abs(clock.to_host(t) - true) for t, true in fed[-100:]) < 0.002
    assert clock.resets == 0


def test_instrument_restart_resets_the_fit():
    clock = InstrumentClock()
    clock.add(1_000_000, 10.0)
    clock.add(1_000_050, 10.05)
    assert clock.add(500, 10.1) == 500 and clock.resets == 1 and len(clock) == 1


def test_errors():
    with pytest.raises(ClockError):
        InstrumentClock().to_host(0)
    with pytest.raises(ClockError):
        InstrumentClock(window=1)

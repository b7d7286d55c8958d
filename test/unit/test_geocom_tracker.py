"""MS60 tracking loop against the simulator: rate, stamps vs truth, faults and recovery."""
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.geocom.client import wire_time_s
from aruco_abs_orient.geocom.protocol import Rpc, encode_request, parse_coordinate, parse_reply
from aruco_abs_orient.geocom.simulator import LATE_S, FaultRates, Ms60Simulator, SimConfig
from aruco_abs_orient.geocom.tracker import Ms60Tracker, TrackerConfig, TrackerError, TrackerState


class Run:
    """A simulator plus a tracker collecting samples and state changes (with host times)."""

    def __init__(self, transport="pty", sim_config=None, seed=1, **tracker_kw):
        sim_config = SimConfig() if sim_config is None else sim_config
        self.sim = Ms60Simulator(sim_config, seed=seed)
        url = self.sim.serve_pty() if transport == "pty" else f"socket://127.0.0.1:{self.sim.serve_tcp(0)}"
        self.samples, self.states = [], []
        self.lock = threading.Lock()
        cfg = TrackerConfig(url, min_latency_s=sim_config.min_latency_s, **tracker_kw)
        self.tracker = Ms60Tracker(cfg, on_sample=self._on_sample,
                                   on_state=lambda s: self.states.append((time.time(), s)))
        self.tracker.start()

    def _on_sample(self, s):
        with self.lock:
            self.samples.append((time.time(), s))

    def wait_for_samples(self, n, timeout=10.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                if len(self.samples) >= n:
                    return
            time.sleep(0.02)
        raise AssertionError(f"fewer than {n} samples after {timeout} s; states {self.states}")

    def first_sample_after(self, t):
        with self.lock:
            return next((rx for rx, _ in self.samples if rx > t), None)

    def close(self):
        self.tracker.stop()
        self.sim.close()

    def check_stream(self):
        """No duplicates, never backwards, every stamp and position equal to the truth."""
        stamps = np.array([s.stamp_s for _, s in self.samples])
        assert np.all(np.diff(stamps) > 0)
        truth = {r.instrument_ms: r for r in self.sim.truth}
        errors = []
        for _, s in self.samples:
            r = truth[s.instrument_ms]
            assert (s.east, s.north, s.height) == r.position
            errors.append(abs(s.stamp_s - r.time_s))
        return np.array(errors)


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_rate_and_stamp_error_without_faults(transport):
    run = Run(transport)
    try:
        run.wait_for_samples(30)
        n0, t0 = len(run.samples), time.time()
        time.sleep(3.0)
        rate = (len(run.samples) - n0) / (time.time() - t0)
        errors = run.check_stream()
        assert run.sim.measuring
    finally:
        run.close()
    assert not run.sim.measuring  # stop() ended the tracking measurement
    assert rate >= 19.0
    assert np.percentile(errors, 95) < 0.002 and errors.max() < 0.004
    assert run.tracker.stats().lost_samples <= 2


@settings(max_examples=300, deadline=None)
@given(late_s=st.floats(0.0, 0.05), seed=st.integers(0, 1000))
def test_simulator_sending_late_measures_again_with_its_latency(late_s, seed):
    """The harness's side of the stamp test: a reply the simulator's thread sends late (a loaded
    host) reports a newer tick whose modelled latency ends within a tick of the actual send, so
    the replies the tracker sees keep the instrument's timing; the truth is that newer tick."""
    sim = Ms60Simulator(SimConfig(), seed=seed)
    sim.locked = sim.measuring = True
    t_complete = sim.t_boot + 2.0
    answer = sim._handle(encode_request(Rpc.TMC_GetCoordinate, (0, 1), 7), t_complete)
    first = answer.truth
    assert first.time_s >= t_complete and answer.send_s == pytest.approx(
        first.time_s + answer.delay_s + wire_time_s(len(answer.data), 115200), abs=1e-9)
    now = answer.send_s + late_s
    later = sim._remeasured(answer, now)
    if late_s <= LATE_S:
        assert later is None
        return
    reading = parse_coordinate(parse_reply(later.data))
    t = later.truth
    assert reading.time_ms == t.instrument_ms > first.instrument_ms and parse_reply(later.data).trid == 7
    assert sim.instrument_ms_at(t.time_s) == pytest.approx(t.instrument_ms, abs=1e-3)  # on a tick (1 µs)
    assert (reading.east, reading.north, reading.height) == t.position == tuple(sim.track(t.time_s - sim.t_boot))
    assert later.delay_s == answer.delay_s
    assert later.send_s == pytest.approx(t.time_s + later.delay_s + wire_time_s(len(later.data), 115200), abs=1e-9)
    # within a tick (1 ms) plus the wire time of a reply whose numbers have a few more digits
    assert now <= later.send_s < now + 0.001 + wire_time_s(12, 115200)


def test_lost_lock_recovers_within_1s_and_counts_lost_samples():
    run = Run("pty")
    try:
        run.wait_for_samples(25)
        run.sim.set_prism_visible(False)
        time.sleep(0.6)
        assert run.tracker.state == TrackerState.LOST
        lost_before = run.tracker.stats().lost_samples
        t_back = time.time()
        run.sim.set_prism_visible(True)
        time.sleep(1.2)
        first = run.first_sample_after(t_back)
        stats = run.tracker.stats()
        run.check_stream()
    finally:
        run.close()
    assert first is not None and first - t_back < 1.0
    assert stats.relocks == 1 and stats.no_position.get(1285, 0) >= 1
    assert lost_before >= 8  # ~0.6 s at 20 Hz without a sample


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_link_outage_reconnects_within_1s(transport):
    run = Run(transport, timeout_s=0.2)
    try:
        run.wait_for_samples(25)
        run.sim.link_down(1.0)
        t_back = time.time() + 1.0
        time.sleep(2.2)
        first = run.first_sample_after(t_back)
        stats = run.tracker.stats()
        run.check_stream()
    finally:
        run.close()
    assert first is not None and first - t_back < 1.0, (first, t_back, run.states)
    assert stats.lost_samples >= 15
    if transport == "tcp":
        assert stats.reconnects >= 1


def test_random_faults_keep_stream_clean_and_count_warnings():
    faults = FaultRates(garbage=0.05, drop=0.03, late=0.01, warning=0.1, spike=0.05)
    run = Run("pty", SimConfig(faults=faults, late_s=0.4), seed=11)
    try:
        run.wait_for_samples(20)
        time.sleep(4.0)
        errors = run.check_stream()
        stats = run.tracker.stats()
    finally:
        run.close()
    assert sum(stats.warnings.values()) >= 3 and set(stats.warnings) <= {1283, 1284}
    n_warn = sum(1 for _, s in run.samples if s.warning)
    assert n_warn == sum(stats.warnings.values())
    assert stats.timeouts >= 1 and stats.garbage_bytes > 0 and stats.lost_samples >= 1
    assert np.median(errors) < 0.002


def test_bad_settings_are_rejected():
    with pytest.raises(TrackerError, match="rate"):
        TrackerConfig("loop://", rate_hz=0).validate()
    with pytest.raises(TrackerError, match="prism_constant"):
        TrackerConfig("loop://", prism_constant_m=5.0).validate()

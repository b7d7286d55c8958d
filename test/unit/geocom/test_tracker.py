"""MS60 tracking loop against the simulator: rate, stamps vs truth, faults and recovery."""
import math
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aruco_abs_orient.geocom.client import wire_time_s
from aruco_abs_orient.geocom.dispatch import LATE_S
from aruco_abs_orient.geocom.protocol import BAP_CONT_REF_SYNCHRO, Rpc, encode_request, parse_coordinate, parse_reply
from aruco_abs_orient.geocom.simulator import FaultRates, Ms60Simulator, SimConfig
from aruco_abs_orient.geocom.tracker import DOUBLE_PRECISION, Ms60Tracker
from aruco_abs_orient.geocom.tracker_types import TrackerConfig, TrackerError, TrackerState


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
        with self.lock:  # the samples so far, then the truth: the simulator logs a reply before sending it
            samples = [s for _, s in self.samples]
        truth = {r.instrument_ms: r for r in list(self.sim.truth)}
        stamps = np.array([s.stamp_s for s in samples])
        assert np.all(np.diff(stamps) > 0)
        errors = []
        for s in samples:
            r = truth[s.instrument_ms]   # the distance the sample was measured with
            assert np.allclose((s.east, s.north, s.height), r.position, atol=0.6e-6)  # 6 decimals on the wire
            errors.append(abs(s.stamp_s - r.time_s))
        assert len({s.instrument_ms for s in samples}) == len(samples)  # no stale distance twice
        assert self.sim.internal_errors == []
        return np.array(errors)

    def wait_for_state(self, state, timeout):
        deadline = time.time() + timeout
        while time.time() < deadline and self.tracker.state != state:
            time.sleep(0.02)
        assert self.tracker.state == state, (self.tracker.state, self.tracker.error, self.states)


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_rate_and_stamp_error_without_faults(transport):
    """Fresh positions following a 20 Hz EDM, stamped with their distance's time to ≤ 2 ms, on a serial link
    and on TCP (no serial byte timing). The rate itself (≥ 19 Hz on a free host) is bench/ms60_soak.py's figure:
    here, beside three other test workers on two cores, polls come late now and then (18.3 Hz at load 7), so
    the test holds the tracker to three quarters of the ticks, which a tracker that missed every other one
    would not reach."""
    run = Run(transport)
    try:
        run.wait_for_samples(30)
        n0, t0, before = len(run.samples), time.time(), run.tracker.stats()
        time.sleep(3.0)
        rate = (len(run.samples) - n0) / (time.time() - t0)
        errors = run.check_stream()
        assert run.sim.tracking and run.sim.meas_prg == BAP_CONT_REF_SYNCHRO and run.sim.user_lock
        assert run.sim.precision == DOUBLE_PRECISION
        stats = run.tracker.stats()
    finally:
        run.close()
    assert not run.sim.tracking  # stop() ended the tracking measurement
    assert rate >= 15.0, rate
    assert np.percentile(errors, 95) < 0.002 and errors.max() < 0.004
    # ticks missed in the same 3 s, counted by the tracker: as the rate, at most a quarter (the start, lock-in
    # and the first polls, is not the steady state)
    lost, samples = stats.lost_samples - before.lost_samples, stats.samples - before.samples
    assert lost <= 0.25 * (samples + lost), (lost, samples)
    assert stats.edm_period_ms == pytest.approx(50.0)
    assert stats.program == "BAP_CONT_REF_SYNCHRO" and stats.error == "" and stats.instrument.startswith("MS60 #")


@settings(max_examples=300, deadline=None)
@given(late_s=st.floats(0.0, 0.05), seed=st.integers(0, 1000))
def test_simulator_sending_late_measures_again_with_its_latency(late_s, seed):
    """The harness's side of the stamp test: a reply the simulator's thread sends late (a loaded
    host) reports a newer tick whose modelled latency ends within a tick of the actual send, so
    the replies the tracker sees keep the instrument's timing; the truth is that newer tick."""
    sim = Ms60Simulator(SimConfig(), seed=seed)
    sim.dispatcher.byte_timing = True   # as on a pty
    sim.locked = sim.tracking = True
    sim._edm_t0_ms = sim._edm_from_ms = sim.instrument_ms_at(sim.t_boot + 1.0)
    t_complete = sim.t_boot + 2.0
    answer = sim.dispatcher.handle(encode_request(Rpc.TMC_GetCoordinate, (0, 1), 7), t_complete)
    first = answer.truth
    assert first.angles_time_s >= t_complete and answer.send_s == pytest.approx(
        first.angles_time_s + answer.delay_s + wire_time_s(len(answer.data), 115200), abs=1e-9)
    assert 0 <= first.angles_time_s - first.time_s < 0.051  # the last distance of a 20 Hz EDM
    now = answer.send_s + late_s
    later = sim.dispatcher.remeasured(answer, now)
    if late_s <= LATE_S:
        assert later is None
        return
    reading = parse_coordinate(parse_reply(later.data))
    t = later.truth
    assert reading.cont_time_ms == t.angles_ms > first.angles_ms and parse_reply(later.data).trid == 7
    assert reading.time_ms == t.instrument_ms >= first.instrument_ms
    assert sim.instrument_ms_at(t.angles_time_s) == pytest.approx(t.angles_ms, abs=1e-3)  # on a tick (1 µs)
    assert sim.instrument_ms_at(t.time_s) == pytest.approx(t.instrument_ms, abs=1e-3)
    assert np.allclose((reading.east, reading.north, reading.height), t.position, atol=1e-12)
    assert np.allclose(t.position, sim.track(t.time_s - sim.t_boot), atol=1e-12)
    assert later.delay_s == answer.delay_s
    assert later.send_s == pytest.approx(t.angles_time_s + later.delay_s + wire_time_s(len(later.data), 115200),
                                         abs=1e-9)
    # within a tick (1 ms) plus the wire time of a reply whose numbers have a few more digits
    assert now <= later.send_s < now + 0.001 + wire_time_s(12, 115200)


@pytest.mark.parametrize("model", ["MS60", "TPS1200"])
def test_lost_lock_relocks_within_a_search_and_the_lock_in_time_plus_1s(model):
    """Fine adjust, search (PowerSearch, or AUT_Search on the TPS1200 model), fine adjust, lock-in,
    tracking: back within a search, the simulator's lock-in time + 1 s of the prism reappearing (no prediction:
    the telescope stayed where the prism was lost)."""
    sim_config = SimConfig(model=model)
    run = Run("pty", sim_config)
    try:
        run.wait_for_samples(25)
        run.sim.set_prism_visible(False)
        run.wait_for_state(TrackerState.LOST, 1.0)
        time.sleep(0.6)
        t_back = time.time()
        run.sim.set_prism_visible(True)
        search_s = sim_config.power_search_s if model == "MS60" else sim_config.search_s
        limit = 2 * sim_config.fine_adjust_s + search_s + sim_config.lock_in_s + 1.0
        deadline = time.time() + limit + 0.5
        while time.time() < deadline and run.first_sample_after(t_back) is None:
            time.sleep(0.05)
        first = run.first_sample_after(t_back)
        stats = run.tracker.stats()
        run.check_stream()
    finally:
        run.close()
    assert first is not None and first - t_back < limit, (first and first - t_back, run.states)
    assert stats.relocks == 1 and stats.no_position.get(1285, 0) >= 1
    assert stats.lost_samples >= 20  # ≥ 1 s at 20 Hz without a distance
    assert stats.program == ("BAP_CONT_REF_SYNCHRO" if model == "MS60" else "BAP_CONT_REF_STANDARD")
    assert stats.search == ("AUT_PS_SearchNext" if model == "MS60" else "AUT_Search")


def test_a_refused_step_is_an_error_state_with_its_reason_then_retried():
    run = Run("tcp", prism_type=99, error_retry_s=0.5)   # no such BAP_PRISMTYPE
    try:
        run.wait_for_state(TrackerState.ERROR, 3.0)
        assert run.tracker.error.startswith("prism type refused: BAP_SetPrismType returned 2 IVPARAM")
        assert run.tracker.stats().error == run.tracker.error and not run.samples
        time.sleep(1.2)
        assert run.tracker.state == TrackerState.ERROR and run.sim.requests > 20  # tried again, refused again
    finally:
        run.close()


def test_lock_mode_switched_off_on_the_instrument_is_an_error_then_recovers():
    run = Run("tcp", error_retry_s=0.5)
    try:
        run.wait_for_samples(5)
        run.sim.set_user_lock(False)   # LOCK mode switched off on the instrument's keyboard
        run.wait_for_state(TrackerState.ERROR, 3.0)
        assert "8714 AUT_NOT_ENABLED" in run.tracker.error and "LOCK mode is off" in run.tracker.error
        n = len(run.samples)
        run.wait_for_state(TrackerState.LOCKED, 5.0)   # the session switches LOCK mode on again
        run.wait_for_samples(n + 5)
        run.check_stream()
    finally:
        run.close()


def test_locked_without_new_distances_is_an_error():
    """Tracking stopped on the instrument (the keyboard): the same distance again and again is not a
    position; after no_distance_s it is an error naming the measurement program."""
    run = Run("tcp", no_distance_s=1.0, error_retry_s=60.0)
    try:
        run.wait_for_samples(5)
        run.sim.change(lambda: setattr(run.sim, "tracking", False))
        t0 = time.time()
        run.wait_for_state(TrackerState.ERROR, 3.0)
        n = len(run.samples)
        stats = run.tracker.stats()
    finally:
        run.close()
    assert time.time() - t0 >= 1.0 and "no new distance" in stats.error and "BAP_CONT_REF_SYNCHRO" in stats.error
    assert stats.duplicates >= 10 and n == stats.samples
    run.check_stream()


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
    # the outage's second counted in EDM periods, as the tracker knows them: 50 ms, or 100 ms on a host too starved
    # to poll every distance (a CI run's Python 3.8 lane: 7 Hz polled, 12 lost over the second)
    assert stats.lost_samples >= 0.75 * 1000.0 / stats.edm_period_ms, stats
    if transport == "tcp":
        assert stats.reconnects >= 1


def test_random_faults_keep_stream_clean_and_count_warnings():
    faults = FaultRates(garbage=0.05, drop=0.03, late=0.01, warning=0.1, spike=0.05)
    run = Run("pty", SimConfig(faults=faults, late_s=0.4), seed=11, motion_timeout_s=5.0)
    try:
        run.wait_for_samples(20, timeout=20.0)
        time.sleep(4.0)
    finally:
        run.close()
    errors = run.check_stream()
    stats = run.tracker.stats()   # after the stop: the same samples as run.samples
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


def test_a_motorised_call_that_times_out_does_not_pile_up_requests():
    """AUT_LockIn takes longer than the motion timeout: the driver does not send more requests into the
    busy instrument; it reopens the link, waits for COM_NullProc behind the running lock-in (whose late
    reply it discards), finds the prism locked and tracks."""
    run = Run("pty", SimConfig(lock_in_s=1.5), timeout_s=0.3, motion_timeout_s=0.8)
    try:
        run.wait_for_samples(5, timeout=15.0)
        stats = run.tracker.stats()
        run.check_stream()
    finally:
        run.close()
    assert stats.timeouts == 1 and stats.reconnects == 1 and stats.stale_replies >= 1, stats
    assert [s for _, s in run.states].count(TrackerState.SEARCHING) == 1


def _hidden_behind_a_pillar(predict: bool, radius: float = 20.0):
    """A prism driven at 1 m/s ``radius`` m from the instrument, hidden for 2 s (it moves 2 m: at 20 m 6° of Hz,
    beyond AUT_FineAdjust's window): (seconds from its reappearance to the first new position, the tracker's
    stats). With ``predict`` the tracker is told where the prism is (its true position 50 ms late, 3 cm off: a
    fused pose), else it has to search."""
    def track(t):
        a = -t / radius  # 1 m/s along a circle about the station, anticlockwise: against PowerSearch's sweep
        return np.array([radius * math.sin(a), radius * math.cos(a), 1.5 + 0.2 * math.sin(t)])

    sim = Ms60Simulator(SimConfig(), track=track, seed=5)
    samples, lock = [], threading.Lock()

    def on_sample(s):
        with lock:
            samples.append(time.time())

    def predicted(at_s):
        return tuple(track(at_s - 0.05 - sim.t_boot) + [0.03, 0.0, 0.0])

    tracker = Ms60Tracker(TrackerConfig(f"socket://127.0.0.1:{sim.serve_tcp(0)}",
                                        min_latency_s=SimConfig().min_latency_s, warmup_samples=10),
                          on_sample=on_sample, predict=predicted if predict else None)
    tracker.start()
    try:
        deadline = time.time() + 10.0
        while time.time() < deadline and len(samples) < 20:
            time.sleep(0.05)
        sim.set_prism_visible(False)
        time.sleep(2.0)
        t_back = time.time()
        sim.set_prism_visible(True)
        deadline = t_back + 12.0
        while time.time() < deadline and not any(t > t_back for t in samples):
            time.sleep(0.02)
        first = next((t for t in samples if t > t_back), None)
        stats = tracker.stats()
    finally:
        tracker.stop()
        sim.close()
    assert sim.internal_errors == []
    return (None if first is None else first - t_back), stats


def test_reaim_at_the_prediction_after_a_pillar_then_search_without_one():
    """Hidden 2 s while moving at 1 m/s: told where the prism is, the tracker turns the telescope there
    (AUT_MakePositioning), fine-adjusts and locks in, and positions resume within the simulator's fine-adjust,
    lock-in and one more re-aim cycle of its reappearance (about 1.6-2.1 s, most of it the simulated AUT_LockIn's
    1.2 s); without a prediction the fine adjustment at the old direction misses and PowerSearch has to sweep the
    horizon for it, clockwise, the prism having gone the other way (most of a turn: seconds). Both times are
    printed."""
    c = SimConfig()
    with_prediction, stats = _hidden_behind_a_pillar(True)
    without, stats_search = _hidden_behind_a_pillar(False)
    print(f"positions resumed {with_prediction:.2f} s after the prism reappeared with the prediction, "
          f"{without if without is None else round(without, 2)} s with the search")
    assert stats.reaims >= 2 and stats.reaims_found == 1 and stats.relocks == 1
    assert with_prediction < c.positioning_s + 2 * c.fine_adjust_s + c.lock_in_s + 0.5
    assert stats_search.reaims == 0 and stats_search.search == "AUT_PS_SearchNext"
    assert without is None or without > with_prediction + 0.5


def test_reaim_aims_where_the_prism_will_be_when_the_turn_ends():
    """5 m from the instrument a prism at 1 m/s crosses 11° a second: the telescope's turn to where it is when the
    turn starts (0.1 s and 22° at 90°/s in the simulator) would leave it outside AUT_FineAdjust's ±1.4° window
    every time. Aimed where it will be when the turn ends, it is found at the first re-aim after it reappears and
    positions resume as fast as at 20 m."""
    c = SimConfig()
    resumed, stats = _hidden_behind_a_pillar(True, radius=5.0)
    assert stats.reaims_found == 1 and stats.relocks == 1, stats
    assert resumed < c.positioning_s + 2 * c.fine_adjust_s + c.lock_in_s + 0.5


def test_extrapolate_to_a_later_time():
    """The prediction of the pose at a given time: the newest pose moved on at the two poses' velocity, stale when
    the newest is older than max_age at ``now`` whatever time it is asked for."""
    from aruco_abs_orient.geocom.tracker import extrapolate

    older, newer = (9.8, np.array([1.0, 2.0, 1.5])), (10.0, np.array([1.2, 2.0, 1.5]))
    np.testing.assert_allclose(extrapolate(older, newer, 10.1, 1.0, 10.5), [1.7, 2.0, 1.5])
    np.testing.assert_allclose(extrapolate(older, newer, 10.5, 1.0), [1.7, 2.0, 1.5])
    assert extrapolate(older, newer, 11.2, 1.0, 10.5) is None

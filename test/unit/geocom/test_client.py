"""GeoCOM client against the simulator over a real pty and over TCP, and over loop://."""
import contextlib
import time

import numpy as np
import pytest

from aruco_abs_orient.geocom.client import GeoComClient, GeoComLinkError, GeoComRcError, GeoComTimeout, wire_time_s
from aruco_abs_orient.geocom.protocol import (
    BAP_CONT_REF_SYNCHRO,
    BAP_REFL_USE,
    MOT_LOCKED_IN,
    MOT_LOCKED_OUT,
    RC,
    TMC_CLEAR,
    TMC_RTRK_DIST,
    TMC_TRK_DIST,
    RcClass,
)
from aruco_abs_orient.geocom.simulator import FaultRates, Ms60Simulator, SimConfig, builtin_track


@pytest.fixture(params=["pty", "tcp"])
def sim_and_url(request):
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002), seed=3)
    url = sim.serve_pty() if request.param == "pty" else f"socket://127.0.0.1:{sim.serve_tcp(0)}"
    yield sim, url
    sim.close()


def test_session_rpcs(sim_and_url):
    """The driver's session on the strict simulator, step by step, with the instrument's refusals."""
    sim, url = sim_and_url
    with GeoComClient(url, timeout_s=0.5) as client:
        client.null_proc()
        assert client.instrument_name() == "MS60"
        assert client.instrument_number() == 1234567
        assert client.firmware_version() == "7.10.2" and client.geocom_version() == "1.50.0"
        client.set_double_precision(6)
        assert client.double_precision() == 6
        client.set_prism_constant(-0.0344)
        assert client.prism_constant() == pytest.approx(-0.0344)
        client.set_station(100.0, 200.0, 300.0, 1.55)
        assert client.get_station() == (100.0, 200.0, 300.0, 1.55)
        client.set_orientation(0.25)
        client.set_target_type(BAP_REFL_USE)
        client.set_meas_prg(BAP_CONT_REF_SYNCHRO)
        assert client.lock_status() == MOT_LOCKED_OUT
        assert client.lock_in(timeout_s=3.0) == RC.AUT_NOT_ENABLED        # LOCK mode off
        client.set_user_lock_state(True)
        assert client.lock_in(timeout_s=3.0) == RC.AUT_NO_TARGET          # not fine-adjusted yet
        # not measuring, not locked: angles only, no position
        assert client.get_coordinate().reading.rc == RC.TMC_ANGLE_OK
        t0 = time.time()
        assert client.fine_adjust(0.05, 0.05, timeout_s=3.0) == 0
        assert client.lock_in(timeout_s=3.0) == 0 and client.lock_status() == MOT_LOCKED_IN
        assert time.time() - t0 >= sim.config.fine_adjust_s + sim.config.lock_in_s  # motorised: seconds
        with pytest.raises(GeoComRcError) as info:
            client.do_measure(TMC_TRK_DIST)                                # TPS1100 only
        assert info.value.rc == RC.IVPARAM
        client.do_measure(TMC_RTRK_DIST)
        time.sleep(0.06)  # one EDM period
        timed = client.get_coordinate()
        r = timed.reading
        assert r.rc_class is RcClass.OK and r.cont_time_ms >= r.time_ms
        truth = sim.truth[-1]
        assert np.allclose((r.east, r.north, r.height), truth.position, atol=1e-6) and r.time_ms == truth.instrument_ms
        assert r.cont_time_ms == truth.angles_ms
        # angles measured before the reply was received, by at least the latency and its wire time
        assert timed.received_s - truth.angles_time_s >= 0.001 + timed.reply_tx_s - 1e-4
        n_bytes = round(timed.reply_tx_s * 115200 / 10)
        if url.startswith("socket://"):
            assert timed.reply_tx_s == 0.0  # no serial byte timing on TCP
        else:
            assert timed.reply_tx_s == pytest.approx(wire_time_s(n_bytes, 115200)) and 60 < n_bytes < 200
        rc, e, n, h = client.get_simple_coord()
        assert rc == 0 and np.allclose((e, n, h), builtin_track(time.time() - sim.t_boot), atol=0.05)
        with pytest.raises(GeoComRcError) as info:                        # a distance exists
            client.set_station(1.0, 2.0, 3.0, 1.5)
        assert info.value.rc == RC.TMC_BUSY
        client.do_measure(TMC_CLEAR)
        client.set_station(1.0, 2.0, 3.0, 1.5)
        client.do_measure(TMC_RTRK_DIST)
        sim.set_prism_visible(False)
        time.sleep(0.2)  # three EDM periods: the distance is no longer valid
        assert client.get_coordinate().reading.rc == RC.TMC_ANGLE_OK
        assert client.fine_adjust(0.05, 0.05, timeout_s=3.0) == RC.AUT_NO_TARGET
        assert client.search(0.35, 0.17, timeout_s=5.0) == RC.AUT_NO_TARGET
        sim.set_prism_visible(True)
        assert client.lock_status() == MOT_LOCKED_OUT  # needs fine adjust and lock-in again
        assert client.power_search_next(timeout_s=6.0) == 0
        assert client.fine_adjust(0.05, 0.05, timeout_s=3.0) == 0 and client.lock_in(timeout_s=3.0) == 0
    assert sim.internal_errors == []


def test_unknown_procedure_is_an_rc_error(sim_and_url):
    _, url = sim_and_url
    with GeoComClient(url) as client, pytest.raises(GeoComRcError, match="4242 returned 3081 COM_PROC_UNAVAIL") as info:
        client._checked(4242)
    assert info.value.rc == RC.COM_PROC_UNAVAIL


def test_garbage_and_late_replies_are_discarded():
    faults = FaultRates(garbage=0.5, late=0.15)
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002, late_s=0.25, faults=faults, profile="lenient"),
                        seed=5)
    url = sim.serve_pty()
    try:
        with GeoComClient(url, timeout_s=0.1) as client:
            client.lock_in()
            client.do_measure(TMC_TRK_DIST)
            got, timeouts = [], 0
            for _ in range(60):
                try:
                    got.append(client.get_coordinate().reading)
                except GeoComTimeout:
                    timeouts += 1
            by_ms = {t.instrument_ms: t for t in sim.truth}
            # every accepted reply is the answer to its own request: its values are that truth
            for r in got:
                if r.has_position:
                    assert np.allclose((r.east, r.north, r.height), by_ms[r.time_ms].position, atol=1e-12)
            times = [r.time_ms for r in got]
            assert times == sorted(times) and len(set(times)) == len(times)
            assert timeouts > 0 and client.stale_replies > 0 and client.garbage_bytes > 0
    finally:
        sim.close()


def test_loop_url_discards_its_own_echo_and_times_out():
    with GeoComClient("loop://", timeout_s=0.15) as client:
        t0 = time.time()
        with pytest.raises(GeoComTimeout):
            client.null_proc()
        assert 0.14 < time.time() - t0 < 0.5
        assert client.garbage_bytes >= len(b"%R1Q,0,1:\r\n")


def test_loop_url_resyncs_after_noise_and_skips_other_trids():
    with GeoComClient("loop://", timeout_s=0.2) as client:
        # waiting in the line before the request (trid 1): a stale reply (trid 5), then the
        # answer glued to noise; the request's own echo follows and is ignored
        client._serial.write(b'%R1P,0,5:0,"OLD"\r\nnoise%R1P,0,1:0,"MS60"\r\n')
        assert client.instrument_name() == "MS60"
        assert client.stale_replies == 1 and client.garbage_bytes == len(b"noise")


def test_bad_port_is_a_link_error():
    with pytest.raises(GeoComLinkError, match="/nonexistent/tty"):
        GeoComClient("/nonexistent/tty")


def test_link_drop_on_tcp_is_a_link_error_or_timeout():
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002), seed=9)
    port = sim.serve_tcp(0)
    try:
        with GeoComClient(f"socket://127.0.0.1:{port}", timeout_s=0.2) as client:
            client.null_proc()
            sim.link_down(0.5)
            with pytest.raises((GeoComLinkError, GeoComTimeout)):
                for _ in range(5):
                    client.null_proc()
        time.sleep(0.5)
        with GeoComClient(f"socket://127.0.0.1:{port}", timeout_s=0.3) as client:
            client.null_proc()
    finally:
        sim.close()


def test_byte_timing_follows_the_baud_rate():
    """At 9600 baud a coordinate round trip takes the wire time of request + reply + latency: never less (each of
    5), and the quickest of them no more (a loaded host only ever adds its scheduling delays)."""
    sim = Ms60Simulator(SimConfig(baud=9600, latency_s=0.003, jitter_s=0.002, profile="lenient"), seed=4)
    url = sim.serve_pty()
    try:
        with GeoComClient(url, baud=9600, timeout_s=1.0) as client:
            client.lock_in()
            client.do_measure(TMC_TRK_DIST)
            request_s = wire_time_s(len(b"%R1Q,2082,9:0,1\r\n"), 9600)
            excess = []
            for _ in range(5):
                t0 = time.time()
                timed = client.get_coordinate()
                elapsed = time.time() - t0
                assert timed.reply_tx_s > 0.1  # ~130 bytes at 9600 baud
                excess.append(elapsed - (request_s + timed.reply_tx_s))
            assert min(excess) >= 0.001 - 0.002  # latency 1..5 ms
            assert min(excess) <= 0.005 + 0.03
    finally:
        sim.close()


def test_a_tcp_peer_that_closes_at_once_is_a_link_error_not_a_hang():
    """An instrument or serial server that accepts and closes the connection (busy with another
    client): the client fails fast (pyserial 3.4's socket handler spun for ever in open())."""
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)

    def accept_and_close():
        with contextlib.suppress(OSError):
            conn, _ = server.accept()
            conn.close()

    thread = threading.Thread(target=accept_and_close, daemon=True)
    thread.start()
    t0 = time.time()
    try:
        url = f"socket://127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises((GeoComLinkError, GeoComTimeout)), GeoComClient(url, timeout_s=0.3) as client:
            time.sleep(0.1)   # the peer has closed by now
            client.null_proc()
        assert time.time() - t0 < 2.0
    finally:
        server.close()
        thread.join(timeout=2.0)
    with pytest.raises(GeoComLinkError, match="socket://nohost"):
        GeoComClient("socket://nohost")

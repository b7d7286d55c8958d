"""The strict simulator driven by an independent GeoCOM client, geocompy (PyPI, test-only): the
ordinary calls a geocompy user makes get RC 0 and values that agree with the simulator's truth
(geometry computed here, not by the simulator), the instrument's refusals get the reference's codes,
and malformed raw requests get a well-formed error reply after which the simulator still serves."""
import atexit
import math
import time
from datetime import datetime, timezone

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

geocompy_comm = pytest.importorskip("geocompy.communication")
from geocompy.data import Coordinate  # noqa: E402
from geocompy.geo import GeoCom  # noqa: E402
from geocompy.geo.gcdata import ATRLock, Prism, Target, UserProgram  # noqa: E402
from geocompy.geo.gctypes import GeoComCode  # noqa: E402

from aruco_abs_orient.geocom.protocol import crc16, parse_reply  # noqa: E402
from aruco_abs_orient.geocom.simulator import Ms60Simulator, SimConfig  # noqa: E402

STATION = (1.0, -2.0, 0.5, 1.6)   # E0, N0, H0, Hi


def _connect(sim, transport):
    if transport == "pty":
        return geocompy_comm.open_serial(sim.serve_pty(), speed=115200, timeout=10)
    return geocompy_comm.open_socket("127.0.0.1", sim.serve_tcp(0), "tcp", timeout=10)


def _polar(p):
    """Hz (from north, clockwise), V (zenith) and slope distance of p from the station: the
    surveying convention, computed here independently of the simulator."""
    e0, n0, h0, hi = STATION
    de, dn, dh = p[0] - e0, p[1] - n0, p[2] - h0 - hi
    return math.atan2(de, dn) % (2 * math.pi), math.atan2(math.hypot(de, dn), dh), math.sqrt(de**2 + dn**2 + dh**2)


@pytest.mark.parametrize("transport, checksum", [("pty", False), ("pty", True), ("tcp", True)])
def test_geocompy_session_gets_rc_0_and_true_values(transport, checksum):
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002), seed=2)
    try:
        with _connect(sim, transport) as conn:
            tps = GeoCom(conn, checksum=checksum)   # COM_NullProc + COM_GetDoublePrecision + identity
            ok = GeoComCode.OK

            def call(response):
                assert response.error == ok, (response.rpcname, response.response)
                return response.params

            assert tps.precision == 15
            assert call(tps.csv.get_instrument_name()) == "MS60" and call(tps.csv.get_serial_number()) == 1234567
            assert call(tps.com.get_geocom_version()) == (1, 50, 0)
            assert call(tps.csv.get_firmware_version()) == (7, 10, 2)
            call(tps.com.set_double_precision(7))
            assert call(tps.com.get_double_precision()) == 7
            now = datetime.now(timezone.utc).replace(tzinfo=None)
            assert abs((call(tps.csv.get_datetime()) - now).total_seconds()) < 2.0
            assert abs((call(tps.csv.get_datetime_precise()) - now).total_seconds()) < 2.0
            call(tps.tmc.do_measurement("CLEAR"))
            call(tps.tmc.set_station(Coordinate(*STATION[:3]), STATION[3]))
            station, hi = call(tps.tmc.get_station())
            assert (station.x, station.y, station.z, hi) == STATION
            call(tps.bap.set_target_type(Target.REFLECTOR))
            call(tps.bap.set_prism_type(Prism.THREESIXTY))
            call(tps.bap.set_measurement_program(UserProgram.CONT_REF_SYNCHRO))
            assert call(tps.bap.get_measurement_program()) == UserProgram.CONT_REF_SYNCHRO
            call(tps.aus.switch_user_lock(True))
            hz, v = call(tps.tmc.get_angle())
            p = sim.track(time.time() - sim.t_boot)
            assert abs(float(hz) - _polar(p)[0]) < 0.02 and abs(float(v) - _polar(p)[1]) < 0.02
            assert len(call(tps.tmc.get_angle_inclination())) == 9
            call(tps.aut.fine_adjust(0.05, 0.05))
            call(tps.aut.search(0.35, 0.17))
            call(tps.aut.powersearch_next("CLOCKWISE", False))
            call(tps.aut.fine_adjust(0.05, 0.05))
            call(tps.aut.lock_in())
            assert call(tps.mot.get_lockon_status()) == ATRLock.LOCK
            call(tps.tmc.do_measurement("RAPIDTRACK"))
            time.sleep(0.06)
            coord, t_ms, cont, cont_ms = call(tps.tmc.get_coordinate(0))
            truth = sim.truth[-1]
            assert t_ms == truth.instrument_ms and cont_ms == truth.angles_ms and 0 <= cont_ms - t_ms <= 60
            assert np.allclose((coord.x, coord.y, coord.z), truth.position, atol=1e-6)
            hz, v, slope = call(tps.tmc.get_simple_measurement(0))
            p = sim.track(time.time() - sim.t_boot)
            assert abs(float(hz) - _polar(p)[0]) < 0.02 and abs(slope - _polar(p)[2]) < 0.05
            full = call(tps.tmc.get_complete_measurement(0))
            assert len(full) == 8 and abs(full[6] - _polar(sim.track(time.time() - sim.t_boot))[2]) < 0.05
            assert call(tps.tmc.get_simple_coordinate(0)) is not None
        assert sim.internal_errors == []
    finally:
        sim.close()


def test_geocompy_gets_the_refusals_of_a_real_instrument():
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002), seed=3)
    try:
        with _connect(sim, "pty") as conn:
            tps = GeoCom(conn)
            assert tps.aut.lock_in().error == GeoComCode.AUT_NOT_ENABLED           # LOCK mode off
            tps.aus.switch_user_lock(True)
            assert tps.aut.lock_in().error == GeoComCode.AUT_NO_TARGET             # not fine-adjusted
            assert tps.tmc.do_measurement("TRACK").error == GeoComCode.IVPARAM     # TPS1100 program 2
            assert tps.tmc.do_measurement("RAPIDTRACK").error == GeoComCode.OK
            assert tps.tmc.set_station(Coordinate(0, 0, 0), 1.5).error == GeoComCode.TMC_BUSY  # a distance
            assert tps.tmc.set_azimuth(0.5).error == GeoComCode.TMC_BUSY
            assert tps.request(17019, [12]).error == GeoComCode.IVPARAM           # no BAP_USER_MEASPRG 12
            assert tps.request(2008, [8, 7]).error == GeoComCode.IVPARAM          # no TMC_INCLINE_PRG 7
            assert tps.request(9051, [2, 0]).error == GeoComCode.IVPARAM          # direction is ±1
            assert tps.request(107, [16]).error == GeoComCode.IVPARAM             # precision 0..15
            assert tps.request(4242).error == GeoComCode.COM_PROC_UNAVAIL
            assert tps.request(2082, [1000]).error == GeoComCode.COM_CANT_DECODE_REQ  # one parameter missing
            assert tps.com.nullprocess().error == GeoComCode.OK
        assert sim.internal_errors == []
    finally:
        sim.close()


@pytest.mark.parametrize("raw, reply", [
    ("%R1Q,2008,30:abc,1", "%R1P,3080,30:0"),      # a non-numeric parameter
    ("%R1Q,2008,31:1.5,1", "%R1P,3080,31:0"),      # a float where an integer is expected
    ("%R1Q,0:", "%R1P,0,0:0"),                     # no transaction id: 0
    ("%R1Q,5004:", '%R1P,0,0:0,"MS60"'),
    ("%R1Q,2008,32:", "%R1P,3080,32:0"),           # parameters missing
    ("%R1Q,9999,33:", "%R1P,3081,33:0"),           # unknown procedure
    ("%R1Q,abc,34:", "%R1P,3080,34:0"),            # the procedure is not a number
    ("%R1Q,0,35,1:", "%R1P,3101,35:0"),            # a wrong checksum
    ("hello", "%R1P,3094,0:0"),                    # not GeoCOM
    ("%R1Q,0,36", "%R1P,3080,36:0"),               # no ':'
    ('%R1Q,5004,37:"open', "%R1P,3080,37:0"),      # an unterminated string
])
def test_malformed_raw_requests_get_a_well_formed_error_and_the_simulator_goes_on(raw, reply):
    sim = Ms60Simulator(SimConfig(latency_s=0.002, jitter_s=0.001), seed=4)
    try:
        with _connect(sim, "pty") as conn:
            assert conn.exchange(raw) == reply
            assert conn.exchange("%R1Q,0,38:") == "%R1P,0,38:0"
            good = f"%R1Q,0,39,{crc16('%R1Q,0,39:')}:"
            assert conn.exchange(good) == f"%R1P,0,39,{crc16('%R1P,0,39:0')}:0"   # checksummed reply
        assert sim.internal_errors == []
    finally:
        sim.close()


_FUZZ = {}


def _fuzz_link():
    """One simulator and connection for all fuzz examples, closed at interpreter exit."""
    if not _FUZZ:
        sim = Ms60Simulator(SimConfig(latency_s=0.001, jitter_s=0.0005), seed=5)
        _FUZZ["sim"] = sim
        _FUZZ["conn"] = geocompy_comm.open_serial(sim.serve_pty(), speed=115200, timeout=5)
        atexit.register(sim.close)
        atexit.register(_FUZZ["conn"].close)
    return _FUZZ["sim"], _FUZZ["conn"]


@settings(max_examples=150, deadline=None)
@given(rpc=st.sampled_from([0, 107, 2008, 2010, 2082, 2113, 5008, 9013, 9037, 9051, 17019, 18007, 31337]),
       trid=st.integers(0, 32767),
       params=st.lists(st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
                                 st.text("abc019.,-+e ", max_size=8)), max_size=5))
def test_any_request_gets_one_well_formed_reply_with_its_trid(rpc, trid, params):
    sim, conn = _fuzz_link()
    body = ",".join(str(p) for p in params)
    reply = parse_reply(conn.exchange(f"%R1Q,{rpc},{trid}:{body}").encode())
    assert reply.trid == trid
    assert conn.exchange("%R1Q,0,1:") == "%R1P,0,1:0"   # still serving, and in step
    assert sim.internal_errors == []


def test_geocompy_reaims_the_telescope_where_the_prism_is():
    """AUT_MakePositioning through geocompy's turn_to: a prism lost while hidden and found again only where the
    telescope is turned to: AUT_FineAdjust misses it from a wrong direction (AUT_NO_TARGET) and finds it, locks in
    and measures after a turn to its direction computed here (Hz, V from the station, the surveying convention)."""
    sim = Ms60Simulator(SimConfig(latency_s=0.003, jitter_s=0.002), seed=4)
    sim.station = STATION
    try:
        with _connect(sim, "tcp") as conn:
            tps = GeoCom(conn)
            tps.aus.switch_user_lock(True)
            assert tps.aut.fine_adjust(0.05, 0.05).error == GeoComCode.OK
            assert tps.aut.lock_in().error == GeoComCode.OK
            sim.set_prism_visible(False)
            sim.set_prism_visible(True)   # lost: it needs aiming again
            hz, v, _ = _polar(sim.track(time.time() - sim.t_boot))
            assert tps.aut.turn_to(hz + 0.5, v).error == GeoComCode.OK            # 29° beside it
            assert tps.aut.fine_adjust(0.05, 0.05).error == GeoComCode.AUT_NO_TARGET
            assert tps.request(9027, [hz, v, 0, 1, 0]).error == GeoComCode.IVPARAM  # ATR mode AUT_TARGET: not modelled
            hz, v, _ = _polar(sim.track(time.time() + 0.2 - sim.t_boot))           # where it will be after the turn
            assert tps.aut.turn_to(hz, v).error == GeoComCode.OK
            assert tps.aut.fine_adjust(0.05, 0.05).error == GeoComCode.OK
            assert tps.aut.lock_in().error == GeoComCode.OK
            assert tps.mot.get_lockon_status().params == ATRLock.LOCK
        assert sim.internal_errors == []
    finally:
        sim.close()

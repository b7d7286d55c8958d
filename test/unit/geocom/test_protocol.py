"""GeoCOM framing, parsing and return-code classes (hand-checked lines from the GeoCOM manual)."""
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.geocom.protocol import (
    RC,
    Byte,
    GeoComProtocolError,
    RcClass,
    Rpc,
    classify_rc,
    crc16,
    encode_reply,
    encode_request,
    format_double,
    parse_coordinate,
    parse_reply,
    parse_request,
    rc_name,
    split_values,
)


def test_request_framing_matches_the_manual():
    assert encode_request(Rpc.COM_NullProc) == b"%R1Q,0:\r\n"
    assert encode_request(Rpc.TMC_GetCoordinate, (100, 1), trid=7) == b"%R1Q,2082,7:100,1\r\n"
    assert encode_request(Rpc.AUS_SetUserLockState, (True,)) == b"%R1Q,18007:1\r\n"
    assert encode_request(Rpc.TMC_SetOrientation, (0.5,)) == b"%R1Q,2113:0.5\r\n"


def test_reply_parsing_of_a_manual_example():
    reply = parse_reply(b"%R1P,0,0:0,1.23,-4.5,6.0,4711,1.23,-4.5,6.0,4711\r\n")
    assert (reply.comrc, reply.trid, reply.rc) == (0, 0, 0)
    c = parse_coordinate(reply)
    assert (c.east, c.north, c.height, c.time_ms) == (1.23, -4.5, 6.0, 4711)
    assert c.has_position and c.rc_class is RcClass.OK


def test_reply_without_trid_and_quoted_string():
    reply = parse_reply(b'%R1P,0:0,"TS60, MS60"\r\n')
    assert reply.trid is None and reply.values == ("TS60, MS60",)


@pytest.mark.parametrize("rc, cls", [
    (0, RcClass.OK),
    (1283, RcClass.WARNING), (1284, RcClass.WARNING),
    (1285, RcClass.NO_POSITION), (1288, RcClass.NO_POSITION), (1292, RcClass.NO_POSITION),
    (1294, RcClass.NO_POSITION), (8710, RcClass.NO_POSITION), (1799, RcClass.NO_POSITION),
    (1, RcClass.ERROR), (1295, RcClass.ERROR), (3077, RcClass.ERROR), (2, RcClass.ERROR),
])
def test_every_return_code_class(rc, cls):
    assert classify_rc(rc) is cls


def test_warning_keeps_the_position_and_no_position_drops_it():
    values = (1.0, 2.0, 3.0, 10, 1.0, 2.0, 3.0, 10)
    warn = parse_coordinate(parse_reply(encode_reply(RC.TMC_ACCURACY_GUARANTEE, values)))
    assert warn.has_position and warn.rc_class is RcClass.WARNING and warn.east == 1.0
    angles_only = parse_coordinate(parse_reply(encode_reply(RC.TMC_ANGLE_OK, (0.0, 0.0, 0.0, 10, 0.0, 0.0, 0.0, 10))))
    assert not angles_only.has_position and math.isnan(angles_only.east)
    bare = parse_coordinate(parse_reply(b"%R1P,0,3:1292\r\n"))
    assert not bare.has_position and bare.time_ms == -1


@pytest.mark.parametrize("line", [
    b"", b"garbage\r\n", b"%R1P,0,1\r\n", b"%R1P,x:0\r\n", b"%R1P,0,1:\r\n", b"%R1P,0,1:abc\r\n",
    b"%R1P,0,1,2,3:0\r\n", b"%R1P,0,1,x:0\r\n", b'%R1P,0:0,"open\r\n', b"%R1P,0:\xff\r\n", b"%R1Q,0:\r\n",
])
def test_malformed_replies_raise(line):
    with pytest.raises(GeoComProtocolError):
        parse_reply(line)


def test_position_reply_with_too_few_values_raises():
    with pytest.raises(GeoComProtocolError):
        parse_coordinate(parse_reply(b"%R1P,0,1:0,1.0,2.0\r\n"))


def test_bad_parameters_raise():
    with pytest.raises(GeoComProtocolError):
        encode_request(Rpc.TMC_SetOrientation, (float("nan"),))
    with pytest.raises(GeoComProtocolError):
        encode_request(Rpc.COM_NullProc, ('a"b',))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@given(st.integers(0, 65535), st.one_of(st.none(), st.integers(0, 9999)),
       st.lists(st.one_of(st.integers(-2**31, 2**31), finite, st.text("abcXYZ 09,.-_", max_size=12)), max_size=8))
def test_request_round_trip(rpc, trid, params):
    req = parse_request(encode_request(rpc, params, trid))
    assert (req.rpc, req.trid) == (rpc, trid)
    assert len(req.params) == len(params)
    for raw, value in zip(req.params, params):
        if isinstance(value, str):
            assert raw == value.strip()
        else:
            assert float(raw) == value


@given(st.integers(0, 20000), st.integers(0, 9999), st.lists(finite, min_size=3, max_size=3),
       st.integers(0, 2**32 - 1))
def test_coordinate_reply_round_trip(rc, trid, enh, t_ms):
    values = (*enh, t_ms, *enh, t_ms)
    reply = parse_reply(encode_reply(rc, values, 0, trid))
    c = parse_coordinate(reply)
    assert reply.trid == trid and c.rc == rc and c.time_ms == t_ms
    if c.has_position:
        assert (c.east, c.north, c.height) == tuple(enh)


def test_split_values_keeps_commas_inside_quotes():
    assert split_values('1,"a,b",2') == ("1", "a,b", "2")
    assert split_values("") == ()


def test_crc16_is_crc16_arc_and_geocompys():
    assert crc16(b"123456789") == 0xBB3D            # the CRC-16/ARC check value
    assert crc16("") == 0
    geocompy = pytest.importorskip("geocompy.communication")
    for text in ("%R1Q,2082,5:0,1", "%R1P,0,0:0", "%R1Q,5004,123:"):
        assert crc16(text) == geocompy.crc16_bytewise(text) == geocompy.crc16_bitwise(text)


def test_checksummed_request_and_reply():
    line = encode_request(Rpc.TMC_GetCoordinate, (0, 1), trid=5, crc=True)
    assert line == f"%R1Q,2082,5,{crc16('%R1Q,2082,5:0,1')}:0,1\r\n".encode()
    assert parse_request(line).crc_ok is True and parse_request(line).params == ("0", "1")
    assert parse_request(line.replace(b":0,1", b":0,2")).crc_ok is False
    assert parse_request(b"%R1Q,0,1:\r\n").crc_ok is None
    reply = encode_reply(0, (1.5,), 0, 7, crc=True)
    assert parse_reply(reply).crc_ok is True and parse_reply(reply).values == ("1.5",)
    with pytest.raises(GeoComProtocolError):
        encode_request(Rpc.COM_NullProc, (), None, crc=True)


def test_double_precision_bytes_and_codes():
    assert format_double(2600012.3456789, 6) == "2600012.345679"
    assert format_double(1.0, 6) == "1.0" and format_double(-0.25, 15) == "-0.25" and format_double(2.6, 0) == "3"
    assert encode_reply(0, (2026, Byte(12), Byte(1)), 0, 0) == b"%R1P,0,0:0,2026,'0C','01'\r\n"
    reply = parse_reply(b"%R1P,3081,4:0\r\n")
    assert reply.code == 3081 and parse_reply(b"%R1P,0,4:8710\r\n").code == 8710
    assert rc_name(8714) == "8714 AUT_NOT_ENABLED" and rc_name(4242) == "4242"

"""ASCII GeoCOM framing, return codes, enumerations and typed results (no I/O here).

In: the procedures' parameters (requests) and the instrument's reply lines. Out: request lines
``%R1Q,<rpc>[,<trid>[,<crc>]]:<params>`` (CR LF terminated; the optional CRC-16/ARC of :func:`crc16`), parsed
replies (the communication code ``comrc``, the procedure's ``rc`` and its typed values), the return codes'
classes the driver acts on (:class:`RcClass`: OK, WARNING, NO_POSITION, ERROR) and the enumerations' values,
after Leica's TPS1200+ and Captivate (TS/MS) GeoCOM references, by chapter and function name; geocompy and
dmpack follow the same numbers and parameter orders. The procedures used, with their parameters, replies and
return codes: doc/design.md §13.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple, Optional, Sequence, Tuple, Union

from ..errors import InstrumentError

__all__ = [
    "GeoComProtocolError", "Byte", "RcClass", "Rpc", "RC", "Request", "Reply", "CoordinateReading",
    "classify_rc", "rc_name", "crc16", "format_double", "encode_request", "parse_request", "encode_reply",
    "parse_reply", "split_values", "parse_coordinate",
    "TMC_STOP", "TMC_DEF_DIST", "TMC_TRK_DIST", "TMC_CLEAR", "TMC_SIGNAL", "TMC_DO_MEASURE", "TMC_RTRK_DIST",
    "TMC_RED_TRK_DIST", "TMC_FREQUENCY", "TMC_MEASURE_PRGS_TPS1200", "TMC_MEA_INC", "TMC_AUTO_INC", "TMC_PLANE_INC",
    "BAP_CONT_REF_STANDARD", "BAP_CONT_REF_FAST", "BAP_CONT_RLESS_VISIBLE", "BAP_CONT_REF_SYNCHRO",
    "BAP_CONTINUOUS_PRGS", "BAP_REFL_USE", "BAP_REFL_LESS", "BAP_PRISM_360", "EDM_CONT_FAST", "AUT_CLOCKWISE",
    "AUT_ANTICLOCKWISE", "MOT_LOCKED_OUT", "MOT_LOCKED_IN", "MOT_PREDICTION", "MAX_DOUBLE_PRECISION",
]

Param = Union[int, float, str, bool]


class GeoComProtocolError(InstrumentError):
    """A line that is not a well-formed GeoCOM request or reply (the message quotes it)."""


class Rpc(enum.IntEnum):
    """GeoCOM remote procedure numbers used by the driver and the simulator."""

    COM_NullProc = 0
    COM_SetDoublePrecision = 107
    COM_GetDoublePrecision = 108
    COM_GetSWVersion = 110
    TMC_GetAngle1 = 2003
    TMC_DoMeasure = 2008
    TMC_GetStation = 2009
    TMC_SetStation = 2010
    TMC_SetEdmMode = 2020
    TMC_GetEdmMode = 2021
    TMC_GetPrismCorr = 2023
    TMC_SetPrismCorr = 2024
    TMC_GetCoordinate = 2082
    TMC_GetAngle5 = 2107
    TMC_GetSimpleMea = 2108
    TMC_SetOrientation = 2113
    TMC_GetSimpleCoord = 2116
    TMC_GetFullMeas = 2167
    CSV_GetInstrumentNo = 5003
    CSV_GetInstrumentName = 5004
    CSV_GetDateTime = 5008
    CSV_GetSWVersion = 5034
    CSV_GetDateTimeCentiSec = 5117
    MOT_ReadLockStatus = 6021
    AUT_LockIn = 9013
    AUT_MakePositioning = 9027
    AUT_Search = 9029
    AUT_FineAdjust = 9037
    AUT_PS_SearchNext = 9051
    BAP_SetPrismType = 17008
    BAP_GetPrismType = 17009
    BAP_GetMeasPrg = 17018
    BAP_SetMeasPrg = 17019
    BAP_SetTargetType = 17021
    BAP_GetTargetType = 17022
    AUS_SetUserAtrState = 18005
    AUS_GetUserAtrState = 18006
    AUS_SetUserLockState = 18007
    AUS_GetUserLockState = 18008


class RC(enum.IntEnum):
    """GeoCOM return codes the driver and the simulator use (manual, "Return codes", GRC_*)."""

    OK = 0
    UNDEFINED = 1
    IVPARAM = 2
    NOT_IMPL = 5
    NA = 27
    TMC_NO_FULL_CORRECTION = 1283
    TMC_ACCURACY_GUARANTEE = 1284
    TMC_ANGLE_OK = 1285
    TMC_ANGLE_NOT_FULL_CORR = 1288
    TMC_ANGLE_NO_ACC_GUARANTY = 1289
    TMC_ANGLE_ERROR = 1290
    TMC_DIST_PPM = 1291
    TMC_DIST_ERROR = 1292
    TMC_BUSY = 1293
    TMC_SIGNAL_ERROR = 1294
    MOT_NOT_LOCK = 1799
    COM_CANT_DECODE_REQ = 3080
    COM_PROC_UNAVAIL = 3081
    COM_NOT_GEOCOM = 3094
    COM_SRVR_RX_CHECKSUM_ERROR = 3101
    AUT_TIMEOUT = 8704
    AUT_MOTOR_ERROR = 8707
    AUT_NO_TARGET = 8710
    AUT_MULTIPLE_TARGETS = 8711
    AUT_NOT_ENABLED = 8714


def rc_name(rc: int) -> str:
    """``"8710 AUT_NO_TARGET"`` for a known code, the number alone otherwise."""
    return f"{int(rc)} {RC(rc).name}" if rc in RC._value2member_map_ else str(int(rc))


# Enumerations of the manual used as parameters.
# TMC_MEASURE_PRG (TMC chapter, TMC_DoMeasure). TMC_TRK_DIST (2) is the TPS1100 tracking program;
# the TPS1200+ and Captivate references no longer list it and track with TMC_RTRK_DIST (8).
TMC_STOP = 0
TMC_DEF_DIST = 1
TMC_TRK_DIST = 2
TMC_CLEAR = 3
TMC_SIGNAL = 4
TMC_DO_MEASURE = 6
TMC_RTRK_DIST = 8
TMC_RED_TRK_DIST = 10
TMC_FREQUENCY = 11
TMC_MEASURE_PRGS_TPS1200 = (TMC_STOP, TMC_DEF_DIST, TMC_CLEAR, TMC_SIGNAL, TMC_DO_MEASURE, TMC_RTRK_DIST,
                            TMC_RED_TRK_DIST, TMC_FREQUENCY)
# TMC_INCLINE_PRG
TMC_MEA_INC = 0
TMC_AUTO_INC = 1
TMC_PLANE_INC = 2
# BAP_USER_MEASPRG (BAP chapter, BAP_SetMeasPrg): the continuous (tracking) programs with a reflector
BAP_CONT_REF_STANDARD = 4   # IR tracking
BAP_CONT_REF_FAST = 5       # fast IR tracking (not on the TPS1200)
BAP_CONT_RLESS_VISIBLE = 6  # reflectorless tracking
BAP_CONT_REF_SYNCHRO = 10   # IR synchro tracking (TPS1200+ and later): angles synchronised with the EDM
BAP_CONTINUOUS_PRGS = (BAP_CONT_REF_STANDARD, BAP_CONT_REF_FAST, BAP_CONT_RLESS_VISIBLE, BAP_CONT_REF_SYNCHRO)
# BAP_TARGET_TYPE
BAP_REFL_USE = 0
BAP_REFL_LESS = 1
BAP_PRISM_360 = 3           # BAP_PRISMTYPE: Leica 360° prism
EDM_CONT_FAST = 9           # EDM_MODE (TMC_SetEdmMode): continuous fast
AUT_CLOCKWISE = 1           # AUT_PS_SearchNext direction
AUT_ANTICLOCKWISE = -1
MOT_LOCKED_OUT = 0          # MOT_LOCK_STATUS
MOT_LOCKED_IN = 1
MOT_PREDICTION = 2
MAX_DOUBLE_PRECISION = 15   # COM_SetDoublePrecision: 0..15 digits after the decimal point


class RcClass(enum.Enum):
    """What a return code means for a coordinate reply."""

    OK = "ok"
    WARNING = "warning"          # position present, accuracy flagged (1283, 1284)
    NO_POSITION = "no_position"  # angles only / no distance / no target (1285-1294, 1799, 8710)
    ERROR = "error"              # any other failure


def classify_rc(rc: int) -> RcClass:
    """Class of GeoCOM return code ``rc`` (see the module docstring)."""
    if rc == RC.OK:
        return RcClass.OK
    if rc in (RC.TMC_NO_FULL_CORRECTION, RC.TMC_ACCURACY_GUARANTEE):
        return RcClass.WARNING
    if RC.TMC_ANGLE_OK <= rc <= RC.TMC_SIGNAL_ERROR or rc in (RC.MOT_NOT_LOCK, RC.AUT_NO_TARGET):
        return RcClass.NO_POSITION
    return RcClass.ERROR


class Request(NamedTuple):
    """A parsed request: procedure number, transaction id (None when absent), raw parameters,
    and its checksum: None when the request carried none, else whether it matched."""

    rpc: int
    trid: Optional[int]
    params: Tuple[str, ...]
    crc_ok: Optional[bool] = None


class Reply(NamedTuple):
    """A parsed reply: communication code, transaction id (None when absent), return code,
    raw values (strings, quotes removed), and its checksum check (None: no checksum)."""

    comrc: int
    trid: Optional[int]
    rc: int
    values: Tuple[str, ...]
    crc_ok: Optional[bool] = None

    @property
    def rc_class(self) -> RcClass:
        return classify_rc(self.rc)

    @property
    def code(self) -> int:
        """The code that decides the call: the communication code when it is not 0, else rc."""
        return self.comrc if self.comrc != 0 else self.rc


class CoordinateReading(NamedTuple):
    """A TMC_GetCoordinate result. ``east``/``north``/``height`` in metres (NaN without a
    position), ``time_ms`` the instrument clock (ms) at the measurement; ``cont_*`` the same for
    the continuous (tracking) measurement; ``rc`` its return code."""

    rc: int
    east: float
    north: float
    height: float
    time_ms: int
    cont_east: float
    cont_north: float
    cont_height: float
    cont_time_ms: int

    @property
    def rc_class(self) -> RcClass:
        return classify_rc(self.rc)

    @property
    def has_position(self) -> bool:
        return self.rc_class in (RcClass.OK, RcClass.WARNING)


def crc16(text: Union[str, bytes]) -> int:
    """CRC-16/ARC (reflected polynomial 0xA001, initial value 0) of ``text``: the GeoCOM checksum
    as geocompy computes it over the line without its ``,<crc>`` field."""
    data = text.encode("ascii") if isinstance(text, str) else bytes(text)
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def format_double(value: float, digits: int) -> str:
    """A double as an instrument sends it with COM_SetDoublePrecision ``digits``: rounded to that
    many decimals, trailing zeros dropped (one kept after the point)."""
    if not math.isfinite(value):
        raise GeoComProtocolError(f"value {value!r} is not a finite number")
    if digits <= 0:
        return str(int(round(value)))
    text = f"{round(value, digits):.{digits}f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


class Byte(int):
    """A GeoCOM byte value, sent as two hexadecimal digits in single quotes (``'0C'``)."""


def _format_param(value: Param, digits: Optional[int] = None) -> str:
    if isinstance(value, Byte):
        return f"'{int(value) & 0xFF:02X}'"
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(int(value))
    if isinstance(value, float):
        if not math.isfinite(value):
            raise GeoComProtocolError(f"parameter {value!r} is not a finite number")
        return repr(float(value)) if digits is None else format_double(value, digits)
    if isinstance(value, str):
        if any(c in value for c in '"\r\n'):
            raise GeoComProtocolError(f"string parameter {value!r} contains a quote or a line break")
        return f'"{value}"'
    raise GeoComProtocolError(f"cannot encode parameter {value!r} of type {type(value).__name__}")


def _with_crc(prefix: str, fields: Sequence[int], body: str, crc: bool) -> bytes:
    head = prefix + ",".join(str(int(f)) for f in fields)
    if crc:
        head += f",{crc16(head + ':' + body)}"
    return (head + ":" + body + "\r\n").encode("ascii")


def encode_request(rpc: int, params: Sequence[Param] = (), trid: Optional[int] = None, crc: bool = False) -> bytes:
    """``%R1Q,<rpc>[,<trid>[,<crc>]]:<params>\\r\\n`` as ASCII bytes (``crc`` needs a trid)."""
    if crc and trid is None:
        raise GeoComProtocolError("a checksum needs a transaction id")
    fields = (rpc,) if trid is None else (rpc, trid)
    return _with_crc("%R1Q,", fields, ",".join(_format_param(p) for p in params), crc)


def encode_reply(rc: int, values: Sequence[Param] = (), comrc: int = 0, trid: Optional[int] = None,
                 digits: Optional[int] = None, crc: bool = False) -> bytes:
    """``%R1P,<comrc>[,<trid>[,<crc>]]:<rc>[,<values>]\\r\\n`` as ASCII bytes (the instrument's side);
    floats with ``digits`` decimals (COM_SetDoublePrecision), or in full when None."""
    if crc and trid is None:
        raise GeoComProtocolError("a checksum needs a transaction id")
    fields = (comrc,) if trid is None else (comrc, trid)
    body = ",".join([str(int(rc))] + [_format_param(v, digits) for v in values])
    return _with_crc("%R1P,", fields, body, crc)


def split_values(text: str) -> Tuple[str, ...]:
    """Split a comma-separated GeoCOM value list; double-quoted strings may hold commas."""
    if text == "":
        return ()
    values, current, quoted = [], [], False
    for c in text:
        if c == '"':
            quoted = not quoted
        elif c == "," and not quoted:
            values.append("".join(current))
            current = []
        else:
            current.append(c)
    if quoted:
        raise GeoComProtocolError(f"unterminated string in {text!r}")
    values.append("".join(current))
    return tuple(v.strip() for v in values)


def _header(line: bytes, prefix: str) -> Tuple[Tuple[int, ...], str, Optional[bool]]:
    """Header integers (at most 3), body text and the checksum check (None without a checksum)."""
    try:
        text = line.decode("ascii").strip()
    except UnicodeDecodeError:
        raise GeoComProtocolError(f"non-ASCII bytes in {line!r}") from None
    if not text.startswith(prefix):
        raise GeoComProtocolError(f"expected {prefix!r} at the start of {text!r}")
    head, sep, body = text[len(prefix):].partition(":")
    if not sep:
        raise GeoComProtocolError(f"missing ':' in {text!r}")
    try:
        fields = tuple(int(f) for f in head.split(","))
    except ValueError:
        raise GeoComProtocolError(f"header of {text!r} is not integers") from None
    if len(fields) not in (1, 2, 3):
        raise GeoComProtocolError(f"header of {text!r} must be <code>[,<trid>[,<crc>]]")
    crc_ok = None
    if len(fields) == 3:
        unsigned = prefix + ",".join(head.split(",")[:2]) + ":" + body
        crc_ok = fields[2] == crc16(unsigned)
    return fields, body, crc_ok


def parse_request(line: bytes) -> Request:
    """Parse a request line (CR LF optional). Raises GeoComProtocolError."""
    fields, body, crc_ok = _header(line, "%R1Q,")
    return Request(fields[0], fields[1] if len(fields) >= 2 else None, split_values(body), crc_ok)


def parse_reply(line: bytes) -> Reply:
    """Parse a reply line (CR LF optional). Raises GeoComProtocolError."""
    fields, body, crc_ok = _header(line, "%R1P,")
    values = split_values(body)
    if not values:
        raise GeoComProtocolError(f"reply {line!r} has no return code")
    try:
        rc = int(values[0])
    except ValueError:
        raise GeoComProtocolError(f"return code {values[0]!r} of {line!r} is not an integer") from None
    return Reply(fields[0], fields[1] if len(fields) >= 2 else None, rc, values[1:], crc_ok)


def parse_coordinate(reply: Reply) -> CoordinateReading:
    """Typed TMC_GetCoordinate result. Replies without a position may carry no values: their
    coordinates are NaN and their times -1. Raises GeoComProtocolError on a malformed reply."""
    v = reply.values
    if len(v) < 8:
        if reply.rc_class in (RcClass.OK, RcClass.WARNING):
            raise GeoComProtocolError(f"TMC_GetCoordinate reply with rc {reply.rc} has {len(v)} values, expected 8")
        nan = float("nan")
        return CoordinateReading(reply.rc, nan, nan, nan, -1, nan, nan, nan, -1)
    try:
        e, n, h, ce, cn, ch = (float(v[i]) for i in (0, 1, 2, 4, 5, 6))
        t, ct = int(v[3]), int(v[7])
    except ValueError:
        raise GeoComProtocolError(f"TMC_GetCoordinate values {v!r} are not numbers") from None
    if reply.rc_class not in (RcClass.OK, RcClass.WARNING):
        e = n = h = ce = cn = ch = float("nan")
    return CoordinateReading(reply.rc, e, n, h, t, ce, cn, ch, ct)

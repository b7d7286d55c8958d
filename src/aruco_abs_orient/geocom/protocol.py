"""ASCII GeoCOM framing, return codes and typed results (no I/O here).

Framing (Leica GeoCOM reference manual, TPS1200/TS30/TS16/MS60 family, "ASCII protocol"):

- request ``%R1Q,<rpc>[,<trid>]:<p1>,<p2>,...`` terminated by CR LF;
- reply ``%R1P,<comrc>[,<trid>]:<rc>[,<v1>,<v2>,...]`` terminated by CR LF.

``comrc`` is the communication-layer code (0 = the request reached the instrument), ``rc`` the
return code of the procedure. Strings travel in double quotes. Parameter orders followed here
(as used across public GeoCOM implementations such as dabamos/dmpack ``dm_geocom_api.f90``
and the GeoCOM TPS1100 v1.07 / TPS1200 manuals):

==========================  =====  ========================================  ==========================
procedure                   rpc    request parameters                        reply values after rc
==========================  =====  ========================================  ==========================
COM_NullProc                0      --                                        --
COM_GetSWVersion            110    --                                        release, version, subversion
TMC_DoMeasure               2008   command (TMC_MEASURE_PRG), inc mode       --
TMC_GetStation              2009   --                                        E0, N0, H0, Hi (m)
TMC_SetStation              2010   E0, N0, H0, Hi (m)                        --
TMC_SetEdmMode              2020   EDM_MODE                                  --
TMC_GetPrismCorr            2023   --                                        prism constant (m)
TMC_SetPrismCorr            2024   prism constant (m)                        --
TMC_GetCoordinate           2082   wait time (ms), inc mode                  E, N, H (m), time (ms),
                                                                             E, N, H (m), time (ms) cont.
TMC_SetOrientation          2113   Hz orientation (rad)                      --
TMC_GetSimpleCoord          2116   wait time (ms), inc mode                  E, N, H (m)
CSV_GetInstrumentNo         5003   --                                        serial number
CSV_GetInstrumentName       5004   --                                        "name"
CSV_GetSWVersion            5034   --                                        release, version, subversion
MOT_ReadLockStatus          6021   --                                        MOT_LOCK_STATUS
AUT_LockIn                  9013   --                                        --
BAP_SetPrismType            17008  BAP_PRISMTYPE                             --
BAP_SetMeasPrg              17019  BAP_USER_MEASPRG                          --
AUS_SetUserLockState        18007  ON_OFF_TYPE                               --
==========================  =====  ========================================  ==========================

Return codes (GeoCOM manual, TMC and AUT subsystems) and the classes the driver uses:

- 0 GRC_OK: a position, use it (:attr:`RcClass.OK`);
- 1283 TMC_NO_FULL_CORRECTION (measurement without full correction) and 1284
  TMC_ACCURACY_GUARANTEE (accuracy not guaranteed): the reply carries a position; keep it and
  flag it (:attr:`RcClass.WARNING`);
- 1285 TMC_ANGLE_OK (only angles valid, no distance) ... 1294 TMC_SIGNAL_ERROR, and the lock
  codes 8710 AUT_NO_TARGET / 1799 MOT_NOT_LOCK: no usable position (:attr:`RcClass.NO_POSITION`);
- anything else: :attr:`RcClass.ERROR`.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple, Optional, Sequence, Tuple, Union

__all__ = [
    "GeoComProtocolError", "RcClass", "Rpc", "RC", "Request", "Reply", "CoordinateReading",
    "classify_rc", "encode_request", "parse_request", "encode_reply", "parse_reply",
    "split_values", "parse_coordinate", "EDM_CONT_FAST", "TMC_TRK_DIST", "TMC_STOP", "TMC_AUTO_INC",
    "BAP_PRISM_360", "MOT_LOCKED_OUT", "MOT_LOCKED_IN", "MOT_PREDICTION",
]

Param = Union[int, float, str, bool]


class GeoComProtocolError(ValueError):
    """A line that is not a well-formed GeoCOM request or reply (the message quotes it)."""


class Rpc(enum.IntEnum):
    """GeoCOM remote procedure numbers used by the driver and the simulator."""

    COM_NullProc = 0
    COM_GetSWVersion = 110
    TMC_DoMeasure = 2008
    TMC_GetStation = 2009
    TMC_SetStation = 2010
    TMC_SetEdmMode = 2020
    TMC_GetPrismCorr = 2023
    TMC_SetPrismCorr = 2024
    TMC_GetCoordinate = 2082
    TMC_SetOrientation = 2113
    TMC_GetSimpleCoord = 2116
    CSV_GetInstrumentNo = 5003
    CSV_GetInstrumentName = 5004
    CSV_GetSWVersion = 5034
    MOT_ReadLockStatus = 6021
    AUT_LockIn = 9013
    BAP_SetPrismType = 17008
    BAP_SetMeasPrg = 17019
    AUS_SetUserLockState = 18007


class RC(enum.IntEnum):
    """GeoCOM return codes the driver distinguishes (GeoCOM manual, GRC_* constants)."""

    OK = 0
    IVPARAM = 2
    NOT_IMPL = 5
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
    AUT_NO_TARGET = 8710


# Enumerations of the GeoCOM manual used as parameters.
EDM_CONT_FAST = 9        # EDM_MODE: continuous fast (tracking)
TMC_STOP = 0             # TMC_MEASURE_PRG: stop measurement
TMC_TRK_DIST = 2         # TMC_MEASURE_PRG: tracking distance
TMC_AUTO_INC = 1         # TMC_INCLINE_PRG: automatic inclination
BAP_PRISM_360 = 3        # BAP_PRISMTYPE: 360° prism
MOT_LOCKED_OUT = 0       # MOT_LOCK_STATUS
MOT_LOCKED_IN = 1
MOT_PREDICTION = 2


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
    """A parsed request: procedure number, transaction id (None when absent), raw parameters."""

    rpc: int
    trid: Optional[int]
    params: Tuple[str, ...]


class Reply(NamedTuple):
    """A parsed reply: communication code, transaction id (None when absent), return code,
    raw values (strings, quotes removed)."""

    comrc: int
    trid: Optional[int]
    rc: int
    values: Tuple[str, ...]

    @property
    def rc_class(self) -> RcClass:
        return classify_rc(self.rc)


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


def _format_param(value: Param) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(int(value))
    if isinstance(value, float):
        if not math.isfinite(value):
            raise GeoComProtocolError(f"parameter {value!r} is not a finite number")
        return repr(float(value))
    if isinstance(value, str):
        if any(c in value for c in '"\r\n'):
            raise GeoComProtocolError(f"string parameter {value!r} contains a quote or a line break")
        return f'"{value}"'
    raise GeoComProtocolError(f"cannot encode parameter {value!r} of type {type(value).__name__}")


def encode_request(rpc: int, params: Sequence[Param] = (), trid: Optional[int] = None) -> bytes:
    """``%R1Q,<rpc>[,<trid>]:<params>\\r\\n`` as ASCII bytes."""
    head = f"%R1Q,{int(rpc)}" if trid is None else f"%R1Q,{int(rpc)},{int(trid)}"
    return (head + ":" + ",".join(_format_param(p) for p in params) + "\r\n").encode("ascii")


def encode_reply(rc: int, values: Sequence[Param] = (), comrc: int = 0, trid: Optional[int] = None) -> bytes:
    """``%R1P,<comrc>[,<trid>]:<rc>[,<values>]\\r\\n`` as ASCII bytes (the instrument's side)."""
    head = f"%R1P,{int(comrc)}" if trid is None else f"%R1P,{int(comrc)},{int(trid)}"
    body = ",".join([str(int(rc))] + [_format_param(v) for v in values])
    return (head + ":" + body + "\r\n").encode("ascii")


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


def _header(line: bytes, prefix: str) -> Tuple[Tuple[int, ...], str]:
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
    if len(fields) not in (1, 2):
        raise GeoComProtocolError(f"header of {text!r} must be <code>[,<trid>]")
    return fields, body


def parse_request(line: bytes) -> Request:
    """Parse a request line (CR LF optional). Raises GeoComProtocolError."""
    fields, body = _header(line, "%R1Q,")
    return Request(fields[0], fields[1] if len(fields) == 2 else None, split_values(body))


def parse_reply(line: bytes) -> Reply:
    """Parse a reply line (CR LF optional). Raises GeoComProtocolError."""
    fields, body = _header(line, "%R1P,")
    values = split_values(body)
    if not values:
        raise GeoComProtocolError(f"reply {line!r} has no return code")
    try:
        rc = int(values[0])
    except ValueError:
        raise GeoComProtocolError(f"return code {values[0]!r} of {line!r} is not an integer") from None
    return Reply(fields[0], fields[1] if len(fields) == 2 else None, rc, values[1:])


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

"""Thread-safe GeoCOM client over pyserial (``serial.serial_for_url``).

Ports are pyserial URLs: ``/dev/ttyUSB0``, ``socket://host:port``, ``rfc2217://host:port``,
``loop://``. A reply's own bytes take ``10·n/baud`` s on a serial line (and on rfc2217://, a serial
port at the far end); over ``socket://`` (an instrument on WLAN/Ethernet) a reply arrives as one
packet and has no such byte timing: ``byte_timing`` says which applies (default: all but
``socket://``), and the coordinate replies carry that wire time for the clock fit. A reply whose
communication code is not 0 (3080, 3081, 3101...) fails the call like a return code does. Every
request carries a transaction id; a reply with another id (a late answer to
a request that already timed out) is discarded, as is any line that is not a reply (garbage,
echoes): the reader resynchronises on the next ``%R1P,`` it sees. One call at a time holds the
port (a lock), so several threads may share a client.
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading
import time
from typing import NamedTuple, Optional, Sequence, Tuple

import serial

from ..errors import InstrumentError
from .protocol import (
    AUT_CLOCKWISE,
    TMC_AUTO_INC,
    CoordinateReading,
    GeoComProtocolError,
    Param,
    Reply,
    Rpc,
    encode_request,
    parse_coordinate,
    parse_reply,
    rc_name,
)

__all__ = ["GeoComError", "GeoComLinkError", "GeoComTimeout", "GeoComRcError", "TimedCoordinate",
           "GeoComClient", "wire_time_s", "rpc_name", "default_byte_timing"]

_REPLY_START = b"%R1P,"
_MAX_LINE = 4096


class GeoComError(InstrumentError):
    """Base class of the client's errors."""


class GeoComLinkError(GeoComError):
    """The port cannot be opened, read or written (names the port)."""


class GeoComTimeout(GeoComError):
    """No reply with the request's transaction id within the timeout."""


def rpc_name(rpc: int) -> str:
    """``"AUT_LockIn"`` for a known procedure number, the number otherwise."""
    return Rpc(rpc).name if rpc in Rpc._value2member_map_ else str(int(rpc))


class GeoComRcError(GeoComError):
    """A procedure answered with a code other than 0 (its communication code, or else its rc)."""

    def __init__(self, rpc: int, rc: int):
        super().__init__(f"{rpc_name(rpc)} returned {rc_name(rc)}")
        self.rpc = rpc
        self.rc = rc


class TimedCoordinate(NamedTuple):
    """A coordinate reply with its host reception time ``received_s`` (s, time.time() of the
    last byte) and the reply's wire time ``reply_tx_s`` (s, 10 bits per byte at the baud on a
    link with byte timing, 0 without)."""

    reading: CoordinateReading
    received_s: float
    reply_tx_s: float


def wire_time_s(n_bytes: int, baud: int) -> float:
    """Seconds ``n_bytes`` take on a serial line at ``baud`` (8N1: 10 bits per byte)."""
    return 10.0 * n_bytes / float(baud)


class _TcpPort:
    """``socket://host:port`` as the few port methods the client uses. pyserial's own handler is not
    used: in pyserial 3.4 (Ubuntu 20.04's python3-serial) its open() spins for ever on a connection
    the peer closes at once (an instrument or serial server refusing a second client), and it
    leaves Nagle's algorithm on, which delays small requests."""

    def __init__(self, url: str):
        host, sep, port = url[len("socket://"):].split("?")[0].rpartition(":")
        if not sep or not host or not port.isdigit():
            raise GeoComLinkError(f"expected socket://host:port, got {url!r}")
        self._socket = socket.create_connection((host, int(port)), timeout=5.0)
        self._socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._socket.settimeout(1.0)   # writes: a peer that stops reading fails within 1 s

    def fileno(self) -> int:
        return self._socket.fileno()

    def write(self, data: bytes) -> None:
        self._socket.sendall(data)

    def flush(self) -> None:
        """Nothing to flush: TCP_NODELAY sends at once."""

    def read(self, size: int) -> bytes:
        """What has arrived (b"" if nothing); raises OSError when the peer closed the connection."""
        ready, _, _ = select.select([self._socket], [], [], 0)
        if not ready:
            return b""
        data = self._socket.recv(size)
        if not data:
            raise OSError("the instrument closed the connection")
        return data

    def close(self) -> None:
        self._socket.close()


def default_byte_timing(url: str) -> bool:
    """Whether replies on ``url`` cross a serial line byte by byte: all ports but ``socket://``."""
    return not url.strip().lower().startswith("socket://")


class GeoComClient:
    """GeoCOM over one pyserial port. ``timeout_s`` is the default reply timeout (s);
    ``byte_timing`` None takes :func:`default_byte_timing`."""

    def __init__(self, url: str, baud: int = 115200, timeout_s: float = 0.5, byte_timing: Optional[bool] = None):
        self.url = url
        self.baud = int(baud)
        self.byte_timing = default_byte_timing(url) if byte_timing is None else bool(byte_timing)
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._buffer = bytearray()
        self._trid = 0
        self.garbage_bytes = 0
        self.stale_replies = 0
        self._stamp = 0.0
        try:
            # non-blocking reads; waiting is done with select() on the port's descriptor so that
            # a reply is taken in one piece the moment it arrives (its reception time matters)
            if url.strip().lower().startswith("socket://"):
                self._serial = _TcpPort(url.strip())
            else:
                self._serial = serial.serial_for_url(url, baudrate=self.baud, timeout=0, write_timeout=1.0)
        except (serial.SerialException, GeoComLinkError, ValueError, OSError) as e:
            raise GeoComLinkError(f"cannot open GeoCOM port {url!r}: {e}") from None
        try:
            self._fileno: Optional[int] = self._serial.fileno()
        except (AttributeError, NotImplementedError, OSError, serial.SerialException):
            self._fileno = None  # loop://, rfc2217://: poll every millisecond

    def close(self) -> None:
        with contextlib.suppress(serial.SerialException, OSError):
            self._serial.close()

    def __enter__(self) -> GeoComClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- framing -------------------------------------------------------------------------
    def _next_trid(self) -> int:
        self._trid = self._trid % 9999 + 1
        return self._trid

    def _read_line(self, deadline: float) -> Tuple[bytes, float]:
        """The next reply-looking line (starting at its ``%R1P,``) and its reception time."""
        while True:
            nl = self._buffer.find(b"\n")
            while nl >= 0:
                raw = bytes(self._buffer[: nl + 1])
                del self._buffer[: nl + 1]
                start = raw.rfind(_REPLY_START)
                self.garbage_bytes += len(raw) if start < 0 else start
                if start >= 0:
                    return raw[start:], self._stamp
                nl = self._buffer.find(b"\n")
            if len(self._buffer) > _MAX_LINE:  # a flood without line ends: keep the tail only
                self.garbage_bytes += len(self._buffer) - len(_REPLY_START)
                del self._buffer[: -len(_REPLY_START)]
            remaining = deadline - time.time()
            if remaining <= 0:
                raise GeoComTimeout(f"no reply on {self.url!r} within the timeout")
            try:
                if self._fileno is not None:
                    select.select([self._fileno], [], [], min(remaining, 0.05))
                else:
                    time.sleep(min(remaining, 0.001))
                chunk = self._serial.read(4096)
            except (serial.SerialException, OSError, TypeError, AttributeError, ValueError) as e:
                raise GeoComLinkError(f"reading {self.url!r} failed: {e}") from None
            self._stamp = time.time()
            if chunk:
                self._buffer += chunk

    def call(self, rpc: int, params: Sequence[Param] = (),
             timeout_s: Optional[float] = None) -> Tuple[Reply, float, int]:
        """Send one request and wait for its reply. Returns ``(reply, received_s, reply_bytes)``.

        Raises GeoComTimeout, GeoComLinkError. Lines that are not replies and replies with
        another transaction id are discarded (counted in ``garbage_bytes``/``stale_replies``)."""
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        with self._lock:
            trid = self._next_trid()
            request = encode_request(rpc, params, trid)
            try:
                self._serial.write(request)
                self._serial.flush()
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                raise GeoComLinkError(f"writing to {self.url!r} failed: {e}") from None
            deadline = time.time() + timeout
            while True:
                line, received = self._read_line(deadline)
                try:
                    reply = parse_reply(line)
                except GeoComProtocolError:
                    self.garbage_bytes += len(line)
                    continue
                if reply.trid != trid:
                    self.stale_replies += 1
                    continue
                return reply, received, len(line)

    def _checked(self, rpc: int, params: Sequence[Param] = (), timeout_s: Optional[float] = None) -> Reply:
        reply = self.call(rpc, params, timeout_s)[0]
        if reply.code != 0:
            raise GeoComRcError(rpc, reply.code)
        return reply

    def code(self, rpc: int, params: Sequence[Param] = (), timeout_s: Optional[float] = None) -> int:
        """Call ``rpc`` and return its code (the communication code when not 0, else the rc),
        for procedures whose failures the caller tells apart."""
        return self.call(rpc, params, timeout_s)[0].code

    def _values(self, rpc: int, n: int, timeout_s: Optional[float] = None) -> Tuple[str, ...]:
        reply = self._checked(rpc, (), timeout_s)
        if len(reply.values) < n:
            raise GeoComError(f"{rpc_name(rpc)} replied {len(reply.values)} values, expected {n}")
        return reply.values[:n]

    # --- procedures ----------------------------------------------------------------------
    def null_proc(self, timeout_s: Optional[float] = None) -> None:
        """COM_NullProc: checks that the instrument answers."""
        self._checked(Rpc.COM_NullProc, (), timeout_s)

    def instrument_name(self) -> str:
        """CSV_GetInstrumentName, e.g. ``"MS60"``."""
        return self._values(Rpc.CSV_GetInstrumentName, 1)[0]

    def instrument_number(self) -> int:
        """CSV_GetInstrumentNo: the serial number."""
        return int(self._values(Rpc.CSV_GetInstrumentNo, 1)[0])

    def firmware_version(self) -> str:
        """CSV_GetSWVersion (the instrument's system software) as ``release.version.subversion``."""
        return ".".join(str(int(v)) for v in self._values(Rpc.CSV_GetSWVersion, 3))

    def geocom_version(self) -> str:
        """COM_GetSWVersion (the GeoCOM release) as ``release.version.subversion``."""
        return ".".join(str(int(v)) for v in self._values(Rpc.COM_GetSWVersion, 3))

    def set_double_precision(self, digits: int) -> None:
        """COM_SetDoublePrecision: decimals of the doubles in the replies."""
        self._checked(Rpc.COM_SetDoublePrecision, (int(digits),))

    def double_precision(self) -> int:
        """COM_GetDoublePrecision."""
        return int(self._values(Rpc.COM_GetDoublePrecision, 1)[0])

    def set_meas_prg(self, program: int) -> None:
        """BAP_SetMeasPrg (BAP_USER_MEASPRG)."""
        self._checked(Rpc.BAP_SetMeasPrg, (int(program),))

    def set_target_type(self, target_type: int) -> None:
        """BAP_SetTargetType (BAP_TARGET_TYPE; 0 = with reflector)."""
        self._checked(Rpc.BAP_SetTargetType, (int(target_type),))

    def fine_adjust(self, hz_rad: float, v_rad: float, timeout_s: Optional[float] = None) -> int:
        """AUT_FineAdjust within a search window (rad); returns its code (0: on the prism)."""
        return self.code(Rpc.AUT_FineAdjust, (float(hz_rad), float(v_rad), 0), timeout_s)

    def make_positioning(self, hz_rad: float, v_rad: float, timeout_s: Optional[float] = None) -> int:
        """AUT_MakePositioning to Hz, V (rad; AUT_NORMAL, AUT_POSITION: the angles, no target); returns its code."""
        return self.code(Rpc.AUT_MakePositioning, (float(hz_rad), float(v_rad), 0, 0, 0), timeout_s)

    def search(self, hz_rad: float, v_rad: float, timeout_s: Optional[float] = None) -> int:
        """AUT_Search over an area (rad); returns its code (0: a prism in the ATR's field)."""
        return self.code(Rpc.AUT_Search, (float(hz_rad), float(v_rad), 0), timeout_s)

    def power_search_next(self, direction: int = AUT_CLOCKWISE, swing: bool = False,
                          timeout_s: Optional[float] = None) -> int:
        """AUT_PS_SearchNext (PowerSearch, 360°); returns its code (0: a prism found)."""
        return self.code(Rpc.AUT_PS_SearchNext, (int(direction), bool(swing)), timeout_s)

    def lock_in(self, timeout_s: Optional[float] = None) -> int:
        """AUT_LockIn: start following the prism. Returns its code (0 locked, 8710 no target,
        8714 LOCK mode off)."""
        return self.code(Rpc.AUT_LockIn, (), timeout_s)

    def set_user_lock_state(self, on: bool) -> None:
        """AUS_SetUserLockState: LOCK mode on (True) or off."""
        self._checked(Rpc.AUS_SetUserLockState, (bool(on),))

    def lock_status(self) -> int:
        """MOT_ReadLockStatus: 0 locked out, 1 locked in, 2 prediction."""
        return int(self._values(Rpc.MOT_ReadLockStatus, 1)[0])

    def set_prism_type(self, prism_type: int) -> None:
        """BAP_SetPrismType (BAP_PRISMTYPE; 3 = 360° prism)."""
        self._checked(Rpc.BAP_SetPrismType, (int(prism_type),))

    def set_prism_constant(self, constant_m: float) -> None:
        """TMC_SetPrismCorr: additive prism constant in metres."""
        self._checked(Rpc.TMC_SetPrismCorr, (float(constant_m),))

    def prism_constant(self) -> float:
        """TMC_GetPrismCorr: additive prism constant in metres."""
        return float(self._values(Rpc.TMC_GetPrismCorr, 1)[0])

    def do_measure(self, command: int, inc_mode: int = TMC_AUTO_INC) -> None:
        """TMC_DoMeasure (TMC_MEASURE_PRG: 8 TMC_RTRK_DIST tracking, 3 TMC_CLEAR, 0 TMC_STOP)."""
        self._checked(Rpc.TMC_DoMeasure, (int(command), int(inc_mode)))

    def get_coordinate(self, wait_ms: int = 0, inc_mode: int = TMC_AUTO_INC,
                       timeout_s: Optional[float] = None) -> TimedCoordinate:
        """TMC_GetCoordinate: the position at the last distance with that distance's instrument
        time (ms), the continuous coordinate with the time of its angles, and the host reception
        time. The rc is in the reading (warnings keep their position); a communication code
        other than 0 raises GeoComRcError."""
        reply, received, nbytes = self.call(Rpc.TMC_GetCoordinate, (int(wait_ms), int(inc_mode)), timeout_s)
        if reply.comrc != 0:
            raise GeoComRcError(Rpc.TMC_GetCoordinate, reply.comrc)
        try:
            reading = parse_coordinate(reply)
        except GeoComProtocolError as e:
            raise GeoComError(str(e)) from None
        return TimedCoordinate(reading, received, wire_time_s(nbytes, self.baud) if self.byte_timing else 0.0)

    def get_simple_coord(self, wait_ms: int = 0, inc_mode: int = TMC_AUTO_INC) -> Tuple[int, float, float, float]:
        """TMC_GetSimpleCoord: ``(rc, E, N, H)`` in metres (no instrument time)."""
        reply = self.call(Rpc.TMC_GetSimpleCoord, (int(wait_ms), int(inc_mode)))[0]
        v = [float(x) for x in reply.values[:3]] if len(reply.values) >= 3 else [float("nan")] * 3
        return reply.code, v[0], v[1], v[2]

    def set_station(self, east: float, north: float, height: float, instrument_height: float) -> None:
        """TMC_SetStation: station coordinates E0, N0, H0 and instrument height Hi (m); the
        instrument refuses it (1293 TMC_BUSY) while a distance exists: TMC_CLEAR first."""
        self._checked(Rpc.TMC_SetStation, (float(east), float(north), float(height), float(instrument_height)))

    def get_station(self) -> Tuple[float, float, float, float]:
        """TMC_GetStation: ``(E0, N0, H0, Hi)`` in metres."""
        e, n, h, hi = (float(v) for v in self._values(Rpc.TMC_GetStation, 4))
        return e, n, h, hi

    def set_orientation(self, hz_rad: float) -> None:
        """TMC_SetOrientation: the current Hz direction becomes ``hz_rad`` (radians); refused
        like TMC_SetStation while a distance exists."""
        self._checked(Rpc.TMC_SetOrientation, (float(hz_rad),))

"""The simulator's GeoCOM dispatch: one ASCII request line in, one scheduled reply out.

In: a request line and the host time (s) it was complete on the link, and an
:class:`~.instrument.Ms60Instrument` whose procedures it calls.
Out: an :class:`Answer` (the encoded reply, the host time its last byte is due, garbage to send
before it, the truth of a coordinate), a :class:`Motion` to run first (a motorised procedure), or
None (a blank line, or a reply dropped by fault injection).
Contract: every request line but a blank one gets a well-formed reply carrying its transaction id
(0 when it had none). The ``strict`` profile decodes and checks every parameter (count or type:
COM_CANT_DECODE_REQ; range: IVPARAM; unknown procedure: COM_PROC_UNAVAIL; not GeoCOM:
COM_NOT_GEOCOM; bad checksum: COM_SRVR_RX_CHECKSUM_ERROR); an exception inside a procedure is logged
in :attr:`GeoComDispatcher.internal_errors` and answered with UNDEFINED, never with silence.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple, Union

from .accuracy import ARCSEC
from .instrument import Ms60Instrument, TruthRecord
from .protocol import (
    AUT_ANTICLOCKWISE,
    AUT_CLOCKWISE,
    BAP_CONT_REF_FAST,
    BAP_CONT_REF_SYNCHRO,
    MAX_DOUBLE_PRECISION,
    RC,
    TMC_MEASURE_PRGS_TPS1200,
    TMC_TRK_DIST,
    Byte,
    GeoComProtocolError,
    Request,
    Rpc,
    encode_reply,
    parse_request,
)

__all__ = ["LATE_S", "Answer", "Motion", "GeoComDispatcher"]

LATE_S = 0.0005
"""A coordinate reply due more than this long ago (s) is measured again (an idle host's sleep
overshoots by ~0.1–0.3 ms; a loaded one by several ms)."""


class Answer(NamedTuple):
    """A reply waiting for its time: ``data`` (bytes), ``send_s`` (host time its last byte is due,
    s), ``prefix`` (garbage sent before it), ``delay_s`` (modelled measurement-to-first-byte time,
    s), for TMC_GetCoordinate its ``truth`` and ``forced_rc`` (an injected warning, or None), and
    the request it answers."""

    data: bytes
    send_s: float
    prefix: bytes
    delay_s: float
    truth: Optional[TruthRecord]
    forced_rc: Optional[int]
    request: Request


class Motion(NamedTuple):
    """A motorised procedure in progress: the request and when it started (host s)."""

    request: Request
    start_s: float


class _Refusal(Exception):
    """A request answered without running it: ``comrc`` (communication layer) or ``rc``."""

    def __init__(self, rc: int = 0, comrc: int = 0):
        super().__init__(rc, comrc)
        self.rc = rc
        self.comrc = comrc


# --- parameter signatures (strict validation) --------------------------------------------------
_Check = Tuple[str, Callable[[Union[int, float]], bool]]
_INC: _Check = ("i", lambda v: v in (0, 1, 2))                       # TMC_INCLINE_PRG
_BOOL: _Check = ("i", lambda v: v in (0, 1))
_WAIT: _Check = ("i", lambda v: 0 <= v <= 3_600_000)                 # ms
_WINDOW: _Check = ("f", lambda v: 0.0 <= v <= 2 * math.pi)           # search window, rad
_COORD: _Check = ("f", lambda v: abs(v) < 1e8)                       # m
_SIGNATURES: Dict[int, Tuple[_Check, ...]] = {
    Rpc.COM_NullProc: (),
    Rpc.COM_SetDoublePrecision: (("i", lambda v: 0 <= v <= MAX_DOUBLE_PRECISION),),
    Rpc.COM_GetDoublePrecision: (),
    Rpc.COM_GetSWVersion: (),
    Rpc.TMC_GetAngle1: (_INC,),
    Rpc.TMC_DoMeasure: (("i", lambda v: v in TMC_MEASURE_PRGS_TPS1200 + (TMC_TRK_DIST,)), _INC),
    Rpc.TMC_GetStation: (),
    Rpc.TMC_SetStation: (_COORD, _COORD, _COORD, ("f", lambda v: abs(v) < 100.0)),
    Rpc.TMC_SetEdmMode: (("i", lambda v: 0 <= v <= 14),),
    Rpc.TMC_GetEdmMode: (),
    Rpc.TMC_GetPrismCorr: (),
    Rpc.TMC_SetPrismCorr: (("f", lambda v: abs(v) < 1.0),),
    Rpc.TMC_GetCoordinate: (_WAIT, _INC),
    Rpc.TMC_GetAngle5: (_INC,),
    Rpc.TMC_GetSimpleMea: (_WAIT, _INC),
    Rpc.TMC_SetOrientation: (("f", lambda v: abs(v) <= 2 * math.pi),),
    Rpc.TMC_GetSimpleCoord: (_WAIT, _INC),
    Rpc.TMC_GetFullMeas: (_WAIT, _INC),
    Rpc.CSV_GetInstrumentNo: (),
    Rpc.CSV_GetInstrumentName: (),
    Rpc.CSV_GetDateTime: (),
    Rpc.CSV_GetSWVersion: (),
    Rpc.CSV_GetDateTimeCentiSec: (),
    Rpc.MOT_ReadLockStatus: (),
    Rpc.AUT_LockIn: (),
    Rpc.AUT_MakePositioning: (("f", lambda v: abs(v) <= 4 * math.pi), ("f", lambda v: abs(v) <= 4 * math.pi),
                              ("i", lambda v: v in (0, 1)), ("i", lambda v: v == 0), _BOOL),
    Rpc.AUT_Search: (_WINDOW, _WINDOW, _BOOL),
    Rpc.AUT_FineAdjust: (_WINDOW, _WINDOW, _BOOL),
    Rpc.AUT_PS_SearchNext: (("i", lambda v: v in (AUT_CLOCKWISE, AUT_ANTICLOCKWISE)), _BOOL),
    Rpc.BAP_SetPrismType: (("i", lambda v: 0 <= v <= 12),),
    Rpc.BAP_GetPrismType: (),
    Rpc.BAP_GetMeasPrg: (),
    Rpc.BAP_SetMeasPrg: (("i", lambda v: 0 <= v <= 11),),
    Rpc.BAP_SetTargetType: (_BOOL,),
    Rpc.BAP_GetTargetType: (),
    Rpc.AUS_SetUserAtrState: (_BOOL,),
    Rpc.AUS_GetUserAtrState: (),
    Rpc.AUS_SetUserLockState: (_BOOL,),
    Rpc.AUS_GetUserLockState: (),
}
_MOTIONS = (Rpc.AUT_LockIn, Rpc.AUT_FineAdjust, Rpc.AUT_Search, Rpc.AUT_PS_SearchNext, Rpc.AUT_MakePositioning)
_ANGLE_RPCS = (Rpc.TMC_GetAngle1, Rpc.TMC_GetAngle5, Rpc.TMC_GetSimpleMea, Rpc.TMC_GetSimpleCoord,
               Rpc.TMC_GetFullMeas)


def _decode(request: Request) -> List[Union[int, float]]:
    """The request's parameters as numbers; _Refusal 3080 (count or type) or IVPARAM (range)."""
    signature = _SIGNATURES[request.rpc]
    if len(request.params) != len(signature):
        raise _Refusal(comrc=RC.COM_CANT_DECODE_REQ)
    values: List[Union[int, float]] = []
    for text, (kind, _) in zip(request.params, signature):
        try:
            values.append(int(text) if kind == "i" else float(text))
        except ValueError:
            raise _Refusal(comrc=RC.COM_CANT_DECODE_REQ) from None
    for value, (_, ok) in zip(values, signature):
        if not (math.isfinite(value) and ok(value)):
            raise _Refusal(RC.IVPARAM)
    return values


def _trid(request: Request) -> int:
    return 0 if request.trid is None else request.trid


# --- the non-motorised procedures: RPC → handler(instrument, decoded parameters, t_complete) → values ----
_Params = Sequence[Union[int, float]]
_Handler = Callable[[Ms60Instrument, _Params, float], tuple]


def _stored(name: str, kind: type, is_set: bool) -> _Handler:
    """The handler of a setting the instrument only stores (``is_set``) or reports back."""
    def handler(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
        if not is_set:
            return (getattr(ins, name),)
        setattr(ins, name, kind(p[0]))
        return ()

    return handler


def _date_time(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    """CSV_GetDateTime: year, then month, day, hour, minute, second as GeoCOM bytes (UTC)."""
    tm = time.gmtime(t_complete)
    return (tm.tm_year,) + tuple(Byte(v) for v in (tm.tm_mon, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec))


def _date_time_centisec(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    """CSV_GetDateTimeCentiSec: year, month, day, hour, minute, second, centiseconds (UTC)."""
    tm = time.gmtime(t_complete)
    return (tm.tm_year, tm.tm_mon, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, int(t_complete * 100) % 100)


def _set_user_lock(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    ins.set_user_lock(bool(p[0]))
    return ()


def _set_user_atr(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    ins.set_user_atr(bool(p[0]))
    return ()


def _set_meas_prg(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    if ins.config.model == "TPS1200" and int(p[0]) in (BAP_CONT_REF_FAST, BAP_CONT_REF_SYNCHRO):
        raise _Refusal(RC.IVPARAM)   # this firmware does not know the program
    ins.meas_prg = int(p[0])
    return ()


def _refuse_while_measured(ins: Ms60Instrument) -> None:
    """TMC_BUSY (strict) while a distance exists: TMC_DoMeasure(TMC_CLEAR) first."""
    if ins.config.strict and (ins.distance is not None or ins.tracking):
        raise _Refusal(RC.TMC_BUSY)


def _set_station(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    _refuse_while_measured(ins)
    ins.station = tuple(float(v) for v in p)
    return ()


def _set_orientation(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    _refuse_while_measured(ins)
    ins.orientation_rad = float(p[0])
    return ()


def _do_measure(ins: Ms60Instrument, p: _Params, t_complete: float) -> tuple:
    if int(p[0]) == TMC_TRK_DIST and ins.config.strict:
        raise _Refusal(RC.IVPARAM)  # not a TPS1200+/Captivate measurement program
    ins.do_measure(int(p[0]), t_complete)
    return ()


_HANDLERS: Dict[int, _Handler] = {
    Rpc.COM_NullProc: lambda ins, p, t: (),
    Rpc.COM_GetSWVersion: lambda ins, p, t: ins.config.geocom,
    Rpc.CSV_GetSWVersion: lambda ins, p, t: ins.config.firmware,
    Rpc.CSV_GetInstrumentName: lambda ins, p, t: (ins.config.name,),
    Rpc.CSV_GetInstrumentNo: lambda ins, p, t: (ins.config.serial_number,),
    Rpc.CSV_GetDateTime: _date_time,
    Rpc.CSV_GetDateTimeCentiSec: _date_time_centisec,
    Rpc.MOT_ReadLockStatus: lambda ins, p, t: (1 if ins.locked else 0,),
    Rpc.AUS_SetUserLockState: _set_user_lock,
    Rpc.AUS_SetUserAtrState: _set_user_atr,
    Rpc.AUS_GetUserLockState: lambda ins, p, t: (int(ins.user_lock),),
    Rpc.AUS_GetUserAtrState: lambda ins, p, t: (int(ins.user_atr),),
    Rpc.BAP_SetMeasPrg: _set_meas_prg,
    Rpc.TMC_GetStation: lambda ins, p, t: ins.station,
    Rpc.TMC_SetStation: _set_station,
    Rpc.TMC_SetOrientation: _set_orientation,
    Rpc.TMC_DoMeasure: _do_measure,
}
#: settings the instrument only stores and reports back: their setters and getters
_HANDLERS.update({rpc: _stored(name, kind, is_set) for set_rpc, get_rpc, name, kind in (
    (Rpc.COM_SetDoublePrecision, Rpc.COM_GetDoublePrecision, "precision", int),
    (Rpc.BAP_SetTargetType, Rpc.BAP_GetTargetType, "target_type", int),
    (Rpc.BAP_SetPrismType, Rpc.BAP_GetPrismType, "prism_type", int),
    (Rpc.TMC_SetEdmMode, Rpc.TMC_GetEdmMode, "edm_mode", int),
    (Rpc.TMC_SetPrismCorr, Rpc.TMC_GetPrismCorr, "prism_constant_m", float),
) for rpc, is_set in ((set_rpc, True), (get_rpc, False))})
#: BAP_GetMeasPrg reports what BAP_SetMeasPrg stored (the setter refuses programs first)
_HANDLERS[Rpc.BAP_GetMeasPrg] = _stored("meas_prg", int, False)


class GeoComDispatcher:
    """Requests to replies for ``instrument``, with the link's timing and the random reply faults of its
    configuration. :attr:`byte_timing` (set by the transport) adds the serial wire time of each line."""

    def __init__(self, instrument: Ms60Instrument):
        self.instrument = instrument
        self.requests = 0
        self.internal_errors: List[str] = []
        self.byte_timing = True

    def handle(self, line: bytes, t_complete: float) -> Union[Answer, Motion, None]:
        """Answer one request line completed at ``t_complete`` (s): an answer, a motion to run
        first, or None (a blank line, or a dropped reply)."""
        try:
            req = parse_request(line)
        except GeoComProtocolError:
            data = self._refusal_reply(line)
            return None if data is None else self._answer(data, t_complete, None, None, Request(-1, 0, ()))
        self.requests += 1
        try:
            return self._dispatch(req, t_complete)
        except Exception as e:  # a bug must show in the tests (internal_errors), never silence the instrument
            self.internal_errors.append(f"{line!r}: {type(e).__name__}: {e}")
            return self._answer(encode_reply(RC.UNDEFINED, (), 0, _trid(req)), t_complete, None, None, req)

    @staticmethod
    def _refusal_reply(line: bytes) -> Optional[bytes]:
        """The reply to a line that is not a decodable request (None for a blank line)."""
        text = line.strip()
        if not text:
            return None
        if not text.startswith(b"%R1Q,"):
            return encode_reply(0, (), RC.COM_NOT_GEOCOM, 0)
        head = text[5:].split(b":", 1)[0].split(b",")
        trid = int(head[1]) if len(head) >= 2 and head[1].strip().isdigit() else 0
        return encode_reply(0, (), RC.COM_CANT_DECODE_REQ, trid)

    def _dispatch(self, req: Request, t_complete: float) -> Union[Answer, Motion, None]:
        ins = self.instrument
        trid = _trid(req)
        crc = req.crc_ok is True
        if req.crc_ok is False:
            return self._answer(encode_reply(0, (), RC.COM_SRVR_RX_CHECKSUM_ERROR, trid), t_complete, None, None, req)
        if req.rpc not in _SIGNATURES:
            return self._answer(encode_reply(0, (), RC.COM_PROC_UNAVAIL, trid, crc=crc), t_complete, None, None, req)
        try:
            params = _decode(req)
        except _Refusal as r:
            return self._answer(encode_reply(r.rc, (), r.comrc, trid, crc=crc), t_complete, None, None, req)
        if req.rpc in _MOTIONS:
            return Motion(req, t_complete)
        tick = math.floor(ins.instrument_ms_at(t_complete)) + 1
        if req.rpc == Rpc.TMC_GetCoordinate:
            f, rng = ins.config.faults, ins.rng
            forced = rng.choice((RC.TMC_NO_FULL_CORRECTION, RC.TMC_ACCURACY_GUARANTEE)) \
                if rng.random() < f.warning else None
            data, truth = self._coordinate(tick, forced, req)
            return self._answer(data, truth.angles_time_s, truth, forced, req)
        with ins.state_lock:
            try:
                if req.rpc in _ANGLE_RPCS:
                    rc, values = self._angles_reply(req.rpc, tick)
                    t_meas = ins.host_time_of(tick)
                else:
                    rc, values, t_meas = RC.OK, self._execute(req.rpc, params, t_complete), t_complete
            except _Refusal as r:
                rc, values, t_meas = r.rc, (), t_complete
            data = encode_reply(rc, values, 0, trid, ins.precision, crc)
        return self._answer(data, t_meas, None, None, req)

    def _execute(self, rpc: int, p: Sequence[Union[int, float]], t_complete: float) -> tuple:
        """Run a non-motorised procedure (state lock held); returns its values or raises _Refusal."""
        handler = _HANDLERS.get(rpc)
        if handler is None:
            raise AssertionError(f"procedure {rpc} has a signature but no implementation")
        return handler(self.instrument, p, t_complete)

    def _angles_reply(self, rpc: int, tick: int) -> Tuple[int, tuple]:
        """rc and values of the angle procedures with angles at counter ``tick``."""
        ins, c = self.instrument, self.instrument.config
        rc, hz, v, slope, dist_ms = ins.angles(tick)
        t_ms = int(tick) % c.wrap_ms
        acc = (1.0 if c.accuracy is None else c.accuracy.angle_arcsec) * ARCSEC  # the class's angle σ, rad
        if rpc == Rpc.TMC_GetAngle5:
            return RC.OK, (hz, v)
        if rpc == Rpc.TMC_GetAngle1:
            return RC.OK, (hz, v, acc, t_ms, 0.0, 0.0, acc, t_ms, 0)
        if rpc == Rpc.TMC_GetSimpleMea:
            return rc, (hz, v, slope)
        if rpc == Rpc.TMC_GetFullMeas:
            d_ms = dist_ms % c.wrap_ms if dist_ms is not None else 0
            return rc, (hz, v, acc, 0.0, 0.0, acc, slope, d_ms)
        # TMC_GetSimpleCoord: the current angles with the last distance
        e0, n0, h0, hi = ins.station
        if dist_ms is None:
            return rc, (0.0, 0.0, 0.0)
        return rc, (e0 + slope * math.sin(v) * math.sin(hz), n0 + slope * math.sin(v) * math.cos(hz),
                    h0 + hi + slope * math.cos(v))

    def _coordinate(self, tick: int, forced_rc: Optional[int], request: Request) -> Tuple[bytes, TruthRecord]:
        """TMC_GetCoordinate reply with angles at counter ``tick`` (unwrapped ms) and its truth."""
        ins = self.instrument
        with ins.state_lock:
            rc, values, truth = ins.coordinate(tick, forced_rc, request.trid)
            data = encode_reply(rc, values, 0, _trid(request), ins.precision, request.crc_ok is True)
        return data, truth

    def _answer(self, data: bytes, t_meas: float, truth: Optional[TruthRecord], forced_rc: Optional[int],
                request: Request) -> Optional[Answer]:
        """Schedule reply ``data`` for a measurement at host time ``t_meas`` with the link's delays
        and the random faults; None when the reply is dropped."""
        c, f, rng = self.instrument.config, self.instrument.config.faults, self.instrument.rng
        delay = c.latency_s + rng.uniform(-c.jitter_s, c.jitter_s)
        if rng.random() < f.spike:
            delay += c.spike_s
        if rng.random() < f.late:
            delay += c.late_s
        drop = rng.random() < f.drop
        prefix = bytes(rng.randrange(32, 127) for _ in range(rng.randint(1, 40))) if rng.random() < f.garbage else b""
        if rng.random() < 0.5 and prefix:
            prefix += b"\r\n"
        if drop:
            if truth is not None:
                self.instrument.truth.append(truth._replace(sent=False))
            return None
        return Answer(data, t_meas + delay + self.wire_s(len(data)), prefix, delay, truth, forced_rc, request)

    def wire_s(self, n_bytes: int) -> float:
        """Serial wire time of ``n_bytes`` (0 over TCP: no byte timing)."""
        return 10.0 * n_bytes / self.instrument.config.baud if self.byte_timing else 0.0

    def remeasured(self, answer: Answer, now: float) -> Optional[Answer]:
        """None if ``answer`` may still be sent at host time ``now`` (s), else the same reply
        measured at the first counter tick from which its latency ``delay_s`` ends after ``now``."""
        truth = answer.truth
        if truth is None or now - answer.send_s <= LATE_S:
            return None
        tick = math.ceil(self.instrument.instrument_ms_at(now - answer.delay_s - self.wire_s(len(answer.data))))
        while True:  # a shorter reply is due earlier on the wire: then the next tick
            data, later = self._coordinate(tick, answer.forced_rc, answer.request)
            send_s = later.angles_time_s + answer.delay_s + self.wire_s(len(data))
            if send_s >= now:
                return answer._replace(data=data, truth=later, send_s=send_s)
            tick += 1

    def motion_answer(self, motion: Motion, wait: Callable[[float], bool]) -> Optional[Answer]:
        """Run ``motion`` and schedule its reply; ``wait(s)`` sleeps up to s seconds and returns True to
        abort (a link outage or a stop: then None)."""
        req = motion.request
        rc = self.instrument.run_motion(req.rpc, _decode(req), motion.start_s, wait)
        if rc is None:
            return None
        return self._answer(encode_reply(rc, (), 0, _trid(req), crc=req.crc_ok is True), time.time(), None,
                            None, req)

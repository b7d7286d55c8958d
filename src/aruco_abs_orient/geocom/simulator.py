"""A simulated Leica MS60 (or TPS1200) speaking ASCII GeoCOM, on a pty or on TCP (127.0.0.1 only).

Profiles. ``strict`` (the default) behaves like the instruments of the TPS1200+/Captivate GeoCOM
references: every parameter is decoded and checked (wrong count or type: communication code 3080
COM_CANT_DECODE_REQ; out of range: rc 2 IVPARAM; unknown procedure: 3081 COM_PROC_UNAVAIL; a
line that is not GeoCOM: 3094 COM_NOT_GEOCOM; a bad checksum: 3101), TMC_DoMeasure knows only the
TPS1200+ measurement programs (program 2 TMC_TRK_DIST is refused), a station or orientation is
refused with 1293 TMC_BUSY while a distance exists (TMC_DoMeasure TMC_CLEAR first), AUT_LockIn
needs LOCK mode (else 8714 AUT_NOT_ENABLED) and a prism in the ATR's view (AUT_FineAdjust first),
motorised procedures take their time, and the EDM measures at its own rate. ``lenient`` keeps the
behaviour of a forgiving instrument: program 2 tracks, lock-in is instant and needs neither LOCK
mode nor fine adjustment, the station may be set at any time, and every poll gets a fresh distance.
Both profiles answer every request line with a well-formed reply carrying the request's
transaction id (0 when it had none) and stay silent only on blank lines.

Models. ``MS60`` (default) has PowerSearch and synchro tracking (BAP_CONT_REF_SYNCHRO); ``TPS1200``
models a TPS1200 without PowerSearch (AUT_PS_SearchNext: rc 5 NOT_IMPL) whose firmware refuses the
fast and synchro tracking programs (BAP_SetMeasPrg 5 and 10: IVPARAM), so a client has to take
BAP_CONT_REF_STANDARD and AUT_Search.

What it models (all times are host ``time.time()`` seconds; the truth log uses them):

- the link: on a pty (a serial line) a request of n bytes is complete ``10·n/baud`` s after its
  first byte and a reply of m bytes takes ``10·m/baud`` s to send; over TCP (an instrument on
  WLAN/Ethernet) there is no byte timing: the request is complete when it arrives and the reply
  leaves in one piece. In both, a reply leaves ``latency ± jitter`` s after the measurement;
- the instrument clock: a millisecond counter ``T = floor(((t − t_boot)(1 + drift))·1000 +
  offset_ms) mod wrap_ms``; angles are measured at the next counter tick after a request is
  complete;
- the EDM: once tracking runs (TMC_DoMeasure TMC_RTRK_DIST, or TMC_DEF_DIST with a continuous
  BAP program) it measures a distance every ``1000/edm_rate_hz`` counter ms while it sees the
  prism (locked, or fine-adjusted onto it). TMC_GetCoordinate reports the position at the last
  distance with that distance's time (CoordTime) and, as the continuous coordinate, the current
  angles with that distance at the angles' time (CoordContTime); two polls between distances
  return the same distance and time. A tracking distance older than three EDM periods is no
  distance (1285 TMC_ANGLE_OK, angles only);
- the prism: a TUM trajectory (positions interpolated, looped) or a built-in smooth track; the
  simulator assumes a correct set-up, so coordinates are the track's whatever station and
  orientation a client sets (it keeps and reports them);
- measurement noise (``accuracy``, an :class:`~.accuracy.InstrumentAccuracy`; None: exact): the slope
  distance, Hz and V of every reported coordinate are the true ones plus independent normal errors of
  the class's σ (the distance's shared by a coordinate's distance and continuous parts), and a prism
  centring error of ``prism_mm`` per axis; the truth log keeps the true positions;
- where the telescope points (Hz, V): at the prism while locked; where the prism was when the lock
  was lost (a hidden prism loses it at once); where AUT_MakePositioning turned it (``positioning_s`` plus
  the angle at ``slew_rad_s``). The motorised procedures take their time and the instrument answers
  nothing else meanwhile: AUT_FineAdjust (``fine_adjust_s``) finds the prism only within its search
  window around that direction when it starts; AUT_Search (``search_s``) only within its area around
  it; AUT_PS_SearchNext (PowerSearch, a fan sweeping the horizon in ``power_search_s`` per turn from that
  direction) when the sweep passes the prism's Hz while it is in view; a search ends ``found_s`` after
  it found the prism (pointing at it), else with AUT_NO_TARGET; AUT_LockIn (``lock_in_s``) needs a fine
  adjustment onto the prism;
- faults: garbage bytes before a reply, dropped replies, late replies (after the client's
  timeout), warnings 1283/1284 (position kept), lost lock for a while, link outages (TCP: the
  connection is closed and refused; pty: the line goes silent), latency spikes.

Every TMC_GetCoordinate answer is logged in :attr:`Ms60Simulator.truth` with the true host time
of its distance, its instrument time and the true position, so tests can measure errors.

A real instrument keeps its reply timing whatever the host does; the simulator is a host thread
and may wake late to send (a loaded machine). A coordinate reply that would leave more than
``LATE_S`` after its due time is measured again at the next counter tick and sent with the same
latency after it (the instrument answers with its latest measurement); the truth records what
was actually reported.
"""

from __future__ import annotations

import contextlib
import math
import os
import random
import select
import socket
import threading
import time
import tty
from typing import Callable, Dict, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from ..errors import InstrumentError
from .accuracy import ARCSEC, InstrumentAccuracy
from .protocol import (
    AUT_ANTICLOCKWISE,
    AUT_CLOCKWISE,
    BAP_CONT_REF_FAST,
    BAP_CONT_REF_SYNCHRO,
    BAP_CONTINUOUS_PRGS,
    MAX_DOUBLE_PRECISION,
    RC,
    TMC_CLEAR,
    TMC_DEF_DIST,
    TMC_DO_MEASURE,
    TMC_MEASURE_PRGS_TPS1200,
    TMC_RED_TRK_DIST,
    TMC_RTRK_DIST,
    TMC_STOP,
    TMC_TRK_DIST,
    Byte,
    GeoComProtocolError,
    Request,
    Rpc,
    encode_reply,
    parse_request,
)

__all__ = ["LATE_S", "PROFILES", "MODELS", "SimulatorError", "FaultRates", "SimConfig", "TruthRecord",
           "Ms60Simulator", "builtin_track", "tum_track"]


LATE_S = 0.0005
"""A coordinate reply due more than this long ago (s) is measured again (an idle host's sleep
overshoots by ~0.1–0.3 ms; a loaded one by several ms)."""

PROFILES = ("strict", "lenient")
MODELS = ("MS60", "TPS1200")

_MAX_REMEASURE = 20  # then send late rather than never (a host too loaded to keep any timing)
_STALE_PERIODS = 3   # a tracking distance older than this many EDM periods is no distance


class SimulatorError(InstrumentError):
    """Bad simulator settings (names the setting) or a trajectory that cannot be played."""


class FaultRates(NamedTuple):
    """Random faults. Per reply: ``garbage``, ``drop``, ``late``, ``warning``, ``spike``
    (probabilities); per second: ``lock_loss``, ``link_loss`` (rates, 1/s) with outages lasting
    uniformly ``outage_s`` seconds."""

    garbage: float = 0.0
    drop: float = 0.0
    late: float = 0.0
    warning: float = 0.0
    spike: float = 0.0
    lock_loss: float = 0.0
    link_loss: float = 0.0
    outage_s: Tuple[float, float] = (0.3, 1.5)


class SimConfig(NamedTuple):
    """Simulator settings: ``baud`` (bit/s), ``latency_s`` and ``jitter_s`` (reply delay after
    the measurement is latency ± jitter, uniform, s), ``spike_s`` (extra delay of a latency
    spike, s), ``late_s`` (delay of a late reply, s), instrument clock ``clock_offset_ms`` (ms),
    ``clock_drift`` (dimensionless, 1e-6 = 1 ppm), ``wrap_ms`` (counter modulus), ``faults``,
    ``profile`` (strict/lenient), ``model`` (MS60/TPS1200), ``edm_rate_hz`` (tracking distances
    per second), durations of the motorised procedures (s), ``accuracy`` (measurement noise, None: exact),
    identity (name, serial number, firmware and GeoCOM versions)."""

    baud: int = 115200
    latency_s: float = 0.012
    jitter_s: float = 0.010
    spike_s: float = 0.150
    late_s: float = 0.8
    clock_offset_ms: float = 123456.0
    clock_drift: float = 40e-6
    wrap_ms: int = 2 ** 32
    faults: FaultRates = FaultRates()
    profile: str = "strict"
    model: str = "MS60"
    edm_rate_hz: float = 20.0
    lock_in_s: float = 1.2
    fine_adjust_s: float = 0.3
    search_s: float = 3.0
    power_search_s: float = 5.0
    found_s: float = 0.2
    positioning_s: float = 0.1
    slew_rad_s: float = math.pi / 2
    accuracy: Optional[InstrumentAccuracy] = None
    name: str = "MS60"
    serial_number: int = 1234567
    firmware: Tuple[int, int, int] = (7, 10, 2)
    geocom: Tuple[int, int, int] = (1, 50, 0)

    @property
    def min_latency_s(self) -> float:
        """The shortest measurement-to-first-reply-byte time (s)."""
        return self.latency_s - self.jitter_s

    @property
    def strict(self) -> bool:
        return self.profile == "strict"

    def validate(self) -> None:
        """Raise SimulatorError naming the first bad setting."""
        checks = [
            ("baud > 0", self.baud > 0),
            ("latency_s ≥ jitter_s ≥ 0", self.latency_s >= self.jitter_s >= 0),
            (f"profile in {PROFILES}", self.profile in PROFILES),
            (f"model in {MODELS}", self.model in MODELS),
            ("0 < edm_rate_hz ≤ 100", 0 < self.edm_rate_hz <= 100),
            ("slew_rad_s > 0", self.slew_rad_s > 0),
            ("motion times ≥ 0", min(self.lock_in_s, self.fine_adjust_s, self.search_s, self.power_search_s,
                                     self.positioning_s,
                                     self.found_s) >= 0),
        ]
        for what, ok in checks:
            if not ok:
                raise SimulatorError(f"simulator settings: {what} is required")


class TruthRecord(NamedTuple):
    """One TMC_GetCoordinate answer: true host time of its distance (s), that distance's
    instrument time (raw ms), true prism position then (m, map), rc, transaction id, whether the
    reply was sent, and the host time (s) and instrument time (raw ms) of its angles."""

    time_s: float
    instrument_ms: int
    position: Tuple[float, float, float]
    rc: int
    trid: Optional[int]
    sent: bool
    angles_time_s: float = float("nan")
    angles_ms: int = -1


class _Answer(NamedTuple):
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


class _Motion(NamedTuple):
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
#: settings the instrument only stores and reports back: RPC → (attribute, type, True for the setter)
_STORED = {rpc: (name, kind, is_set) for set_rpc, get_rpc, name, kind in (
    (Rpc.COM_SetDoublePrecision, Rpc.COM_GetDoublePrecision, "precision", int),
    (Rpc.BAP_SetTargetType, Rpc.BAP_GetTargetType, "target_type", int),
    (Rpc.BAP_SetPrismType, Rpc.BAP_GetPrismType, "prism_type", int),
    (Rpc.TMC_SetEdmMode, Rpc.TMC_GetEdmMode, "edm_mode", int),
    (Rpc.TMC_SetPrismCorr, Rpc.TMC_GetPrismCorr, "prism_constant_m", float),
) for rpc, is_set in ((set_rpc, True), (get_rpc, False))}
#: BAP_GetMeasPrg reports what BAP_SetMeasPrg stored (the setter refuses programs first)
_STORED[Rpc.BAP_GetMeasPrg] = ("meas_prg", int, False)
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


def builtin_track(t: float) -> np.ndarray:
    """A smooth prism track (m): a 10 m × 6 m figure of eight around (10, 3, 1.2), period ~31 s."""
    w = 2 * math.pi / 31.4
    return np.array([10.0 + 5.0 * math.sin(w * t), 3.0 + 3.0 * math.sin(2 * w * t), 1.2 + 0.05 * math.sin(w * t)])


def tum_track(path: str) -> Callable[[float], np.ndarray]:
    """Prism positions of a TUM file as a function of time since its first stamp (looped)."""
    from ..tum import TumError, read_tum

    try:
        traj = read_tum(path)
    except TumError as e:
        raise SimulatorError(str(e)) from None
    if len(traj.stamps) < 2 or not np.all(np.diff(traj.stamps) > 0):
        raise SimulatorError(f"{path}: need ≥ 2 poses with increasing stamps")
    t_rel = traj.stamps - traj.stamps[0]
    period = float(t_rel[-1])

    def position(t: float) -> np.ndarray:
        tt = t % period
        return np.array([np.interp(tt, t_rel, traj.positions[:, k]) for k in range(3)])

    return position


class Ms60Simulator:
    """The instrument. Start it with :meth:`serve_pty` or :meth:`serve_tcp`; stop with :meth:`close`."""

    def __init__(self, config: Optional[SimConfig] = None, track: Callable[[float], np.ndarray] = builtin_track,
                 seed: Optional[int] = None):
        config = SimConfig() if config is None else config
        config.validate()
        self.config = config
        self.track = track
        self._rng = random.Random(seed)
        self._state_lock = threading.RLock()
        self.t_boot = time.time()
        self.prism_visible = True
        self.locked = False
        self.adjusted = False          # the telescope points at the prism (AUT_FineAdjust succeeded)
        self._aim: Optional[Tuple[float, float]] = None  # (Hz, V) rad where the telescope points; None: at the prism
        self.user_lock = False         # LOCK mode (AUS_SetUserLockState)
        self.user_atr = False
        self.tracking = False          # the EDM measures continuously
        self.precision = MAX_DOUBLE_PRECISION
        self.station = (0.0, 0.0, 0.0, 0.0)
        self.orientation_rad = 0.0
        self.prism_constant_m = 0.0
        self.prism_type = 0
        self.target_type = 0
        self.meas_prg = 0
        self.edm_mode = 0
        self.distance: Optional[Tuple[int, np.ndarray]] = None   # (unwrapped tick ms, true position)
        self._edm_t0_ms = 0.0          # counter ms of the EDM's first tick since tracking started
        self._edm_from_ms = 0.0        # distances before this counter ms were not seen
        self.truth: List[TruthRecord] = []
        self.events: List[Tuple[float, str, float]] = []  # (start s, kind, end s or start)
        self.requests = 0
        self.internal_errors: List[str] = []
        self._byte_timing = True
        self._link_down_until = 0.0
        self._stop = threading.Event()
        self._threads: List[threading.Thread] = []
        self._pty: Optional[Tuple[int, int]] = None
        self._server: Optional[socket.socket] = None
        self._conn: Optional[socket.socket] = None

    # --- instrument clock ----------------------------------------------------------------
    def instrument_ms_at(self, t: float) -> float:
        """Instrument counter (ms, not wrapped, fractional) at host time ``t`` (s)."""
        c = self.config
        return (t - self.t_boot) * (1.0 + c.clock_drift) * 1000.0 + c.clock_offset_ms

    def host_time_of(self, counter_ms: float) -> float:
        """Host time (s) at which the unwrapped counter reads ``counter_ms``."""
        c = self.config
        return self.t_boot + (counter_ms - c.clock_offset_ms) / 1000.0 / (1.0 + c.clock_drift)

    def _event(self, kind: str, until: Optional[float] = None) -> None:
        now = time.time()
        self.events.append((now, kind, now if until is None else until))

    # --- EDM -----------------------------------------------------------------------------
    @property
    def edm_period_ms(self) -> float:
        """Counter ms between two tracking distances (1 ms in the lenient profile: every poll
        gets a fresh distance)."""
        return 1000.0 / self.config.edm_rate_hz if self.config.strict else 1.0

    def _edm_sees_prism(self) -> bool:
        return self.tracking and self.prism_visible and (self.locked or self.adjusted)

    def _settle_edm(self, now_ms: float) -> None:
        """Bring :attr:`distance` up to counter ``now_ms`` (call before any change of state)."""
        if not self._edm_sees_prism():
            return
        period = self.edm_period_ms
        k = math.floor((now_ms - self._edm_t0_ms) / period)
        tick = math.ceil(self._edm_t0_ms + k * period)
        if tick > now_ms:
            tick = math.ceil(self._edm_t0_ms + (k - 1) * period)
        if tick >= self._edm_from_ms and (self.distance is None or tick > self.distance[0]):
            self.distance = (tick, self.track(self.host_time_of(tick) - self.t_boot))

    def _change(self, change: Callable[[], None]) -> None:
        """Apply ``change`` to the state with the EDM's distances kept right across it."""
        with self._state_lock:
            now_ms = self.instrument_ms_at(time.time())
            self._settle_edm(now_ms)
            saw = self._edm_sees_prism()
            change()
            if self._edm_sees_prism() and not saw:
                self._edm_from_ms = now_ms

    def _prism_direction(self, t: Optional[float] = None) -> Tuple[float, float]:
        """(Hz, V) rad of the prism at host time ``t`` (now)."""
        hz, v, _ = self._polar(self.track((time.time() if t is None else t) - self.t_boot))
        return hz, v

    def aim(self) -> Tuple[float, float]:
        """(Hz, V) rad where the telescope points now: at the prism while locked (or before anything turned it)."""
        if self._aim is None or (self.locked and self.prism_visible):
            return self._prism_direction()
        return self._aim

    def _point_at_prism(self) -> None:
        self._aim = None

    def set_prism_visible(self, visible: bool) -> None:
        """Hide (the lock and the fine adjustment are lost at once, the telescope stays where the prism was)
        or show the prism (the lock needs AUT_FineAdjust and AUT_LockIn again)."""
        def change() -> None:
            if not visible and self.prism_visible:
                self._aim = self.aim()
            self.prism_visible = bool(visible)
            if not visible:
                self.locked = self.adjusted = False

        self._change(change)
        self._event("prism_visible" if visible else "prism_hidden")

    def link_down(self, duration_s: float) -> None:
        """Break the link for ``duration_s`` seconds (TCP: close and refuse; pty: silence)."""
        self._link_down_until = time.time() + float(duration_s)
        self._event("link_down", self._link_down_until)
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)

    @property
    def link_up(self) -> bool:
        return time.time() >= self._link_down_until

    # --- geometry --------------------------------------------------------------------------
    def _polar(self, p: np.ndarray) -> Tuple[float, float, float]:
        """Hz (azimuth from north, clockwise, rad), V (zenith angle, rad) and slope distance (m)
        of point ``p`` seen from the station (its height plus the instrument height)."""
        e0, n0, h0, hi = self.station
        d = np.asarray(p, dtype=float) - (e0, n0, h0 + hi)
        dist = float(np.linalg.norm(d))
        hz = math.atan2(d[0], d[1]) % (2 * math.pi)
        v = math.acos(max(-1.0, min(1.0, d[2] / dist))) if dist > 0 else 0.0
        return hz, v, dist

    def _from_polar(self, hz: float, v: float, slope: float) -> np.ndarray:
        """The point (m) at Hz, V (rad) and slope distance (m) from the station."""
        e0, n0, h0, hi = self.station
        return np.array([e0 + slope * math.sin(v) * math.sin(hz), n0 + slope * math.sin(v) * math.cos(hz),
                         h0 + hi + slope * math.cos(v)])

    def _noise(self, kind: str, distance: float = 0.0) -> float:
        """A random error of the accuracy class: of an angle (rad) or of the slope distance ``distance`` (m)."""
        a = self.config.accuracy
        if a is None:
            return 0.0
        return self._rng.gauss(0.0, a.distance_sigma(distance) if kind == "distance" else a.angle_arcsec * ARCSEC)

    def _centring(self) -> np.ndarray:
        """The prism's centring error (m, per axis) of one measurement."""
        a = self.config.accuracy
        if a is None or a.prism_mm == 0:
            return np.zeros(3)
        return np.array([self._rng.gauss(0.0, 1e-3 * a.prism_mm) for _ in range(3)])

    def _measure(self, tick: int) -> Tuple[int, Optional[Tuple[int, np.ndarray]], np.ndarray]:
        """Angles at counter ``tick``: (rc, the distance they combine with or None, true prism
        position at the tick). rc is 0 or 1285 TMC_ANGLE_OK (no valid distance)."""
        self._settle_edm(tick)
        now_p = self.track(self.host_time_of(tick) - self.t_boot)
        dist = self.distance
        if dist is None or (self.tracking and tick - dist[0] > _STALE_PERIODS * self.edm_period_ms):
            return RC.TMC_ANGLE_OK, None, now_p
        return RC.OK, dist, now_p

    def _coordinate(self, tick: int, forced_rc: Optional[int], request: Request) -> Tuple[bytes, TruthRecord]:
        """TMC_GetCoordinate reply with angles at counter ``tick`` (unwrapped ms) and its truth."""
        c = self.config
        with self._state_lock:
            rc, dist, now_p = self._measure(tick)
            t_ms = int(tick) % c.wrap_ms
            if dist is None:
                values: tuple = (0.0, 0.0, 0.0, t_ms, 0.0, 0.0, 0.0, t_ms)
                truth = TruthRecord(float("nan"), -1, (math.nan,) * 3, int(rc), request.trid, True,
                                    self.host_time_of(tick), t_ms)
            else:
                if forced_rc is not None:
                    rc = forced_rc
                d_ms, p = dist
                hz_d, v_d, slope = self._polar(p)
                hz, v, _ = self._polar(now_p)
                slope_error = self._noise("distance", slope)
                measured = self._from_polar(hz_d + self._noise("angle"), v_d + self._noise("angle"),
                                            slope + slope_error) + self._centring()
                cont = tuple(self._from_polar(hz + self._noise("angle"), v + self._noise("angle"),
                                              slope + slope_error) + self._centring())
                values = tuple(float(x) for x in measured) + (int(d_ms) % c.wrap_ms,) + cont + (t_ms,)
                truth = TruthRecord(self.host_time_of(d_ms), int(d_ms) % c.wrap_ms,
                                    (float(p[0]), float(p[1]), float(p[2])), int(rc), request.trid, True,
                                    self.host_time_of(tick), t_ms)
            data = encode_reply(rc, values, 0, self._trid(request), self.precision, request.crc_ok is True)
        return data, truth

    def _angles_reply(self, rpc: int, tick: int) -> Tuple[int, tuple]:
        """rc and values of the angle procedures with angles at counter ``tick``."""
        c = self.config
        rc, dist, now_p = self._measure(tick)
        hz, v, _ = self._polar(now_p)
        slope = self._polar(dist[1])[2] if dist is not None else 0.0
        t_ms = int(tick) % c.wrap_ms
        acc = (1.0 if c.accuracy is None else c.accuracy.angle_arcsec) * ARCSEC  # the class's angle σ, rad
        if rpc == Rpc.TMC_GetAngle5:
            return RC.OK, (hz, v)
        if rpc == Rpc.TMC_GetAngle1:
            return RC.OK, (hz, v, acc, t_ms, 0.0, 0.0, acc, t_ms, 0)
        if rpc == Rpc.TMC_GetSimpleMea:
            return rc, (hz, v, slope)
        if rpc == Rpc.TMC_GetFullMeas:
            d_ms = int(dist[0]) % c.wrap_ms if dist is not None else 0
            return rc, (hz, v, acc, 0.0, 0.0, acc, slope, d_ms)
        # TMC_GetSimpleCoord: the current angles with the last distance
        e0, n0, h0, hi = self.station
        if dist is None:
            return rc, (0.0, 0.0, 0.0)
        return rc, (e0 + slope * math.sin(v) * math.sin(hz), n0 + slope * math.sin(v) * math.cos(hz),
                    h0 + hi + slope * math.cos(v))

    @staticmethod
    def _trid(request: Request) -> int:
        return 0 if request.trid is None else request.trid

    # --- procedures --------------------------------------------------------------------------
    def _execute(self, rpc: int, p: Sequence[Union[int, float]], t_complete: float) -> tuple:
        """Run a non-motorised procedure (state lock held); returns its values or raises _Refusal."""
        c = self.config
        if rpc == Rpc.COM_NullProc:
            return ()
        if rpc in _STORED:  # a setting the instrument only stores and reports back
            name, kind, is_set = _STORED[rpc]
            if not is_set:
                return (getattr(self, name),)
            setattr(self, name, kind(p[0]))
            return ()
        if rpc == Rpc.COM_GetSWVersion:
            return c.geocom
        if rpc == Rpc.CSV_GetSWVersion:
            return c.firmware
        if rpc == Rpc.CSV_GetInstrumentName:
            return (c.name,)
        if rpc == Rpc.CSV_GetInstrumentNo:
            return (c.serial_number,)
        if rpc in (Rpc.CSV_GetDateTime, Rpc.CSV_GetDateTimeCentiSec):
            tm = time.gmtime(t_complete)
            if rpc == Rpc.CSV_GetDateTimeCentiSec:
                return (tm.tm_year, tm.tm_mon, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec,
                        int(t_complete * 100) % 100)
            return (tm.tm_year,) + tuple(Byte(v) for v in (tm.tm_mon, tm.tm_mday, tm.tm_hour, tm.tm_min,
                                                               tm.tm_sec))
        if rpc == Rpc.MOT_ReadLockStatus:
            return (1 if self.locked else 0,)
        if rpc in (Rpc.AUS_SetUserLockState, Rpc.AUS_SetUserAtrState):
            on = bool(p[0])

            def change() -> None:
                if rpc == Rpc.AUS_SetUserLockState:
                    self.user_lock = on
                    if not on:  # the telescope stops following: the moving prism leaves its view
                        self.locked = self.adjusted = False
                else:
                    self.user_atr = on

            self._change(change)
            return ()
        if rpc == Rpc.AUS_GetUserLockState:
            return (int(self.user_lock),)
        if rpc == Rpc.AUS_GetUserAtrState:
            return (int(self.user_atr),)
        if rpc == Rpc.BAP_SetMeasPrg:
            if c.model == "TPS1200" and int(p[0]) in (BAP_CONT_REF_FAST, BAP_CONT_REF_SYNCHRO):
                raise _Refusal(RC.IVPARAM)   # this firmware does not know the program
            self.meas_prg = int(p[0])
            return ()
        if rpc == Rpc.TMC_GetStation:
            return self.station
        if rpc in (Rpc.TMC_SetStation, Rpc.TMC_SetOrientation):
            if c.strict and (self.distance is not None or self.tracking):
                raise _Refusal(RC.TMC_BUSY)  # a distance exists: TMC_DoMeasure(TMC_CLEAR) first
            if rpc == Rpc.TMC_SetStation:
                self.station = tuple(float(v) for v in p)
            else:
                self.orientation_rad = float(p[0])
            return ()
        if rpc == Rpc.TMC_DoMeasure:
            self._do_measure(int(p[0]), t_complete)
            return ()
        raise AssertionError(f"procedure {rpc} has a signature but no implementation")

    def _do_measure(self, program: int, t_complete: float) -> None:
        c = self.config
        if program == TMC_TRK_DIST and c.strict:
            raise _Refusal(RC.IVPARAM)  # not a TPS1200+/Captivate measurement program
        now_ms = self.instrument_ms_at(t_complete)
        track = program in (TMC_RTRK_DIST, TMC_RED_TRK_DIST, TMC_TRK_DIST) or (
            program in (TMC_DEF_DIST, TMC_DO_MEASURE) and self.meas_prg in BAP_CONTINUOUS_PRGS)

        def change() -> None:
            if program in (TMC_STOP, TMC_CLEAR) or not track:
                self.tracking = False
            if program == TMC_CLEAR:
                self.distance = None
            if track:
                self.tracking = True
                self._edm_t0_ms = now_ms
            elif program in (TMC_DEF_DIST, TMC_DO_MEASURE) and self.prism_visible and (self.locked or self.adjusted):
                tick = math.ceil(now_ms)  # a single distance
                self.distance = (tick, self.track(self.host_time_of(tick) - self.t_boot))

        self._change(change)

    def _motion_result(self, motion: _Motion) -> Optional[int]:
        """Run a motorised procedure to its end in the serving thread; its rc, or None when the
        link went down or the simulator stopped meanwhile."""
        c = self.config
        rpc = motion.request.rpc
        params = _decode(motion.request)
        if rpc == Rpc.AUT_LockIn:
            if c.strict and not self.user_lock:
                return RC.AUT_NOT_ENABLED
            if c.strict and not (self.adjusted and self.prism_visible):
                return RC.AUT_NO_TARGET
            duration = c.lock_in_s if c.strict else 0.0
        elif rpc == Rpc.AUT_FineAdjust:
            duration = c.fine_adjust_s
        elif rpc == Rpc.AUT_MakePositioning:
            target = (float(params[0]) % (2 * math.pi), float(params[1]))
            hz0, v0 = self.aim()
            turn = max(abs(math.remainder(target[0] - hz0, 2 * math.pi)), abs(target[1] - v0))
            duration = c.positioning_s + turn / c.slew_rad_s
        else:
            if rpc == Rpc.AUT_PS_SearchNext and c.model == "TPS1200":
                return RC.NOT_IMPL   # no PowerSearch on this instrument
            duration = c.power_search_s if rpc == Rpc.AUT_PS_SearchNext else c.search_s
        start_aim = self.aim()
        in_window = rpc == Rpc.AUT_FineAdjust and self.prism_visible and self._within(start_aim, params[0] / 2,
                                                                                       params[1] / 2)
        end = motion.start_s + duration
        seen: Optional[float] = None
        while True:
            now = time.time()
            if seen is None and self.prism_visible and self._finds(rpc, params, start_aim, now - motion.start_s):
                seen = now
            if now >= end or (seen is not None and now >= seen + c.found_s):
                break
            if self._stop.wait(min(0.01, max(0.0, end - now))) or not self.link_up:
                return None
        if rpc == Rpc.AUT_MakePositioning:
            self._change(lambda: self._turn_to(target))
            return RC.OK
        if rpc == Rpc.AUT_FineAdjust:  # the ATR looks where the telescope points, then centres the prism
            seen = now if in_window else None
        if not self.prism_visible or (rpc != Rpc.AUT_LockIn and seen is None):
            return RC.AUT_NO_TARGET
        if rpc == Rpc.AUT_LockIn:
            self._change(lambda: setattr(self, "locked", True))
        elif rpc == Rpc.AUT_FineAdjust:
            self._change(lambda: (setattr(self, "adjusted", True), self._point_at_prism()))
        else:
            self._change(self._point_at_prism)  # a search leaves the prism in the ATR's field
        return RC.OK

    def _turn_to(self, target: Tuple[float, float]) -> None:
        self._aim = target
        self.locked = self.adjusted = False

    def _within(self, aim: Tuple[float, float], hz_window: float, v_window: float) -> bool:
        """The prism is within ±``hz_window``, ±``v_window`` (rad) of ``aim`` (Hz, V) now."""
        hz, v = self._prism_direction()
        return abs(math.remainder(hz - aim[0], 2 * math.pi)) <= hz_window and abs(v - aim[1]) <= v_window

    def _finds(self, rpc: int, params, aim: Tuple[float, float], elapsed: float) -> bool:
        """A search ``rpc`` started pointing at ``aim`` ``elapsed`` s ago finds the visible prism now: AUT_Search
        within its area (its Hz and V widths), PowerSearch when its fan (full height) has swept past the prism's
        Hz (clockwise or not); AUT_FineAdjust is judged at its end, within its window."""
        if rpc == Rpc.AUT_Search:
            return self._within(aim, params[0] / 2, params[1] / 2)
        if rpc == Rpc.AUT_PS_SearchNext:
            turned = 2 * math.pi * elapsed / self.config.power_search_s
            sign = 1.0 if params[0] == AUT_CLOCKWISE else -1.0
            ahead = (sign * (self._prism_direction()[0] - aim[0])) % (2 * math.pi)
            return ahead <= turned or turned >= 2 * math.pi
        return False

    # --- requests ------------------------------------------------------------------------------
    def _refusal_reply(self, line: bytes) -> Optional[bytes]:
        """The reply to a line that is not a decodable request (None for a blank line)."""
        text = line.strip()
        if not text:
            return None
        if not text.startswith(b"%R1Q,"):
            return encode_reply(0, (), RC.COM_NOT_GEOCOM, 0)
        head = text[5:].split(b":", 1)[0].split(b",")
        trid = int(head[1]) if len(head) >= 2 and head[1].strip().isdigit() else 0
        return encode_reply(0, (), RC.COM_CANT_DECODE_REQ, trid)

    def _handle(self, line: bytes, t_complete: float) -> Union[_Answer, _Motion, None]:
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
            return self._answer(encode_reply(RC.UNDEFINED, (), 0, self._trid(req)), t_complete, None, None, req)

    def _dispatch(self, req: Request, t_complete: float) -> Union[_Answer, _Motion, None]:
        trid = self._trid(req)
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
            return _Motion(req, t_complete)
        tick = math.floor(self.instrument_ms_at(t_complete)) + 1
        if req.rpc == Rpc.TMC_GetCoordinate:
            f = self.config.faults
            forced = self._rng.choice((RC.TMC_NO_FULL_CORRECTION, RC.TMC_ACCURACY_GUARANTEE)) \
                if self._rng.random() < f.warning else None
            data, truth = self._coordinate(tick, forced, req)
            return self._answer(data, truth.angles_time_s, truth, forced, req)
        with self._state_lock:
            try:
                if req.rpc in _ANGLE_RPCS:
                    rc, values = self._angles_reply(req.rpc, tick)
                    t_meas = self.host_time_of(tick)
                else:
                    rc, values, t_meas = RC.OK, self._execute(req.rpc, params, t_complete), t_complete
            except _Refusal as r:
                rc, values, t_meas = r.rc, (), t_complete
            data = encode_reply(rc, values, 0, trid, self.precision, crc)
        return self._answer(data, t_meas, None, None, req)

    def _answer(self, data: bytes, t_meas: float, truth: Optional[TruthRecord], forced_rc: Optional[int],
                request: Request) -> Optional[_Answer]:
        """Schedule reply ``data`` for a measurement at host time ``t_meas`` with the link's delays
        and the random faults; None when the reply is dropped."""
        c, f, rng = self.config, self.config.faults, self._rng
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
                self.truth.append(truth._replace(sent=False))
            return None
        return _Answer(data, t_meas + delay + self._wire_s(len(data)), prefix, delay, truth, forced_rc, request)

    def _wire_s(self, n_bytes: int) -> float:
        """Serial wire time of ``n_bytes`` (0 over TCP: no byte timing)."""
        return 10.0 * n_bytes / self.config.baud if self._byte_timing else 0.0

    def _remeasured(self, answer: _Answer, now: float) -> Optional[_Answer]:
        """None if ``answer`` may still be sent at host time ``now`` (s), else the same reply
        measured at the first counter tick from which its latency ``delay_s`` ends after ``now``."""
        truth = answer.truth
        if truth is None or now - answer.send_s <= LATE_S:
            return None
        tick = math.ceil(self.instrument_ms_at(now - answer.delay_s - self._wire_s(len(answer.data))))
        while True:  # a shorter reply is due earlier on the wire: then the next tick
            data, later = self._coordinate(tick, answer.forced_rc, answer.request)
            send_s = later.angles_time_s + answer.delay_s + self._wire_s(len(data))
            if send_s >= now:
                return answer._replace(data=data, truth=later, send_s=send_s)
            tick += 1

    def _motion_answer(self, motion: _Motion) -> Optional[_Answer]:
        """Run ``motion`` and schedule its reply (None: aborted by a link outage or a stop)."""
        rc = self._motion_result(motion)
        if rc is None:
            return None
        req = motion.request
        return self._answer(encode_reply(rc, (), 0, self._trid(req), crc=req.crc_ok is True), time.time(), None,
                            None, req)

    # --- transports ------------------------------------------------------------------------
    def _serve_stream(self, read: Callable[[float], bytes], write: Callable[[bytes], None]) -> None:
        """Read request lines, answer them one after the other with the wire timing."""
        buf = bytearray()
        first_byte_t: Optional[float] = None
        while not self._stop.is_set():
            chunk = read(0.05)
            if chunk is None:
                return
            if not self.link_up:
                buf.clear()
                continue
            if chunk:
                if not buf:
                    first_byte_t = time.time()
                buf += chunk
            while b"\n" in buf:
                i = buf.index(b"\n")
                line = bytes(buf[: i + 1])
                del buf[: i + 1]
                t_complete = max(time.time(), (first_byte_t or time.time()) + self._wire_s(len(line)))
                first_byte_t = time.time() if buf else None
                answer = self._handle(line, t_complete)
                if isinstance(answer, _Motion):
                    answer = self._motion_answer(answer)
                if answer is None:
                    continue
                for _ in range(_MAX_REMEASURE):
                    wait = answer.send_s - time.time()
                    if wait > 0:
                        time.sleep(wait)
                    later = self._remeasured(answer, time.time())
                    if later is None:
                        break
                    answer = later
                truth = answer.truth
                if not self.link_up or self._stop.is_set():
                    if truth is not None:
                        self.truth.append(truth._replace(sent=False))
                    buf.clear()
                    break
                if truth is not None:
                    self.truth.append(truth)
                try:
                    write(answer.prefix + answer.data)
                except OSError:
                    return

    def serve_pty(self) -> str:
        """Start serving on a new pseudo-terminal; returns the path of its slave (the "serial
        port" a client opens)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._pty = (master, slave)
        self._byte_timing = True

        def read(timeout: float) -> Optional[bytes]:
            ready, _, _ = select.select([master], [], [], timeout)
            if not ready:
                return b""
            try:
                return os.read(master, 4096)
            except OSError:
                return None

        def write(data: bytes) -> None:
            os.write(master, data)

        self._start(lambda: self._serve_stream(read, write))
        self._start(self._random_faults)
        return os.ttyname(slave)

    def serve_tcp(self, port: int = 0) -> int:
        """Start serving on TCP 127.0.0.1:``port`` (0 = any free port), one client at a time,
        without serial byte timing (an instrument on WLAN/Ethernet); returns the port."""
        self._byte_timing = False
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind(("127.0.0.1", int(port)))
        except OSError as e:
            raise SimulatorError(f"cannot listen on 127.0.0.1:{port}: {e.strerror}") from None
        server.listen(1)
        server.settimeout(0.1)
        self._server = server

        def accept_loop() -> None:
            while not self._stop.is_set():
                try:
                    conn, _ = server.accept()
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not self.link_up:
                    conn.close()
                    continue
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self._conn = conn
                self._event("client_connected")

                def read(timeout: float, conn=conn) -> Optional[bytes]:
                    ready, _, _ = select.select([conn], [], [], timeout)
                    if not ready:
                        return b""
                    try:
                        data = conn.recv(4096)
                    except OSError:
                        return None
                    return data if data else None

                self._serve_stream(read, conn.sendall)
                self._conn = None
                conn.close()

        self._start(accept_loop)
        self._start(self._random_faults)
        return server.getsockname()[1]

    def _start(self, target: Callable[[], None]) -> None:
        th = threading.Thread(target=target, daemon=True)
        th.start()
        self._threads.append(th)

    def _random_faults(self) -> None:
        """Lock losses and link outages at the configured rates (Poisson, checked every 50 ms)."""
        f, rng = self.config.faults, self._rng
        while not self._stop.wait(0.05):
            if f.lock_loss > 0 and self.prism_visible and rng.random() < f.lock_loss * 0.05:
                self.set_prism_visible(False)
                timer = threading.Timer(rng.uniform(*f.outage_s), self.set_prism_visible, (True,))
                timer.daemon = True
                timer.start()
            if f.link_loss > 0 and self.link_up and rng.random() < f.link_loss * 0.05:
                self.link_down(rng.uniform(*f.outage_s))

    def close(self) -> None:
        """Stop serving and release the pty/socket."""
        self._stop.set()
        if self._server is not None:
            self._server.close()
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.shutdown(socket.SHUT_RDWR)
        for th in self._threads:
            th.join(timeout=2.0)
        if self._pty is not None:
            for fd in self._pty:
                with contextlib.suppress(OSError):
                    os.close(fd)
            self._pty = None

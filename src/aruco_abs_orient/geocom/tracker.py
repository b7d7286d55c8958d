"""The MS60 tracking loop: the documented GeoCOM session for kinematic prism tracking, in a thread.

In: a :class:`~.tracker_types.TrackerConfig` (a pyserial URL and the session's settings), callbacks for
samples and state changes, and optionally ``predict`` (where the prism is at a given host time, from the
robot's fused pose). Out: :class:`~.tracker_types.PrismSample` positions stamped with the instrument's measurement
time mapped to host time, :class:`~.tracker_types.TrackerState` changes and :meth:`Ms60Tracker.stats`.
Contract: each step of the session follows the TPS1200+ / Captivate GeoCOM references (cited step by
step in :class:`Ms60Tracker`); stamps never go backwards and never repeat; a refused step is the
``error`` state with a message saying what to check, tried again after ``error_retry_s``; a failed link
reconnects and a lost lock is re-acquired without leaving the loop.
"""

from __future__ import annotations

import collections
import contextlib
import math
import statistics
import threading
import time
from typing import Callable, Deque, Dict, Optional, Tuple

import numpy as np

from ..errors import InstrumentError
from .accuracy import polar_covariance
from .client import GeoComClient, GeoComError, GeoComLinkError, GeoComRcError, GeoComTimeout, rpc_name
from .clock import InstrumentClock
from .protocol import (
    AUT_CLOCKWISE,
    BAP_CONT_REF_STANDARD,
    BAP_CONT_REF_SYNCHRO,
    BAP_REFL_USE,
    MOT_LOCKED_OUT,
    RC,
    TMC_AUTO_INC,
    TMC_CLEAR,
    TMC_RTRK_DIST,
    TMC_STOP,
    RcClass,
    Rpc,
    rc_name,
)
from .tracker_types import PrismSample, TrackerConfig, TrackerError, TrackerState, TrackerStats

__all__ = ["TrackerError", "TrackerState", "TrackerConfig", "PrismSample", "TrackerStats", "Ms60Tracker",
           "DOUBLE_PRECISION", "FINE_ADJUST_WINDOW_RAD", "SEARCH_AREA_RAD", "extrapolate"]

DOUBLE_PRECISION = 6
"""COM_SetDoublePrecision: 6 decimals (1 µm, 1 µrad) keep the coordinate replies short."""
FINE_ADJUST_WINDOW_RAD = 0.05
"""AUT_FineAdjust search window, Hz and V (rad, about 3°)."""
SEARCH_AREA_RAD = (0.35, 0.17)
"""AUT_Search area, Hz and V (rad, about 20° × 10°)."""
_PROGRAMS = ((BAP_CONT_REF_SYNCHRO, "BAP_CONT_REF_SYNCHRO"), (BAP_CONT_REF_STANDARD, "BAP_CONT_REF_STANDARD"))
_UNAVAILABLE = (RC.IVPARAM, RC.NOT_IMPL, RC.NA, RC.COM_PROC_UNAVAIL)
_NO_TARGET = (RC.AUT_TIMEOUT, 8709, RC.AUT_NO_TARGET, RC.AUT_MULTIPLE_TARGETS, 8712, 8713)  # try again
_AIMED_RAD = FINE_ADJUST_WINDOW_RAD / 8  # a predicted prism this close to the line of sight needs no re-aim's turn
_MAX_REPOLLS = 3       # polls in a row that may repeat the old distance before one slot is given up
_POLL_MARGIN_S = 0.003  # a poll reaches the instrument this long after the expected distance


def extrapolate(older: Tuple[float, np.ndarray], newer: Tuple[float, np.ndarray], now: float,
                max_age: float, at: Optional[float] = None) -> Optional[np.ndarray]:
    """The position at ``at`` (s, default ``now``) from two (stamp s, position (3,) m) poses, linearly; None when
    the newer is more than ``max_age`` s old at ``now`` (a stale pose), or from the future."""
    (t0, p0), (t1, p1) = older, newer
    if not 0.0 <= now - t1 <= max_age:
        return None
    rate = (np.asarray(p1) - np.asarray(p0)) / (t1 - t0) if t1 > t0 else np.zeros(3)
    return np.asarray(p1, dtype=float) + rate * ((now if at is None else at) - t1)


def _direction(d: np.ndarray) -> Tuple[float, float]:
    """Hz (from north, clockwise) and V (zenith angle), rad, of the vector ``d`` (E, N, H)."""
    return math.atan2(d[0], d[1]), math.atan2(math.hypot(d[0], d[1]), d[2])


class _SessionError(Exception):
    """The instrument refused a step tracking needs (the message says which and what to do)."""


class Ms60Tracker:
    """Runs the loop in a thread (:meth:`start`/:meth:`stop`) and calls ``on_sample`` with each
    new :class:`PrismSample` and ``on_state`` with each new :class:`TrackerState` (from the
    loop's thread). ``predict(t)`` (optional, called from the loop's thread) gives where the prism is at host
    time ``t`` (s; now or up to a turn's time ahead) ((E, N, H) m in the instrument's frame) or None when it
    does not know (no pose, or a stale one): after a lost lock the telescope is turned to where the prism will
    be when the turn ends before the prism is searched for.

    Session (each step cites the GeoCOM reference it follows: "RM1200" = TPS1200+ GeoCOM Reference
    Manual v1.50, "RMCap" = the Captivate TS/MS GeoCOM Reference Manual; sections by chapter and
    function name):

    1. connect and check: COM_NullProc (RM1200/RMCap COM chapter), CSV_GetInstrumentName,
       CSV_GetInstrumentNo, COM_GetSWVersion (GeoCOM release), CSV_GetSWVersion (firmware) (CSV and
       COM chapters), COM_SetDoublePrecision (COM chapter: decimals of the doubles in the replies);
    2. TMC_DoMeasure(TMC_CLEAR) (TMC chapter, TMC_DoMeasure: "TMC_STOP and clear data"): stops any
       running program and clears the distance, which TMC_SetStation and TMC_SetOrientation require
       (TMC chapter, TMC_SetStation / TMC_SetOrientation: distances must be cleared first);
    3. TMC_SetStation and TMC_SetOrientation when configured (TMC chapter);
    4. target and prism: BAP_SetTargetType(BAP_REFL_USE), BAP_SetPrismType, TMC_SetPrismCorr when
       configured (BAP and TMC chapters);
    5. measurement program: BAP_SetMeasPrg(BAP_CONT_REF_SYNCHRO), synchro tracking, whose angles are
       taken with the distance; an instrument that refuses it (IVPARAM: its firmware lacks it) gets
       BAP_CONT_REF_STANDARD, IR tracking (BAP chapter, BAP_SetMeasPrg / BAP_USER_MEASPRG). The EDM
       mode follows from the program; TMC_SetEdmMode is the TPS1100 interface and not used;
    6. LOCK mode: AUS_SetUserLockState(ON) (AUS chapter: LOCK mode on does not lock by itself);
    7. acquire: after a lost lock, when a prediction of the prism's position is at hand (``predict``: the
       robot's fused pose and the prism lever arm), AUT_MakePositioning (AUT chapter: AUT_NORMAL, AUT_POSITION)
       first, to the prism's direction when the turn will end (its time: the angle at ``turn_rate_deg_s`` plus
       the overhead the previous turn took beyond that; no turn when the telescope points within a few tenths of
       a degree of it already); AUT_FineAdjust (AUT chapter: centres the prism in the ATR's field, searching its
       window), then AUT_LockIn (AUT chapter: needs LOCK mode and a successful AUT_FineAdjust); without a target
       AUT_PS_SearchNext (AUT chapter, PowerSearch, TPS1200+ and later) or, on an instrument without PowerSearch
       (NOT_IMPL/NA/COM_PROC_UNAVAIL), AUT_Search, then AUT_FineAdjust again. Motorised procedures take seconds:
       they get ``motion_timeout_s``. MOT_ReadLockStatus confirms the lock (MOT chapter);
    8. tracking: TMC_DoMeasure(TMC_RTRK_DIST) (TMC chapter, TMC_MEASURE_PRG: "distance-TRK
       measurement program"; TMC_TRK_DIST = 2 is TPS1100 only);
    9. poll TMC_GetCoordinate (TMC chapter): the first coordinate and CoordTime belong to the last
       distance, the continuous coordinate and CoordContTime to this request's angles. The position
       is stamped with CoordTime mapped to host time; the clock fit uses CoordContTime, the time of
       a measurement made when the request arrived. A CoordTime not newer than the last one is the
       same distance again: counted in ``duplicates``, not published.

    Polls follow the EDM: once its period is known (from successive CoordTimes), each poll is sent
    so that it reaches the instrument just after the next expected distance; a poll that still gets
    the old distance is repeated at once. Before that, polls run at ``rate_hz``.

    States: ``connecting``, ``searching`` (acquiring the prism), ``locked`` (polling), ``lost`` (the
    lock dropped: re-acquiring through step 7 and 8), ``reconnecting`` (the link failed: the session
    again), ``error`` (the instrument refused a step tracking needs, or gives no distance while
    locked: :attr:`Ms60Tracker.error` says which and what to check; the session is retried every
    ``error_retry_s``), ``stopped``. Stamps never go backwards and never repeat. The first
    ``warmup_samples`` positions only feed the clock fit (its lower envelope needs a few
    low-latency replies received promptly before its stamps can be trusted; on a loaded host the
    loop thread wakes late for some replies).
    """

    def __init__(self, config: TrackerConfig, on_sample: Optional[Callable[[PrismSample], None]] = None,
                 on_state: Optional[Callable[[TrackerState], None]] = None,
                 client_factory: Callable[..., GeoComClient] = GeoComClient,
                 predict: Optional[Callable[[float], Optional[Tuple[float, float, float]]]] = None):
        config.validate()
        self.predict = predict                   # (host s) -> the prism's (E, N, H) then, or None (missing or stale)
        self.reaims = 0                          # re-aims at a prediction after a lost lock
        self.reaims_found = 0                    # ... after which AUT_FineAdjust found the prism
        self._reaiming_since = 0.0               # host time re-aims began to fail in this loss (0: they do not)
        self._pointing: Optional[np.ndarray] = None  # a point (E, N, H) on the telescope's line of sight, or None
        self._turn_overhead_s = 0.0              # the last AUT_MakePositioning's time beyond its angle's turn
        self.config = config
        self.on_sample = on_sample
        self.on_state = on_state
        self._factory = client_factory
        self._client: Optional[GeoComClient] = None
        self.clock = InstrumentClock(min_latency_s=config.min_latency_s)
        self.state = TrackerState.CONNECTING
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._stats_lock = threading.Lock()
        self._last_ms: Optional[int] = None      # unwrapped instrument ms of the last distance
        self._last_stamp = float("-inf")
        self._last_fresh_s = 0.0                 # host time of the last new distance
        self._clock_resets = 0
        self._recent: Deque[float] = collections.deque()
        self._periods: Deque[int] = collections.deque(maxlen=20)
        self._repolls = 0
        self._timeouts_in_row = 0
        self._motion_pending = False             # a motorised call timed out: its reply may still come
        self._retry_at = 0.0
        self._power_search: Optional[bool] = None
        self.station_axis = np.zeros(3)          # E, N, H of the instrument's tilting axis (m), read at connect
        self.instrument = ""
        self.error = ""
        self.notice = ""
        self.program = ""
        self.samples = self.lost_samples = self.timeouts = self.duplicates = self.out_of_order = 0
        self.reconnects = self.relocks = 0
        self.warnings: Dict[int, int] = {}
        self.no_position: Dict[int, int] = {}
        self._garbage = self._stale = 0

    # --- life cycle ------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self.run, name="ms60_tracker", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the loop, stop the instrument's tracking measurement (TMC_DoMeasure TMC_STOP) and
        close the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.config.motion_timeout_s + 5.0)
        if self._client is not None and self.state in (TrackerState.LOCKED, TrackerState.LOST, TrackerState.SEARCHING):
            with contextlib.suppress(GeoComError):  # leave the instrument idle
                self._client.do_measure(TMC_STOP, TMC_AUTO_INC)
        self._close_client()
        self._set_state(TrackerState.STOPPED)

    def run(self) -> None:
        """The loop (blocks until :meth:`stop`)."""
        while not self._stop.is_set():
            next_s = self._cycle()
            self._stop.wait(max(0.0, next_s - time.time()))

    def _set_state(self, state: TrackerState) -> None:
        if state != self.state:
            self.state = state
            if self.on_state is not None:
                self.on_state(state)

    def _close_client(self) -> None:
        if self._client is not None:
            self._garbage += self._client.garbage_bytes
            self._stale += self._client.stale_replies
            self._client.close()
            self._client = None

    @property
    def edm_period_ms(self) -> Optional[float]:
        """The EDM's period (instrument ms) from recent successive distances, or None."""
        if len(self._periods) < 3:
            return None
        base = min(self._periods)
        return statistics.median(d / max(1, round(d / base)) for d in self._periods)

    # --- one cycle ---------------------------------------------------------------------------
    def _cycle(self) -> float:
        """Do the current state's work; returns the host time of the next cycle (s)."""
        now = time.time()
        period = 1.0 / self.config.rate_hz
        try:
            if self.state == TrackerState.ERROR:
                if now < self._retry_at:
                    return self._retry_at
                self._connect()
            elif self.state in (TrackerState.CONNECTING, TrackerState.RECONNECTING):
                self._connect()
            elif self.state in (TrackerState.SEARCHING, TrackerState.LOST):
                self._acquire()
                return max(now + period, time.time())
            elif self.state == TrackerState.LOCKED:
                return self._poll()
        except _SessionError as e:
            self._fail(str(e))
        except GeoComTimeout:
            with self._stats_lock:
                self.timeouts += 1
            self._timeouts_in_row += 1
            if self._motion_pending or (self._timeouts_in_row >= self.config.max_timeouts
                                        and self.state not in (TrackerState.CONNECTING, TrackerState.ERROR)):
                self._reconnect()
        except GeoComLinkError:
            if self.state not in (TrackerState.CONNECTING, TrackerState.ERROR):
                self._reconnect()
            else:
                self._close_client()
                return time.time() + self.config.backoff_s
        except (InstrumentError, ValueError):  # malformed reply content: skip this slot
            pass
        return max(now + period, time.time()) if self.state == TrackerState.LOCKED else time.time()

    def _fail(self, message: str) -> None:
        self.error = message
        self._retry_at = time.time() + self.config.error_retry_s
        if self._client is not None:
            with contextlib.suppress(GeoComError):
                self._client.do_measure(TMC_STOP, TMC_AUTO_INC)
        self._close_client()
        self._set_state(TrackerState.ERROR)

    def _reconnect(self) -> None:
        self._close_client()
        self._timeouts_in_row = 0
        if self.state != TrackerState.RECONNECTING:
            with self._stats_lock:
                self.reconnects += 1
        self._set_state(TrackerState.RECONNECTING)

    def _required(self, step: str, call: Callable[[], object], hint: str) -> None:
        """Run a session step; a refusal raises _SessionError naming the step, the code and ``hint``."""
        try:
            call()
        except GeoComRcError as e:
            raise _SessionError(f"{step} refused: {rpc_name(e.rpc)} returned {rc_name(e.rc)}; {hint}") from None

    def _connect(self) -> None:
        """Session steps 1-6 (see the class docstring), then acquisition or tracking."""
        self._close_client()
        c = self.config
        try:
            client = self._factory(c.url, c.baud, c.timeout_s, c.byte_timing)
        except GeoComLinkError:
            self._stop.wait(c.backoff_s)
            return
        self._client = client
        # a motorised call that timed out may still be running: this waits for the instrument to
        # be free (its late reply is discarded by transaction id) instead of queueing requests
        client.null_proc(timeout_s=c.motion_timeout_s if self._motion_pending else min(c.timeout_s, 0.2))
        self._motion_pending = False
        self._timeouts_in_row = 0
        if not self.instrument:
            self.instrument = (f"{client.instrument_name()} #{client.instrument_number()} "
                               f"fw {client.firmware_version()} GeoCOM {client.geocom_version()}")
        self._required("double precision", lambda: client.set_double_precision(DOUBLE_PRECISION),
                       "the instrument does not accept COM_SetDoublePrecision")
        self._required("clearing the distance", lambda: client.do_measure(TMC_CLEAR, TMC_AUTO_INC),
                       "the instrument is busy: stop any measurement on its keyboard")
        if c.station is not None:
            self._required("station", lambda: client.set_station(*c.station),
                           "check the station parameters; the instrument refuses a station while a distance exists")
        if c.orientation_rad is not None:
            self._required("orientation", lambda: client.set_orientation(c.orientation_rad),
                           "check station/orientation_deg")
        e0, n0, h0, hi = client.get_station()  # the tilting axis, where each position's covariance is seen from
        self.station_axis = np.array([e0, n0, h0 + hi])
        self._required("target type", lambda: client.set_target_type(BAP_REFL_USE),
                       "the instrument cannot measure to a reflector")
        if c.prism_type is not None:
            self._required("prism type", lambda: client.set_prism_type(c.prism_type),
                           "the prism type is unknown to this instrument")
        if c.prism_constant_m is not None:
            self._required("prism constant", lambda: client.set_prism_constant(c.prism_constant_m),
                           "check prism_constant_mm")
        self._set_program(client)
        self._required("LOCK mode", lambda: client.set_user_lock_state(True),
                       "the instrument has no ATR/LOCK (or no GeoCOM robotic licence)")
        self.error = ""
        if client.lock_status() != MOT_LOCKED_OUT:   # still locked (a reconnection): track at once
            self._start_tracking(client)
        else:
            self._set_state(TrackerState.SEARCHING)

    def _set_program(self, client: GeoComClient) -> None:
        """Step 5: the first continuous program the instrument accepts."""
        refusals = []
        for program, name in _PROGRAMS:
            try:
                client.set_meas_prg(program)
            except GeoComRcError as e:
                if e.rc not in _UNAVAILABLE:
                    raise _SessionError(f"measurement program refused: BAP_SetMeasPrg({name}) returned "
                                        f"{rc_name(e.rc)}") from None
                refusals.append(f"{name}: {rc_name(e.rc)}")
                continue
            self.program = name
            return
        raise _SessionError("no continuous measurement program: BAP_SetMeasPrg refused " + ", ".join(refusals)
                            + "; the instrument cannot track a prism")

    def _acquire(self) -> None:
        """Step 7 and 8: fine adjust, search if there is no target, lock in, start tracking."""
        client = self._client
        assert client is not None
        reaimed = self.state == TrackerState.LOST and self._reaim(client)
        rc = self._motion(Rpc.AUT_FineAdjust, lambda t: client.fine_adjust(FINE_ADJUST_WINDOW_RAD,
                                                                          FINE_ADJUST_WINDOW_RAD, t))
        if reaimed and rc == 0:
            with self._stats_lock:
                self.reaims_found += 1
        if reaimed and rc in _NO_TARGET:
            since = self._reaiming_since = self._reaiming_since or time.time()
            if time.time() - since < self.config.reaim_search_after_s:  # hidden: aim again, no sweep meanwhile
                self.notice = f"prism not at its predicted position (AUT_FineAdjust returned {rc_name(rc)})"
                return
        self._reaiming_since = 0.0
        if rc in _NO_TARGET:
            if not self._search(client):
                return
            rc = self._motion(Rpc.AUT_FineAdjust, lambda t: client.fine_adjust(FINE_ADJUST_WINDOW_RAD,
                                                                              FINE_ADJUST_WINDOW_RAD, t))
        if rc in _NO_TARGET:
            self.notice = f"prism not found: AUT_FineAdjust returned {rc_name(rc)}"
            return
        if rc != 0:
            raise _SessionError(f"fine adjustment refused: AUT_FineAdjust returned {rc_name(rc)}; the instrument "
                                "needs motorisation, ATR and the GeoCOM robotic licence")
        rc = self._motion(Rpc.AUT_LockIn, client.lock_in)
        if rc == RC.AUT_NOT_ENABLED:
            raise _SessionError("lock-in refused: AUT_LockIn returned 8714 AUT_NOT_ENABLED; LOCK mode is off "
                                "(switch it on, or check that nothing switches it off on the instrument)")
        if rc in _NO_TARGET:
            self.notice = f"lock-in failed: AUT_LockIn returned {rc_name(rc)}"
            return
        if rc != 0:
            raise _SessionError(f"lock-in refused: AUT_LockIn returned {rc_name(rc)}")
        if client.lock_status() == MOT_LOCKED_OUT:
            self.notice = "AUT_LockIn succeeded but MOT_ReadLockStatus says locked out"
            return
        if self.state == TrackerState.LOST:
            with self._stats_lock:
                self.relocks += 1
        self._start_tracking(client)

    def _reaim(self, client: GeoComClient) -> bool:
        """Turn the telescope to where the predicted prism will be when the turn ends (AUT_MakePositioning), unless
        it points there already; False without a prediction or when the instrument refuses (then the search as
        before)."""
        if self.predict is None:
            return False
        start = time.time()
        rate = math.radians(self.config.turn_rate_deg_s)
        turn_s, angle, target = 0.0, 0.0, None
        for k in range(3):  # where the telescope turns to sets how long it turns, which sets where the prism is
            p = self.predict(start + turn_s)
            if p is None:
                return False
            target = np.asarray(p, dtype=float)
            angle = self._turn_angle(target)
            if k == 0 and self._pointing is not None and angle <= _AIMED_RAD:  # already there: no turn
                with self._stats_lock:
                    self.reaims += 1
                return True
            turn_s = self._turn_overhead_s + angle / rate
        hz, v = _direction(target - self.station_axis)
        hz %= 2 * math.pi
        rc = self._motion(Rpc.AUT_MakePositioning, lambda t: client.make_positioning(hz, v, t))
        if rc != 0:
            self.notice = f"re-aim refused: AUT_MakePositioning returned {rc_name(rc)}"
            return False
        self._turn_overhead_s = max(0.0, time.time() - start - angle / rate)
        self._pointing = target
        with self._stats_lock:
            self.reaims += 1
        return True

    def _turn_angle(self, target: np.ndarray) -> float:
        """The telescope's turn (rad, the larger of Hz and V) from where it points to ``target`` (0: unknown)."""
        if self._pointing is None:
            return 0.0
        (hz0, v0), (hz1, v1) = (_direction(p - self.station_axis) for p in (self._pointing, target))
        return max(abs(math.remainder(hz1 - hz0, 2 * math.pi)), abs(v1 - v0))

    def _search(self, client: GeoComClient) -> bool:
        """PowerSearch, or AUT_Search on an instrument without it; True when a prism was found."""
        if self._power_search is not False:
            rc = self._motion(Rpc.AUT_PS_SearchNext, lambda t: client.power_search_next(AUT_CLOCKWISE, False, t))
            if rc in _UNAVAILABLE:
                self._power_search = False
            else:
                self._power_search = True
                name = "AUT_PS_SearchNext"
        if self._power_search is False:
            rc = self._motion(Rpc.AUT_Search, lambda t: client.search(*SEARCH_AREA_RAD, t))
            name = "AUT_Search"
        if rc in _NO_TARGET:
            self.notice = f"prism not found: {name} returned {rc_name(rc)}"
            return False
        if rc != 0:
            raise _SessionError(f"search refused: {name} returned {rc_name(rc)}; the instrument needs "
                                "motorisation and ATR")
        return True

    def _motion(self, rpc: int, call: Callable[[float], int]) -> int:
        """A motorised call with the motion timeout; a timeout marks it pending (see _connect)."""
        try:
            return call(self.config.motion_timeout_s)
        except GeoComTimeout:
            self._motion_pending = True
            raise

    def _start_tracking(self, client: GeoComClient) -> None:
        """Step 8."""
        self._required("tracking", lambda: client.do_measure(TMC_RTRK_DIST, TMC_AUTO_INC),
                       f"the instrument does not track with TMC_RTRK_DIST and {self.program}")
        self.notice = ""
        self._last_fresh_s = time.time()
        self._repolls = 0
        self._set_state(TrackerState.LOCKED)

    # --- polling -------------------------------------------------------------------------------
    def _next_poll_s(self) -> float:
        """Host time to send the next poll: just after the next expected distance, or one
        ``rate_hz`` period from now while the EDM's period is unknown."""
        period_ms = self.edm_period_ms
        now = time.time()
        if period_ms is None or self._last_ms is None or not self.clock.ready:
            return now + 1.0 / self.config.rate_hz
        due = self.clock.to_host(self._last_ms + period_ms) + _POLL_MARGIN_S
        if due < now:  # at least one distance was missed: aim at the next one to come
            due += period_ms / 1000.0 * (1 + int((now - due) / (period_ms / 1000.0)))
        return due

    def _poll(self) -> float:
        """Step 9; returns the host time of the next poll."""
        assert self._client is not None
        timed = self._client.get_coordinate(0, TMC_AUTO_INC)
        self._timeouts_in_row = 0
        r = timed.reading
        if not r.has_position:
            with self._stats_lock:
                self.no_position[r.rc] = self.no_position.get(r.rc, 0) + 1
            if r.rc_class == RcClass.NO_POSITION and self._client.lock_status() == MOT_LOCKED_OUT:
                self.notice = f"lock lost (TMC_GetCoordinate returned {rc_name(r.rc)})"
                self._set_state(TrackerState.LOST)
                return time.time()
            self._check_distance_age(r.rc)
            return time.time() + 1.0 / self.config.rate_hz
        with self._stats_lock:
            cont_ms = self.clock.add(r.cont_time_ms, timed.received_s, timed.reply_tx_s)
        if self.clock.resets != self._clock_resets:  # instrument restarted: its clock began anew
            self._clock_resets = self.clock.resets
            self._last_ms = None
            self._periods.clear()
        t_ms = cont_ms - (r.cont_time_ms - r.time_ms) % self.clock.wrap_ms
        if self._last_ms is not None and t_ms <= self._last_ms:
            with self._stats_lock:
                self.duplicates += 1
            self._repolls += 1
            self._check_distance_age(r.rc)
            if self._repolls <= _MAX_REPOLLS:
                return time.time()   # the old distance: the new one is due any moment
            self._repolls = 0
            return time.time() + 1.0 / self.config.rate_hz
        self._repolls = 0
        self._last_fresh_s = time.time()
        if self._last_ms is not None:
            gap = t_ms - self._last_ms
            period = self.edm_period_ms
            if period is not None:
                with self._stats_lock:
                    self.lost_samples += max(0, round(gap / period) - 1)
            if gap < 1000:
                self._periods.append(gap)
        self._last_ms = t_ms
        if len(self.clock) <= self.config.warmup_samples:
            return self._next_poll_s()
        with self._stats_lock:
            stamp = self.clock.to_host(t_ms)
        if stamp <= self._last_stamp:
            with self._stats_lock:
                self.out_of_order += 1
            return self._next_poll_s()
        self._last_stamp = stamp
        cov = polar_covariance(self.station_axis, (r.east, r.north, r.height), self.config.accuracy)
        sample = PrismSample(stamp, r.east, r.north, r.height, r.time_ms, r.rc, cov)
        self._pointing = np.array([r.east, r.north, r.height])
        with self._stats_lock:
            self.samples += 1
            if r.rc != 0:
                self.warnings[r.rc] = self.warnings.get(r.rc, 0) + 1
            now = time.time()
            self._recent.append(now)
            while self._recent[0] < now - 60.0:
                self._recent.popleft()
        if self.on_sample is not None:
            self.on_sample(sample)
        return self._next_poll_s()

    def _check_distance_age(self, rc: int) -> None:
        """Locked, yet no new distance for ``no_distance_s``: the EDM does not track."""
        age = time.time() - self._last_fresh_s
        if age > self.config.no_distance_s:
            raise _SessionError(f"locked on the prism but no new distance for {age:.1f} s (TMC_GetCoordinate "
                                f"returned {rc_name(rc)}): the EDM does not track; check the target type "
                                f"(reflector), the prism and the measurement program ({self.program})")

    # --- reporting ---------------------------------------------------------------------------
    def stats(self, window_s: float = 5.0) -> TrackerStats:
        """A consistent snapshot of the counters; ``rate_hz`` over the last ``window_s`` s."""
        now = time.time()
        with self._stats_lock:
            while self._recent and self._recent[0] < now - window_s:
                self._recent.popleft()
            rate = len(self._recent) / window_s
            client = self._client
            garbage = self._garbage + (client.garbage_bytes if client else 0)
            stale = self._stale + (client.stale_replies if client else 0)
            offset = self.clock.offset_s if self.clock.ready else float("nan")
            drift = self.clock.drift if self.clock.ready else float("nan")
            search = {None: "", True: "AUT_PS_SearchNext", False: "AUT_Search"}[self._power_search]
            period = self.edm_period_ms
            return TrackerStats(self.state.value, self.samples, self.lost_samples, rate, dict(self.warnings),
                                dict(self.no_position), self.timeouts, self.duplicates, self.out_of_order,
                                self.reconnects, self.relocks, garbage, stale, offset, drift, self.instrument,
                                self.error, self.notice, self.program, search,
                                float("nan") if period is None else float(period), self.reaims, self.reaims_found)

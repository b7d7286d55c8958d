"""The simulated total station's instrument model: its settings, state, clock, EDM and motors.

In: a :class:`SimConfig`, a prism track (host seconds since boot → position, m) and a seed; the
procedure calls of :mod:`.dispatch` (measure at a counter tick, change a setting, run a motorised
procedure) and the fault calls of the transports (hide or show the prism).
Out: measurements (angles, distances, coordinates with their instrument times) and the truth log
(:class:`TruthRecord`, the true position behind every reported coordinate).
Contract: every change of state goes through :meth:`Ms60Instrument.change` under the state lock, so
the EDM's distances are settled up to the change first; all times are host ``time.time()`` seconds
or unwrapped instrument counter milliseconds; one random generator serves the whole simulator.
No GeoCOM encoding and no I/O here: replies are built in :mod:`.dispatch`, served in :mod:`.transport`.
"""

from __future__ import annotations

import math
import random
import threading
import time
from typing import Callable, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from ..errors import InstrumentError
from .accuracy import ARCSEC, InstrumentAccuracy
from .protocol import (
    AUT_CLOCKWISE,
    BAP_CONTINUOUS_PRGS,
    MAX_DOUBLE_PRECISION,
    RC,
    TMC_CLEAR,
    TMC_DEF_DIST,
    TMC_DO_MEASURE,
    TMC_RED_TRK_DIST,
    TMC_RTRK_DIST,
    TMC_STOP,
    TMC_TRK_DIST,
    Rpc,
)

__all__ = ["PROFILES", "MODELS", "SimulatorError", "FaultRates", "SimConfig", "TruthRecord", "Ms60Instrument",
           "builtin_track", "tum_track"]

PROFILES = ("strict", "lenient")
MODELS = ("MS60", "TPS1200")

_STALE_PERIODS = 3   # a tracking distance older than this many EDM periods is no distance
_FAN_HALF_WIDTH_RAD = 0.01  # PowerSearch's fan: a prism within this of its Hz is seen


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


def _positioning_target(params: Sequence[Union[int, float]]) -> Tuple[float, float]:
    """AUT_MakePositioning's target (Hz in [0, 2π), V), rad."""
    return float(params[0]) % (2 * math.pi), float(params[1])


class Ms60Instrument:
    """The instrument's state and physics (all times host ``time.time()`` seconds).

    - the clock: a millisecond counter ``T = floor(((t − t_boot)(1 + drift))·1000 + offset_ms) mod
      wrap_ms``; angles are measured at a counter tick;
    - the EDM: once tracking runs (TMC_RTRK_DIST, or TMC_DEF_DIST with a continuous BAP program) it
      measures a distance every ``1000/edm_rate_hz`` counter ms while it sees the prism (locked, or
      fine-adjusted onto it); a coordinate combines the last distance with its time and the current
      angles with theirs; a tracking distance older than three EDM periods is no distance (1285
      TMC_ANGLE_OK, angles only);
    - the prism: ``track`` (host s since boot → m); the set-up is assumed correct, so coordinates are
      the track's whatever station and orientation a client sets (they are kept and reported);
    - noise (``config.accuracy``; None: exact): normal errors of the class's σ on slope distance (shared
      by a coordinate's two parts), Hz and V, and a prism centring error per axis; the truth keeps the
      true positions;
    - the telescope (Hz, V): at the prism while locked, where the prism was when the lock was lost,
      where AUT_MakePositioning turned it. Motorised procedures take their time: AUT_FineAdjust finds
      the prism only within its window around the starting direction, AUT_Search within its area,
      PowerSearch when its fan sweeps past the prism's Hz while the prism is visible; a search ends
      ``found_s`` after finding it (pointing at it), else with AUT_NO_TARGET; AUT_LockIn needs a fine
      adjustment onto the prism.
    """

    def __init__(self, config: Optional[SimConfig] = None, track: Callable[[float], np.ndarray] = builtin_track,
                 seed: Optional[int] = None):
        config = SimConfig() if config is None else config
        config.validate()
        self.config = config
        self.track = track
        self.rng = random.Random(seed)
        self.state_lock = threading.RLock()
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

    # --- instrument clock ----------------------------------------------------------------
    def instrument_ms_at(self, t: float) -> float:
        """Instrument counter (ms, not wrapped, fractional) at host time ``t`` (s)."""
        c = self.config
        return (t - self.t_boot) * (1.0 + c.clock_drift) * 1000.0 + c.clock_offset_ms

    def host_time_of(self, counter_ms: float) -> float:
        """Host time (s) at which the unwrapped counter reads ``counter_ms``."""
        c = self.config
        return self.t_boot + (counter_ms - c.clock_offset_ms) / 1000.0 / (1.0 + c.clock_drift)

    def event(self, kind: str, until: Optional[float] = None) -> None:
        """Log an injected fault or link event ``kind`` (until host time ``until``, s) in :attr:`events`."""
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

    def change(self, change: Callable[[], None]) -> None:
        """Apply ``change`` to the state with the EDM's distances kept right across it."""
        with self.state_lock:
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

        self.change(change)
        self.event("prism_visible" if visible else "prism_hidden")

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
        return self.rng.gauss(0.0, a.distance_sigma(distance) if kind == "distance" else a.angle_arcsec * ARCSEC)

    def _centring(self) -> np.ndarray:
        """The prism's centring error (m, per axis) of one measurement."""
        a = self.config.accuracy
        if a is None or a.prism_mm == 0:
            return np.zeros(3)
        return np.array([self.rng.gauss(0.0, 1e-3 * a.prism_mm) for _ in range(3)])

    # --- measurements ----------------------------------------------------------------------
    def _measure(self, tick: int) -> Tuple[int, Optional[Tuple[int, np.ndarray]], np.ndarray]:
        """Angles at counter ``tick``: (rc, the distance they combine with or None, true prism
        position at the tick). rc is 0 or 1285 TMC_ANGLE_OK (no valid distance)."""
        self._settle_edm(tick)
        now_p = self.track(self.host_time_of(tick) - self.t_boot)
        dist = self.distance
        if dist is None or (self.tracking and tick - dist[0] > _STALE_PERIODS * self.edm_period_ms):
            return RC.TMC_ANGLE_OK, None, now_p
        return RC.OK, dist, now_p

    def coordinate(self, tick: int, forced_rc: Optional[int], trid: Optional[int]) -> Tuple[int, tuple, TruthRecord]:
        """TMC_GetCoordinate with angles at counter ``tick`` (unwrapped ms): rc (``forced_rc`` when
        given and a distance exists), its eight values and its truth (transaction id ``trid``).
        Call with the state lock held."""
        c = self.config
        rc, dist, now_p = self._measure(tick)
        t_ms = int(tick) % c.wrap_ms
        if dist is None:
            values: tuple = (0.0, 0.0, 0.0, t_ms, 0.0, 0.0, 0.0, t_ms)
            truth = TruthRecord(float("nan"), -1, (math.nan,) * 3, int(rc), trid, True, self.host_time_of(tick), t_ms)
            return rc, values, truth
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
        truth = TruthRecord(self.host_time_of(d_ms), int(d_ms) % c.wrap_ms, (float(p[0]), float(p[1]), float(p[2])),
                            int(rc), trid, True, self.host_time_of(tick), t_ms)
        return rc, values, truth

    def angles(self, tick: int) -> Tuple[int, float, float, float, Optional[int]]:
        """Angles at counter ``tick``: rc (0, or 1285 without a valid distance), Hz and V (rad), the slope
        distance (m, 0 without) of the distance they combine with and that distance's unwrapped counter ms."""
        rc, dist, now_p = self._measure(tick)
        hz, v, _ = self._polar(now_p)
        slope = self._polar(dist[1])[2] if dist is not None else 0.0
        return rc, hz, v, slope, (None if dist is None else int(dist[0]))

    # --- procedures ------------------------------------------------------------------------
    def set_user_lock(self, on: bool) -> None:
        """LOCK mode on or off; off, the telescope stops following and the moving prism leaves its view."""
        def change() -> None:
            self.user_lock = on
            if not on:
                self.locked = self.adjusted = False

        self.change(change)

    def set_user_atr(self, on: bool) -> None:
        """ATR mode on or off (stored)."""
        self.change(lambda: setattr(self, "user_atr", on))

    def do_measure(self, program: int, t_complete: float) -> None:
        """TMC_DoMeasure ``program`` requested at host time ``t_complete`` (s): start or stop tracking,
        clear the distance, or take a single one."""
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

        self.change(change)

    def run_motion(self, rpc: int, params: Sequence[Union[int, float]], start_s: float,
                   wait: Callable[[float], bool]) -> Optional[int]:
        """Run the motorised procedure ``rpc`` (decoded ``params``) started at host time ``start_s`` to
        its end; ``wait(s)`` sleeps up to s seconds and returns True to abort (link down, stopped).
        Its rc, or None when aborted."""
        refused = self._motion_refused(rpc)
        if refused is not None:
            return refused
        duration = self._motion_duration(rpc, params)
        start_aim = self.aim()
        in_window = rpc == Rpc.AUT_FineAdjust and self.prism_visible and self._within(start_aim, params[0] / 2,
                                                                                       params[1] / 2)
        looked = self._look(rpc, params, start_aim, start_s, start_s + duration, wait)
        if looked is None:
            return None
        seen, now = looked
        if rpc == Rpc.AUT_MakePositioning:
            target = _positioning_target(params)
            self.change(lambda: self._turn_to(target))
            return RC.OK
        if rpc == Rpc.AUT_FineAdjust:  # the ATR looks where the telescope points, then centres the prism
            seen = now if in_window else None
        return self._motion_found(rpc, seen)

    def _motion_refused(self, rpc: int) -> Optional[int]:
        """The rc of a motorised procedure refused before it starts, else None."""
        c = self.config
        if rpc == Rpc.AUT_LockIn and c.strict:
            if not self.user_lock:
                return RC.AUT_NOT_ENABLED
            if not (self.adjusted and self.prism_visible):
                return RC.AUT_NO_TARGET
        if rpc == Rpc.AUT_PS_SearchNext and c.model == "TPS1200":
            return RC.NOT_IMPL   # no PowerSearch on this instrument
        return None

    def _motion_duration(self, rpc: int, params: Sequence[Union[int, float]]) -> float:
        """How long (s) the motorised procedure ``rpc`` runs when it finds nothing."""
        c = self.config
        if rpc == Rpc.AUT_LockIn:
            return c.lock_in_s if c.strict else 0.0
        if rpc == Rpc.AUT_FineAdjust:
            return c.fine_adjust_s
        if rpc == Rpc.AUT_MakePositioning:
            target = _positioning_target(params)
            hz0, v0 = self.aim()
            turn = max(abs(math.remainder(target[0] - hz0, 2 * math.pi)), abs(target[1] - v0))
            return c.positioning_s + turn / c.slew_rad_s
        return c.power_search_s if rpc == Rpc.AUT_PS_SearchNext else c.search_s

    def _look(self, rpc: int, params: Sequence[Union[int, float]], start_aim: Tuple[float, float], start_s: float,
              end: float, wait: Callable[[float], bool]) -> Optional[Tuple[Optional[float], float]]:
        """Let the procedure ``rpc`` look for the prism until host time ``end``, or ``found_s`` after it
        found it: (when it found it or None, the host time it stopped), or None when ``wait`` aborted."""
        seen: Optional[float] = None
        looked = 0.0   # s into the procedure up to which it has looked
        while True:
            now = time.time()
            if seen is None and self.prism_visible and self._finds(rpc, params, start_aim, looked, now - start_s):
                seen = now
            looked = now - start_s
            if now >= end or (seen is not None and now >= seen + self.config.found_s):
                return seen, now
            if wait(min(0.01, max(0.0, end - now))):
                return None

    def _motion_found(self, rpc: int, seen: Optional[float]) -> int:
        """End a lock-in, fine adjustment or search that found the prism at ``seen`` (None: did not)."""
        if not self.prism_visible or (rpc != Rpc.AUT_LockIn and seen is None):
            return RC.AUT_NO_TARGET
        if rpc == Rpc.AUT_LockIn:
            self.change(lambda: setattr(self, "locked", True))
        elif rpc == Rpc.AUT_FineAdjust:
            self.change(lambda: (setattr(self, "adjusted", True), self._point_at_prism()))
        else:
            self.change(self._point_at_prism)  # a search leaves the prism in the ATR's field
        return RC.OK

    def _turn_to(self, target: Tuple[float, float]) -> None:
        self._aim = target
        self.locked = self.adjusted = False

    def _within(self, aim: Tuple[float, float], hz_window: float, v_window: float) -> bool:
        """The prism is within ±``hz_window``, ±``v_window`` (rad) of ``aim`` (Hz, V) now."""
        hz, v = self._prism_direction()
        return abs(math.remainder(hz - aim[0], 2 * math.pi)) <= hz_window and abs(v - aim[1]) <= v_window

    def _finds(self, rpc: int, params, aim: Tuple[float, float], since: float, elapsed: float) -> bool:
        """A search ``rpc`` started pointing at ``aim`` finds the visible prism between ``since`` and ``elapsed`` s
        into it: AUT_Search within its area (its Hz and V widths), PowerSearch when its fan (full height) sweeps
        past the prism's Hz meanwhile (clockwise or not; a prism that shows up behind the fan waits for the next
        turn); AUT_FineAdjust is judged at its end, within its window."""
        if rpc == Rpc.AUT_Search:
            return self._within(aim, params[0] / 2, params[1] / 2)
        if rpc == Rpc.AUT_PS_SearchNext:
            turn = 2 * math.pi / self.config.power_search_s
            sign = 1.0 if params[0] == AUT_CLOCKWISE else -1.0
            ahead = (sign * (self._prism_direction()[0] - aim[0])) % (2 * math.pi)
            return (ahead - turn * since + _FAN_HALF_WIDTH_RAD) % (2 * math.pi) <= (
                turn * (elapsed - since) + 2 * _FAN_HALF_WIDTH_RAD)
        return False

"""The MS60 tracking loop: connect, lock on the prism, poll coordinates, survive faults.

States: ``connecting`` (first connection and set-up), ``searching`` (AUT_LockIn until the
instrument locks), ``locked`` (TMC_GetCoordinate at ``rate_hz``), ``lost`` (the lock dropped:
AUT_LockIn every cycle until it succeeds), ``reconnecting`` (the link failed: reopen, set up
again). Every position is stamped with its instrument time mapped to host time
(:class:`~.clock.InstrumentClock`), never with the reception time. Stamps never go backwards and
never repeat: a sample whose instrument time or stamp is not newer than the last one is dropped
and counted. Poll slots without a published sample after the first one are counted as lost.
The first ``warmup_samples`` positions (2 s at 20 Hz) only feed the clock fit: the lower
envelope needs a few low-latency replies *received promptly* before its stamps can be trusted.
On a loaded host the loop thread wakes late for some replies (their reception stamps are late by
milliseconds); after 1 s the envelope may still rest on such replies (with 8 CPU-bound processes
on 2 cores the first stamps were up to 3.6 ms late), after 2 s it had a prompt one (p95 < 1.1 ms).
"""

from __future__ import annotations

import collections
import contextlib
import enum
import threading
import time
from typing import Callable, Deque, Dict, List, NamedTuple, Optional, Tuple

from .client import GeoComClient, GeoComError, GeoComLinkError, GeoComRcError, GeoComTimeout
from .clock import InstrumentClock
from .protocol import BAP_PRISM_360, EDM_CONT_FAST, MOT_LOCKED_OUT, TMC_AUTO_INC, TMC_STOP, TMC_TRK_DIST, RcClass

__all__ = ["TrackerError", "TrackerState", "TrackerConfig", "PrismSample", "TrackerStats", "Ms60Tracker"]


class TrackerError(ValueError):
    """Bad tracker settings (names the setting)."""


class TrackerState(enum.Enum):
    CONNECTING = "connecting"
    SEARCHING = "searching"
    LOCKED = "locked"
    LOST = "lost"
    RECONNECTING = "reconnecting"
    STOPPED = "stopped"


class TrackerConfig(NamedTuple):
    """``url`` pyserial URL; ``baud`` bit/s; ``rate_hz`` poll rate (Hz); ``timeout_s`` reply
    timeout (s); ``max_timeouts`` consecutive timeouts before reconnecting; ``backoff_s`` pause
    between reconnection attempts (s); ``prism_type`` BAP_PRISMTYPE or None (leave as is);
    ``prism_constant_m`` additive constant (m) or None; ``station`` (E0, N0, H0, Hi) in metres
    or None; ``orientation_rad`` Hz orientation (rad) or None; ``min_latency_s`` the
    instrument's shortest measurement-to-reply time (s) for the clock; ``warmup_samples``
    positions that only feed the clock before the first one is published."""

    url: str
    baud: int = 115200
    rate_hz: float = 20.0
    timeout_s: float = 0.3
    max_timeouts: int = 3
    backoff_s: float = 0.1
    prism_type: Optional[int] = BAP_PRISM_360
    prism_constant_m: Optional[float] = None
    station: Optional[Tuple[float, float, float, float]] = None
    orientation_rad: Optional[float] = None
    min_latency_s: float = 0.0
    warmup_samples: int = 40

    def validate(self) -> None:
        """Raise TrackerError naming the first bad setting."""
        if not isinstance(self.url, str) or not self.url:
            raise TrackerError("port: an empty pyserial URL")
        checks = [("baud", self.baud > 0), ("rate", 0 < self.rate_hz <= 100), ("timeout", self.timeout_s > 0),
                  ("max_timeouts", self.max_timeouts >= 1), ("backoff", self.backoff_s >= 0),
                  ("min_latency", self.min_latency_s >= 0), ("warmup_samples", self.warmup_samples >= 0)]
        for name, ok in checks:
            if not ok:
                raise TrackerError(f"{name}: value out of range")
        if self.prism_constant_m is not None and not abs(self.prism_constant_m) < 1.0:
            raise TrackerError(f"prism_constant: {self.prism_constant_m} m is not within ±1 m")


class PrismSample(NamedTuple):
    """One prism position: ``stamp_s`` host time of the measurement (s), ``east``, ``north``,
    ``height`` (m, instrument frame = map), ``instrument_ms`` (raw counter, ms), ``rc`` (0 or a
    warning code 1283/1284)."""

    stamp_s: float
    east: float
    north: float
    height: float
    instrument_ms: int
    rc: int

    @property
    def warning(self) -> bool:
        return self.rc != 0


class TrackerStats(NamedTuple):
    """Counters and clock figures for status and diagnostics (rate in Hz, offset in s, drift
    dimensionless)."""

    state: str
    samples: int
    lost_samples: int
    rate_hz: float
    warnings: Dict[int, int]
    no_position: Dict[int, int]
    timeouts: int
    duplicates: int
    out_of_order: int
    reconnects: int
    relocks: int
    garbage_bytes: int
    stale_replies: int
    clock_offset_s: float
    clock_drift: float
    instrument: str


class Ms60Tracker:
    """Runs the loop in a thread (:meth:`start`/:meth:`stop`) and calls ``on_sample`` with each
    new :class:`PrismSample` and ``on_state`` with each new :class:`TrackerState` (from the
    loop's thread)."""

    def __init__(self, config: TrackerConfig, on_sample: Optional[Callable[[PrismSample], None]] = None,
                 on_state: Optional[Callable[[TrackerState], None]] = None,
                 client_factory: Callable[..., GeoComClient] = GeoComClient):
        config.validate()
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
        self._last_ms: Optional[int] = None
        self._last_stamp = float("-inf")
        self._clock_resets = 0
        self._recent: Deque[float] = collections.deque()
        self._timeouts_in_row = 0
        self.instrument = ""
        self.setup_warnings: List[str] = []
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
            self._thread.join(timeout=5.0)
        if self._client is not None and self.state in (TrackerState.LOCKED, TrackerState.LOST, TrackerState.SEARCHING):
            with contextlib.suppress(GeoComError):  # leave the instrument idle
                self._client.do_measure(TMC_STOP, TMC_AUTO_INC)
        self._close_client()
        self._set_state(TrackerState.STOPPED)

    def run(self) -> None:
        """The loop (blocks until :meth:`stop`)."""
        period = 1.0 / self.config.rate_hz
        next_tick = time.time()
        while not self._stop.is_set():
            delivered = self._cycle()
            next_tick += period
            now = time.time()
            slots = 1
            if now > next_tick:  # overran: skip the missed slots instead of bursting
                missed = int((now - next_tick) / period)
                slots += missed
                next_tick += missed * period
            if self.samples > 0:
                with self._stats_lock:
                    self.lost_samples += max(0, slots - delivered)
            self._stop.wait(max(0.0, next_tick - time.time()))

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

    # --- one cycle per poll slot -------------------------------------------------------------
    def _cycle(self) -> int:
        """Do the current state's work; returns the number of samples published (0 or 1)."""
        try:
            if self.state in (TrackerState.CONNECTING, TrackerState.RECONNECTING):
                self._connect()
            elif self.state in (TrackerState.SEARCHING, TrackerState.LOST):
                self._lock_in()
            elif self.state == TrackerState.LOCKED:
                return self._poll()
        except GeoComTimeout:
            with self._stats_lock:
                self.timeouts += 1
            self._timeouts_in_row += 1
            if self._timeouts_in_row >= self.config.max_timeouts and self.state != TrackerState.CONNECTING:
                self._reconnect()
        except GeoComLinkError:
            if self.state != TrackerState.CONNECTING:
                self._reconnect()
            else:
                self._stop.wait(self.config.backoff_s)
        except (GeoComError, ValueError):  # malformed reply content: skip this slot
            pass
        return 0

    def _reconnect(self) -> None:
        self._close_client()
        self._timeouts_in_row = 0
        if self.state != TrackerState.RECONNECTING:
            with self._stats_lock:
                self.reconnects += 1
        self._set_state(TrackerState.RECONNECTING)

    def _connect(self) -> None:
        self._close_client()
        c = self.config
        try:
            client = self._factory(c.url, c.baud, c.timeout_s)
        except GeoComLinkError:
            self._stop.wait(c.backoff_s)
            return
        self._client = client
        client.null_proc(timeout_s=min(c.timeout_s, 0.2))
        self._timeouts_in_row = 0
        if not self.instrument:
            self.instrument = f"{client.instrument_name()} #{client.instrument_number()} fw {client.firmware_version()}"
        optional = [
            (c.prism_type is not None, lambda: client.set_prism_type(c.prism_type)),
            (c.prism_constant_m is not None, lambda: client.set_prism_constant(c.prism_constant_m)),
            (c.station is not None, lambda: client.set_station(*c.station)),
            (c.orientation_rad is not None, lambda: client.set_orientation(c.orientation_rad)),
            (True, lambda: client.set_user_lock_state(True)),
            (True, lambda: client.set_edm_mode(EDM_CONT_FAST)),
            (True, lambda: client.do_measure(TMC_TRK_DIST, TMC_AUTO_INC)),
        ]
        for wanted, call in optional:
            if wanted:
                try:
                    call()
                except GeoComRcError as e:  # an instrument without this feature: carry on
                    if str(e) not in self.setup_warnings:
                        self.setup_warnings.append(str(e))
        locked = client.lock_status() != MOT_LOCKED_OUT
        self._set_state(TrackerState.LOCKED if locked else TrackerState.SEARCHING)

    def _lock_in(self) -> None:
        assert self._client is not None
        if self._client.lock_in() == 0:
            self._timeouts_in_row = 0
            if self.state == TrackerState.LOST:
                with self._stats_lock:
                    self.relocks += 1
            self._set_state(TrackerState.LOCKED)

    def _poll(self) -> int:
        assert self._client is not None
        timed = self._client.get_coordinate(0, TMC_AUTO_INC)
        self._timeouts_in_row = 0
        r = timed.reading
        if not r.has_position:
            with self._stats_lock:
                self.no_position[r.rc] = self.no_position.get(r.rc, 0) + 1
            if r.rc_class == RcClass.NO_POSITION and self._client.lock_status() == MOT_LOCKED_OUT:
                self._set_state(TrackerState.LOST)
            return 0
        with self._stats_lock:
            t_ms = self.clock.add(r.time_ms, timed.received_s, timed.reply_tx_s)
            stamp = self.clock.to_host(t_ms)
        if self.clock.resets != self._clock_resets:  # instrument restarted: its clock began anew
            self._clock_resets = self.clock.resets
            self._last_ms = None
        if self._last_ms is not None and t_ms <= self._last_ms:
            with self._stats_lock:
                self.duplicates += 1
            return 0
        self._last_ms = t_ms
        if len(self.clock) <= self.config.warmup_samples:
            return 0
        if stamp <= self._last_stamp:
            with self._stats_lock:
                self.out_of_order += 1
            return 0
        self._last_stamp = stamp
        sample = PrismSample(stamp, r.east, r.north, r.height, r.time_ms, r.rc)
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
        return 1

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
            return TrackerStats(self.state.value, self.samples, self.lost_samples, rate, dict(self.warnings),
                                dict(self.no_position), self.timeouts, self.duplicates, self.out_of_order,
                                self.reconnects, self.relocks, garbage, stale, offset, drift, self.instrument)

"""What the MS60 tracking loop takes and gives: its settings, states, samples and statistics.

In: nothing (types only). Out: :class:`TrackerConfig` (the port and the session's settings
:class:`~.tracker.Ms60Tracker` runs with; :meth:`TrackerConfig.validate` raises :class:`TrackerError`
naming the bad setting), :class:`TrackerState` (the loop's states), :class:`PrismSample` (one prism
position with its host-time stamp, raw instrument time, return code and covariance) and
:class:`TrackerStats` (a consistent snapshot of the loop's counters and clock figures, for status and
diagnostics).
Contract: positions in metres in the instrument's frame (= map), stamps in host seconds, instrument
times in raw counter milliseconds; no behaviour here beyond validation.
"""

from __future__ import annotations

import enum
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from ..errors import InstrumentError
from .accuracy import MS60_TRACKING, AccuracyError, InstrumentAccuracy
from .protocol import BAP_PRISM_360

__all__ = ["TrackerError", "TrackerState", "TrackerConfig", "PrismSample", "TrackerStats"]


class TrackerError(InstrumentError):
    """Bad tracker settings (names the setting)."""


class TrackerState(enum.Enum):
    CONNECTING = "connecting"
    SEARCHING = "searching"
    LOCKED = "locked"
    LOST = "lost"
    RECONNECTING = "reconnecting"
    ERROR = "error"
    STOPPED = "stopped"


class TrackerConfig(NamedTuple):
    """``url`` pyserial URL; ``baud`` bit/s; ``rate_hz`` nominal position rate (Hz; polls follow
    the EDM once its period is known); ``timeout_s`` reply timeout of ordinary calls (s);
    ``motion_timeout_s`` reply timeout of the motorised ones (s); ``max_timeouts`` consecutive
    timeouts before reconnecting; ``backoff_s`` pause between reconnection attempts (s);
    ``prism_type`` BAP_PRISMTYPE or None (leave as is); ``prism_constant_m`` additive constant
    (m) or None; ``station`` (E0, N0, H0, Hi) in metres or None; ``orientation_rad`` Hz
    orientation (rad) or None; ``min_latency_s`` the instrument's shortest measurement-to-reply
    time (s) for the clock; ``warmup_samples`` positions that only feed the clock before the
    first one is published; ``byte_timing`` whether replies cross a serial line byte by byte
    (None: all ports but socket://); ``no_distance_s`` how long a lock without a new distance is
    tolerated (s); ``error_retry_s`` pause before the session is tried again after an error (s);
    ``accuracy`` the instrument's accuracy class, each position's covariance (:mod:`.accuracy`);
    ``reaim_search_after_s`` how long re-aims at a prediction may fail (the prism hidden, or the prediction
    wrong) before the search sweeps for it all the same (s); ``turn_rate_deg_s`` how fast the instrument turns its
    telescope (°/s), for the time a re-aim's turn takes."""

    url: str
    baud: int = 115200
    rate_hz: float = 20.0
    timeout_s: float = 0.3
    motion_timeout_s: float = 30.0
    max_timeouts: int = 3
    backoff_s: float = 0.1
    prism_type: Optional[int] = BAP_PRISM_360
    prism_constant_m: Optional[float] = None
    station: Optional[Tuple[float, float, float, float]] = None
    orientation_rad: Optional[float] = None
    min_latency_s: float = 0.0
    warmup_samples: int = 40
    byte_timing: Optional[bool] = None
    no_distance_s: float = 2.0
    error_retry_s: float = 5.0
    accuracy: InstrumentAccuracy = MS60_TRACKING
    reaim_search_after_s: float = 10.0
    turn_rate_deg_s: float = 90.0

    def validate(self) -> None:
        """Raise TrackerError naming the first bad setting."""
        if not isinstance(self.url, str) or not self.url:
            raise TrackerError("port: an empty pyserial URL")
        checks = [("baud", self.baud > 0), ("rate", 0 < self.rate_hz <= 100), ("timeout", self.timeout_s > 0),
                  ("motion_timeout", self.motion_timeout_s >= self.timeout_s),
                  ("max_timeouts", self.max_timeouts >= 1), ("backoff", self.backoff_s >= 0),
                  ("min_latency", self.min_latency_s >= 0), ("warmup_samples", self.warmup_samples >= 0),
                  ("no_distance", self.no_distance_s > 0), ("error_retry", self.error_retry_s >= 0),
                  ("reaim_search_after", self.reaim_search_after_s >= 0), ("turn_rate", self.turn_rate_deg_s > 0)]
        for name, ok in checks:
            if not ok:
                raise TrackerError(f"{name}: value out of range")
        if self.prism_constant_m is not None and not abs(self.prism_constant_m) < 1.0:
            raise TrackerError(f"prism_constant: {self.prism_constant_m} m is not within ±1 m")
        try:
            self.accuracy.validate()
        except AccuracyError as e:
            raise TrackerError(f"accuracy: {e}") from None


class PrismSample(NamedTuple):
    """One prism position: ``stamp_s`` host time of its distance measurement (s), ``east``,
    ``north``, ``height`` (m, instrument frame = map), ``instrument_ms`` (raw counter of the
    distance, ms), ``rc`` (0 or a warning code 1283/1284), ``cov`` its covariance (3×3 m², east, north,
    height: the accuracy class carried from the station's polar measurement, :func:`.accuracy.polar_covariance`)."""

    stamp_s: float
    east: float
    north: float
    height: float
    instrument_ms: int
    rc: int
    cov: Optional[np.ndarray] = None

    @property
    def warning(self) -> bool:
        return self.rc != 0


class TrackerStats(NamedTuple):
    """Counters and clock figures for status and diagnostics (rate in Hz, offset in s, drift
    dimensionless); ``error`` the message of the error state ("" otherwise), ``notice`` why the
    prism is not locked ("" otherwise), ``program`` and ``search`` what the instrument accepted, ``reaims``
    the turns to a predicted position after a lost lock and ``reaims_found`` those the prism was found at."""

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
    error: str = ""
    notice: str = ""
    program: str = ""
    search: str = ""
    edm_period_ms: float = float("nan")
    reaims: int = 0
    reaims_found: int = 0

"""Instrument millisecond clock → host time (seconds), online, robust to serial latency spikes.

Each coordinate reply gives the instrument time ``T`` (ms) of its measurement (the angles taken
when the request arrived: TMC_GetCoordinate's CoordContTime) and the host time ``r`` (s) at which
the reply's last byte arrived. The reply's own bytes take ``tx`` seconds on a serial wire (10 bits
per byte at the baud rate; 0 on a TCP link, where the reply arrives as one packet: assuming the
serial time there would stamp early by the whole reply's wire time) and the instrument needs at
least ``min_latency``
seconds between the measurement and the first reply byte, so the measurement happened at host
time ``≤ r − tx − min_latency``. Writing ``y = r − tx − T/1000`` (s), every sample satisfies
``y ≥ offset(T)`` and the samples with the smallest latency touch that line: the offset + drift
line is the **lower envelope** of the (T, y) points. Latency spikes and jitter only lift points,
they never pull the estimate.

The fit: the lower convex hull of the samples in a sliding window; the supporting line of the
hull at the window's mean time (the line below all points that minimises the sum of residuals,
i.e. the linear-programming solution). The drift is bounded to ``max_drift`` (default 100 ppm);
before ``min_span_s`` of data the drift is taken as 0 and the offset is the lowest ``y``.

The ms counter wraps (``wrap_ms``, 2**32 by default): a step back by more than half the
modulus is a wrap; a smaller step back is an instrument restart and resets the fit.
"""

from __future__ import annotations

import collections
from typing import Deque, List, Optional, Tuple

from ..errors import InstrumentError

__all__ = ["ClockError", "InstrumentClock", "lower_envelope_line"]


class ClockError(InstrumentError):
    """A clock query before any sample, or bad clock parameters."""


def _cross(o, a, b) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def lower_envelope_line(points: List[Tuple[float, float]], max_slope: float) -> Tuple[float, float]:
    """Line ``y = a + b·x`` below all ``points`` minimising the summed residual, |b| ≤ max_slope.

    Returns ``(a, b)``. The optimum is the lower-hull edge spanning the mean x (or, when that
    edge is steeper than ``max_slope``, the line of slope ±max_slope through the lowest point
    relative to that slope)."""
    if not points:
        raise ClockError("no samples for the envelope")
    pts = sorted(set(points))
    mean_x = sum(p[0] for p in pts) / len(pts)
    hull: List[Tuple[float, float]] = []
    for p in pts:
        while len(hull) >= 2 and _cross(hull[-2], hull[-1], p) <= 0:
            hull.pop()
        hull.append(p)
    b = 0.0
    for p, q in zip(hull, hull[1:]):
        if p[0] <= mean_x <= q[0] and q[0] > p[0]:
            b = (q[1] - p[1]) / (q[0] - p[0])
            break
    b = max(-max_slope, min(max_slope, b))
    a = min(y - b * x for x, y in pts)
    return a, b


class InstrumentClock:
    """Maps instrument times (ms, wrapping counter) to host times (s).

    ``window`` samples are kept (default 1200, one minute at 20 Hz); ``min_latency_s`` is the
    instrument's shortest measurement-to-reply time (s), the only constant the link cannot
    observe; ``max_drift`` the bound on |drift| (dimensionless, 200e-6 = 200 ppm)."""

    def __init__(self, window: int = 1200, min_latency_s: float = 0.0, max_drift: float = 100e-6,
                 min_span_s: float = 10.0, wrap_ms: int = 2 ** 32):
        if window < 2 or min_latency_s < 0 or max_drift < 0 or wrap_ms < 2:
            raise ClockError("window ≥ 2, min_latency_s ≥ 0, max_drift ≥ 0 and wrap_ms ≥ 2 are required")
        self.min_latency_s = float(min_latency_s)
        self.max_drift = float(max_drift)
        self.min_span_s = float(min_span_s)
        self.wrap_ms = int(wrap_ms)
        self._samples: Deque[Tuple[float, float]] = collections.deque(maxlen=int(window))
        self._last_raw: Optional[int] = None
        self._wraps = 0
        self._origin_s: Optional[float] = None   # instrument seconds subtracted before fitting
        self._fit: Optional[Tuple[float, float]] = None
        self.resets = 0

    def unwrap(self, time_ms: int) -> int:
        """Monotonic instrument time (ms) of raw counter value ``time_ms``. Updates the wrap
        state: call it once per new sample, in arrival order."""
        t = int(time_ms) % self.wrap_ms
        if self._last_raw is not None and t < self._last_raw:
            if self._last_raw - t > self.wrap_ms // 2:
                self._wraps += 1
            else:
                self.reset()
                self.resets += 1
        self._last_raw = t
        return t + self._wraps * self.wrap_ms

    def reset(self) -> None:
        """Forget all samples (instrument restarted)."""
        self._samples.clear()
        self._last_raw = None
        self._wraps = 0
        self._origin_s = None
        self._fit = None

    def add(self, time_ms: int, received_s: float, reply_tx_s: float = 0.0) -> int:
        """Add one reply: instrument time ``time_ms`` (raw ms), host reception time of its last
        byte ``received_s`` (s), wire time of the reply ``reply_tx_s`` (s). Returns the unwrapped
        instrument time (ms)."""
        t_ms = self.unwrap(time_ms)
        t_s = t_ms / 1000.0
        if self._origin_s is None:
            self._origin_s = t_s
        x = t_s - self._origin_s
        self._samples.append((x, received_s - reply_tx_s - self.min_latency_s - t_s))
        self._fit = None
        return t_ms

    def __len__(self) -> int:
        """Number of samples in the window."""
        return len(self._samples)

    @property
    def ready(self) -> bool:
        return bool(self._samples)

    def _line(self) -> Tuple[float, float]:
        if self._fit is None:
            if not self._samples:
                raise ClockError("the instrument clock has no samples yet")
            span = self._samples[-1][0] - self._samples[0][0]
            slope = self.max_drift if span >= self.min_span_s else 0.0
            self._fit = lower_envelope_line(list(self._samples), slope)
        return self._fit

    @property
    def offset_s(self) -> float:
        """Host time minus instrument time (s) at the newest sample."""
        a, b = self._line()
        return a + b * self._samples[-1][0]

    @property
    def drift(self) -> float:
        """Host seconds per instrument second minus 1 (dimensionless; 1e-6 = 1 ppm)."""
        return self._line()[1]

    def to_host(self, time_ms_unwrapped: int) -> float:
        """Host time (s) of an unwrapped instrument time (ms, from :meth:`add`/:meth:`unwrap`)."""
        a, b = self._line()
        t_s = time_ms_unwrapped / 1000.0
        return t_s + a + b * (t_s - self._origin_s)

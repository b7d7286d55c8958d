"""What a time-offset estimator returns, and why it may not.

In: nothing (records). Out: :class:`OffsetEstimate` (offset, σ, confidence, the searched curve),
returned by :mod:`.coherence`, :mod:`.baseline` and :mod:`.online`; :class:`TimeSyncError`,
raised with the reason when the offset cannot be estimated from the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Tuple

import numpy as np

from ..errors import GeometryError

__all__ = ["TimeSyncError", "OffsetEstimate"]


class TimeSyncError(GeometryError):
    """The time offset cannot be estimated from these data; the message says why."""


@dataclass
class OffsetEstimate:
    """A camera ↔ total-station time offset (camera stamp = total-station time + ``offset``).

    ``offset`` and ``sigma`` in seconds; ``confidence`` in [0, 1] (peak coherence × uniqueness of
    the peak × sharpness, see ``estimate_offset``); ``coherence`` the peak value of the curve;
    ``taus`` / ``curve`` the coherence (or correlation, for the baseline) over the searched
    offsets (s), for plotting; ``yaw_offset`` (rad) the mean of VO yaw − track heading at the
    optimum; ``drift`` (rad/s) the fitted VO yaw drift of the first window; ``overlap`` (s) the
    time with usable (moving) samples; ``method`` "coherence" or "xcorr".
    """

    offset: float
    sigma: float
    confidence: float
    coherence: float
    taus: np.ndarray
    curve: np.ndarray
    method: str
    n_samples: int
    overlap: float
    yaw_offset: float = 0.0
    drift: float = 0.0
    extra: dict = field(default_factory=dict)

    def report_dict(self) -> dict:
        """The estimate for a report: milliseconds and degrees (the units a reader expects)."""
        return {
            "method": self.method,
            "offset_ms": 1e3 * self.offset,
            "sigma_ms": 1e3 * self.sigma,
            "confidence": self.confidence,
            "peak": self.coherence,
            "samples": self.n_samples,
            "overlap_s": self.overlap,
            "yaw_offset_deg": math.degrees(self.yaw_offset),
            "drift_deg_per_min": math.degrees(self.drift) * 60.0,
        }


def _check_search(search) -> Tuple[float, float]:
    lo, hi = (float(search[0]), float(search[1]))
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        raise TimeSyncError(f"search interval must be (low, high) seconds with low < high, got {search}")
    return lo, hi

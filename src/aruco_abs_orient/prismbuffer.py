"""The recent prism positions of the total station, and the prism position at an image's time.

In: samples (total-station time s, position (3,) m in map, covariance 3×3 m² or None) as they arrive, late
ones too (kept in time order, those older than ``horizon`` s before the newest dropped). Out: :meth:`PrismBuffer.at`
the position at a time by linear interpolation between the two samples around it (None when they are more than
``max_gap`` apart), or extrapolated from the last two up to ``max_extrapolation`` past the newest, with the extra
1-σ (m) that extrapolation adds; :meth:`PrismBuffer.cov_at` the larger of the neighbours' covariances. No ROS,
Python 3.8.
"""

from __future__ import annotations

import bisect
from typing import List, Optional, Tuple

import numpy as np

__all__ = ["PrismBuffer"]


class PrismBuffer:
    """Recent prism positions (total-station time), interpolated at image times, each with its covariance
    (3×3 m², None: unknown)."""

    def __init__(self, horizon: float = 30.0):
        self.horizon = horizon
        self.t: List[float] = []
        self.p: List[np.ndarray] = []
        self.cov: List[Optional[np.ndarray]] = []

    def add(self, t: float, p, cov=None) -> None:
        cov = None if cov is None else np.asarray(cov, dtype=float)
        if self.t and t <= self.t[-1]:
            if t == self.t[-1]:
                return
            i = bisect.bisect_left(self.t, t)  # late sample: insert in order
            self.t.insert(i, t)
            self.p.insert(i, np.asarray(p, dtype=float))
            self.cov.insert(i, cov)
        else:
            self.t.append(t)
            self.p.append(np.asarray(p, dtype=float))
            self.cov.append(cov)
        cut = bisect.bisect_left(self.t, self.t[-1] - self.horizon)
        if cut:
            del self.t[:cut], self.p[:cut], self.cov[:cut]

    def clear(self) -> None:
        self.t.clear()
        self.p.clear()
        self.cov.clear()

    def cov_at(self, t: float) -> Optional[np.ndarray]:
        """The covariance (3×3 m²) of the samples around ``t``, the larger of the two neighbours' (None when
        either is unknown or there are none)."""
        i = bisect.bisect_right(self.t, t)
        near = [self.cov[k] for k in (i - 1, i) if 0 <= k < len(self.t)]
        if not near or any(c is None for c in near):
            return None
        return max(near, key=lambda c: float(np.trace(c)))

    def at(self, t: float, max_gap: float, max_extrapolation: float) -> Optional[Tuple[np.ndarray, float]]:
        """(position, extra 1-σ in m from interpolation/extrapolation) at ``t``, or None."""
        n = len(self.t)
        if n == 0:
            return None
        i = bisect.bisect_right(self.t, t)
        if 0 < i < n:
            t0, t1 = self.t[i - 1], self.t[i]
            if t1 - t0 > max_gap:
                return None
            a = (t - t0) / (t1 - t0)
            return self.p[i - 1] + a * (self.p[i] - self.p[i - 1]), 0.0
        if i == n and n >= 2 and t - self.t[-1] <= max_extrapolation:
            v = (self.p[-1] - self.p[-2]) / max(self.t[-1] - self.t[-2], 1e-3)
            dt = t - self.t[-1]
            return self.p[-1] + v * dt, 0.5 * float(np.linalg.norm(v)) * dt
        if i == n and t == self.t[-1]:
            return self.p[-1], 0.0
        return None

"""The live node's time-offset estimator: incremental, over a sliding horizon, thread-safe.

In: VO yaws, prism fixes and marker yaws as they arrive. Out: the offset in use
(:attr:`OnlineOffsetEstimator.applied`, fused from confident :mod:`.coherence` estimates) and
camera stamps put on the total station's clock (:meth:`OnlineOffsetEstimator.correct_stamp`).
"""

from __future__ import annotations

import collections
import math
import threading
from typing import Deque, Optional, Tuple

import numpy as np

from .coherence import YawSeries, estimate_offset, estimate_offset_from_marker_yaws
from .estimate import OffsetEstimate, TimeSyncError, _check_search

__all__ = ["OnlineOffsetEstimator"]


class OnlineOffsetEstimator:
    """Incremental time-offset estimation for the live node, over a sliding ``horizon`` (s).

    Feed samples as they come (``add_vo`` yaw on the camera clock, ``add_track`` prism fixes on the
    total-station clock, ``add_marker_yaw`` absolute yaws on the camera clock) and call ``update``;
    every ``update_period`` s of camera time it re-estimates over the buffered data (memory is
    bounded by ``horizon`` and ``max_samples`` per stream). ``latest`` is the last estimate (or
    None), ``last_error`` why the last attempt failed (or None); ``applied`` is the offset in use,
    changed only by an estimate with ``confidence ≥ min_confidence`` and ``sigma ≤ max_sigma``.

    Confident estimates are fused (a scalar Kalman filter, ``applied_sigma`` its σ in s): the first
    counts fully; each later one shares all but ``update_period`` s of its data with the previous,
    so it enters with its variance × ``horizon / update_period``; the offset may wander as a random
    walk of ``offset_walk`` s/√s (clock drift). ``**kwargs`` go to :func:`.coherence.estimate_offset`:
    ``params`` (:class:`~.coherence.TimeSyncParams`) and ``prism_in_base``.

    Thread-safe: the ``add_*`` calls may come from one thread while ``update_in_background`` runs the
    estimate (0.1–0.5 s of numpy) in another, so a live node's image loop never waits for it.
    """

    def __init__(self, horizon: float = 90.0, search=(-1.0, 1.0), update_period: float = 5.0,
                 min_confidence: float = 0.5, max_sigma: float = 0.01, max_samples: int = 20000,
                 offset_walk: float = 1e-4, **kwargs):
        if horizon <= 0 or update_period <= 0:
            raise TimeSyncError("horizon and update_period must be > 0 s")
        self.horizon = float(horizon)
        self.search = _check_search(search)
        self.update_period = float(update_period)
        self.min_confidence = float(min_confidence)
        self.max_sigma = float(max_sigma)
        self.kwargs = kwargs
        self._vo: Deque[Tuple[float, float]] = collections.deque(maxlen=max_samples)
        self._track: Deque[Tuple[float, float, float]] = collections.deque(maxlen=max_samples)
        self._marker: Deque[Tuple[float, float]] = collections.deque(maxlen=max_samples)
        self._last_update: Optional[float] = None
        self.latest: Optional[OffsetEstimate] = None
        self.last_error: Optional[str] = None
        self.offset_walk = float(offset_walk)
        self.applied: Optional[float] = None
        self.applied_sigma: Optional[float] = None
        self._applied_at: Optional[float] = None
        self._lock = threading.Lock()
        self._worker: Optional[threading.Thread] = None

    def add_vo(self, t: float, yaw: float) -> None:
        """A VO yaw (rad) of base_link stamped ``t`` (s, camera clock)."""
        with self._lock:
            self._vo.append((float(t), float(yaw)))
            self._trim(self._vo, float(t))

    def add_track(self, t: float, x: float, y: float) -> None:
        """A prism fix (m, map) stamped ``t`` (s, total-station clock)."""
        with self._lock:
            self._track.append((float(t), float(x), float(y)))
            self._trim(self._track, float(t))

    def add_marker_yaw(self, t: float, yaw: float) -> None:
        """An absolute yaw (rad) of base_link from a marker, stamped ``t`` (s, camera clock)."""
        with self._lock:
            self._marker.append((float(t), float(yaw)))
            self._trim(self._marker, float(t))

    def clear(self) -> None:
        """Forget the buffered samples (a time jump: a looped bag); the applied offset is kept."""
        with self._lock:
            self._vo.clear()
            self._track.clear()
            self._marker.clear()
            self._last_update = None

    def _trim(self, buf: Deque, newest: float) -> None:
        while buf and buf[0][0] < newest - self.horizon:
            buf.popleft()

    @property
    def buffered(self) -> Tuple[int, int, int]:
        """Numbers of buffered (VO, track, marker) samples."""
        return len(self._vo), len(self._track), len(self._marker)

    def _due(self, now: Optional[float], force: bool):
        """(now, VO, track, marker arrays) to estimate from when an update is due, else None."""
        with self._lock:
            if not self._vo and not self._marker:
                return None
            if now is None:
                now = max(self._vo[-1][0] if self._vo else -math.inf,
                          self._marker[-1][0] if self._marker else -math.inf)
            if not force and self._last_update is not None and now - self._last_update < self.update_period:
                return None
            self._last_update = now
            return (now, np.array(self._vo, dtype=float).reshape(-1, 2),
                    np.array(self._track, dtype=float).reshape(-1, 3),
                    np.array(self._marker, dtype=float).reshape(-1, 2))

    def update(self, now: Optional[float] = None, force: bool = False) -> Optional[OffsetEstimate]:
        """Re-estimate if ``update_period`` s (camera clock ``now``, default the newest VO stamp)
        passed since the last attempt, or if ``force``; returns the new estimate or None."""
        data = self._due(now, force)
        return None if data is None else self._estimate_from(*data)

    def update_in_background(self, now: Optional[float] = None) -> bool:
        """Like ``update`` but in a daemon thread (at most one at a time); True if one was started.
        ``latest``, ``applied`` and ``last_error`` change when it ends."""
        if self._worker is not None and self._worker.is_alive():
            return False
        data = self._due(now, False)
        if data is None:
            return False
        self._worker = threading.Thread(target=self._estimate_from, args=data, name="time offset", daemon=True)
        self._worker.start()
        return True

    def suggestion(self, in_use: float, min_difference: float = 0.02, n_sigma: float = 5.0) -> Optional[float]:
        """The applied (confident, fused) offset when it contradicts the offset ``in_use`` (s): differs
        by more than ``n_sigma`` ``applied_sigma`` and ``min_difference`` s (a forgotten or wrong offset);
        else None (keep ``in_use``: a good offset from ``timesync --markers`` is not replaced by a coarser
        live one, nor by one whose σ is optimistic)."""
        with self._lock:  # a consistent pair: the worker thread fuses both
            applied, sigma = self.applied, self.applied_sigma
        if applied is None or sigma is None:
            return None
        return applied if abs(applied - in_use) > max(n_sigma * sigma, min_difference) else None

    def _estimate_from(self, now: float, vo: np.ndarray, track: np.ndarray, mk: np.ndarray) -> Optional[OffsetEstimate]:
        try:
            if len(mk) >= 3:
                est = estimate_offset_from_marker_yaws(
                    YawSeries(mk[:, 0], mk[:, 1]), track[:, 0], track[:, 1:],
                    YawSeries(vo[:, 0], vo[:, 1]) if len(vo) else None, search=self.search, **self.kwargs)
            else:
                est = estimate_offset(vo[:, 0], vo[:, 1], track[:, 0], track[:, 1:], search=self.search,
                                      **self.kwargs)
        except TimeSyncError as e:
            self.last_error = str(e)
            return None
        with self._lock:
            self.last_error = None
            self.latest = est
            if est.confidence >= self.min_confidence and est.sigma <= self.max_sigma:
                self._fuse(est, now)
        return est

    def _fuse(self, est: OffsetEstimate, now: float) -> None:
        if self.applied is None or self.applied_sigma is None or self._applied_at is None:
            self.applied, self.applied_sigma, self._applied_at = est.offset, est.sigma, now
            return
        prior_var = self.applied_sigma**2 + self.offset_walk**2 * max(0.0, now - self._applied_at)
        new_var = est.sigma**2 * max(1.0, self.horizon / self.update_period)
        gain = prior_var / (prior_var + new_var)
        self.applied += gain * (est.offset - self.applied)
        self.applied_sigma = math.sqrt((1.0 - gain) * prior_var)
        self._applied_at = now

    def correct_stamp(self, t_camera: float) -> float:
        """Camera stamp (s) moved to the total-station clock with the applied offset (unchanged
        while none is applied)."""
        return t_camera - self.applied if self.applied is not None else t_camera

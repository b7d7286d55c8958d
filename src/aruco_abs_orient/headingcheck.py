"""A dual-antenna GNSS heading beside the marker heading: do the two agree?

In: the marker heading (ENU yaw of base_link, rad, at its stamps: ``abs_orient/orientation``), the receiver's
heading at its stamps (its baseline's azimuth clockwise from true north, or its ENU yaw: :func:`receiver_yaw`, the
baseline's mounting yaw in base_link taken off), and what the marker heading is referred to
(:class:`~aruco_abs_orient.north.NorthReference`: grid or true north, the meridian convergence γ). Out:
:meth:`HeadingAgreement.summary`, an :class:`Agreement`: the pairs of the last ``window`` seconds (each receiver
heading against the marker heading interpolated to its stamp), the mean of receiver − markers − what the north
explains (0 with ``north: true``, −γ with ``north: grid``), its σ (the pairs' scatter, with their correlation in
time), and the verdict: ``ok`` (agree within ``k`` σ or ``tolerance``), ``warn`` with the likely cause (a
difference of about ±γ: one side's north is not what it says; any other constant: the baseline's mounting angle)
or ``waiting`` (too few pairs). A receiver's heading is always true north; a grid heading is turned to it by γ.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple, Optional

import numpy as np

from .calibration.variance import correlation_factor
from .errors import ConfigurationError
from .north import NorthReference
from .transforms import wrap_angle

__all__ = ["CONVENTIONS", "receiver_yaw", "Agreement", "HeadingAgreement"]

#: how a receiver states its heading: ``compass`` the baseline's azimuth clockwise from north (NMEA HDT,
#: nmea_navsat_driver's ``heading`` quaternion), ``enu`` the ENU yaw counter-clockwise from east (REP 103)
CONVENTIONS = ("compass", "enu")


def receiver_yaw(angle: float, convention: str, mounting_yaw: float = 0.0) -> float:
    """base_link's ENU yaw (rad) from a receiver's heading ``angle`` (rad) in ``convention`` and its baseline's
    yaw in base_link ``mounting_yaw`` (rad: 0 when the antennas lie along base_link's x, rear to front)."""
    if convention not in CONVENTIONS:
        raise ConfigurationError(f"convention: expected one of {CONVENTIONS}, got {convention!r}")
    yaw = math.pi / 2.0 - angle if convention == "compass" else angle
    return float(wrap_angle(yaw - mounting_yaw))


class Agreement(NamedTuple):
    """The verdict of :meth:`HeadingAgreement.summary`: ``pairs``; ``mean`` (rad) of receiver − markers − what
    the north explains; ``sigma`` (rad) of that mean; ``level`` ``ok``, ``warn`` or ``waiting``; ``message``."""

    pairs: int
    mean: float
    sigma: float
    level: str
    message: str


class HeadingAgreement:
    """Pairs of receiver and marker headings over the last ``window`` s (a marker heading is interpolated to a
    receiver stamp between two within ``max_gap`` s of each other); :meth:`summary` tests their mean difference
    against ``k`` times its σ, and against ``tolerance`` (rad: the receiver's own bias, a baseline's mounting
    measured to so much), whichever is larger, once there are ``min_pairs``."""

    def __init__(self, window: float = 60.0, max_gap: float = 0.5, min_pairs: int = 20, k: float = 3.0,
                 tolerance: float = math.radians(0.1)):
        self.window, self.max_gap, self.min_pairs, self.k, self.tolerance = window, max_gap, min_pairs, k, tolerance
        self._markers: deque = deque()   # (t, yaw), in time order
        self._pairs: deque = deque()     # (t, receiver − markers)
        self._waiting: deque = deque()   # receiver (t, yaw) after the last marker heading

    def add_markers(self, t: float, yaw: float) -> None:
        """A marker heading (ENU yaw of base_link, rad) at ``t`` (s); a stamp older than the last is ignored. The
        receiver headings waiting for it are paired."""
        if self._markers and t <= self._markers[-1][0]:
            return
        self._markers.append((float(t), float(yaw)))
        while self._markers and self._markers[0][0] < t - self.window - self.max_gap:
            self._markers.popleft()
        waiting, self._waiting = self._waiting, deque()
        for tr, yr in waiting:
            if self._pair(tr, yr) is None and tr > t - self.max_gap:
                self._waiting.append((tr, yr))

    def add_receiver(self, t: float, yaw: float) -> None:
        """A receiver heading (base_link's ENU yaw, :func:`receiver_yaw`) at ``t``: paired when marker headings
        within ``max_gap`` of each other bracket ``t``, now or when the next arrives (the marker heading comes an
        image's processing later)."""
        if self._pair(float(t), float(yaw)) is None and self._markers and \
                self._markers[-1][0] < t <= self._markers[-1][0] + self.max_gap:  # else no heading can bracket it
            self._waiting.append((float(t), float(yaw)))

    def _pair(self, t: float, yaw: float) -> Optional[float]:
        """Receiver − markers at ``t``, recorded, or None when no two marker headings bracket ``t``."""
        times = [m[0] for m in self._markers]
        i = int(np.searchsorted(times, t))
        if i == 0 or i == len(times):
            return None
        (t0, y0), (t1, y1) = self._markers[i - 1], self._markers[i]
        if t1 - t0 > self.max_gap:
            return None
        ours = y0 + float(wrap_angle(y1 - y0)) * (t - t0) / (t1 - t0)
        diff = float(wrap_angle(yaw - ours))
        self._pairs.append((t, diff))
        while self._pairs and self._pairs[0][0] < t - self.window:
            self._pairs.popleft()
        return diff

    def summary(self, north: NorthReference) -> Agreement:
        """The verdict over the pairs in the window; ``north``: what the marker heading is referred to."""
        n = len(self._pairs)
        if n < self.min_pairs:
            return Agreement(n, float("nan"), float("nan"), "waiting",
                             f"{n} pairs of receiver and marker headings (need {self.min_pairs})")
        d = np.array([p[1] for p in self._pairs])
        gamma = north.gamma if math.isfinite(north.gamma) else 0.0
        expected = -gamma if north.north == "grid" else 0.0  # a receiver's heading is true north
        d = np.asarray(wrap_angle(d - expected))
        mean = float(np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d))))
        sigma = float(np.std(d) * math.sqrt(correlation_factor(d[:, None]) / n))
        limit = max(self.k * sigma, self.tolerance)
        told = (f"receiver − markers {math.degrees(mean):+.3f}° ± {math.degrees(sigma):.3f}° over {n} pairs "
                f"(markers referred to {north.north} north")
        told += f", γ {math.degrees(gamma):+.3f}° taken into account)" if expected else ")"
        if abs(mean) <= limit:
            return Agreement(n, mean, sigma, "ok", f"agree: {told}")
        if math.isfinite(north.gamma) and abs(north.gamma) > limit and min(
                abs(mean - north.gamma), abs(mean + north.gamma)) <= limit:
            return Agreement(n, mean, sigma, "warn", (
                f"differ by the meridian convergence ({math.degrees(north.gamma):+.3f}°): {told}; one of them is not "
                "referred to the north it states (a receiver set to grid azimuths, or ~north not what the map is)"))
        return Agreement(n, mean, sigma, "warn", (
            f"differ: {told}; a constant difference is the antennas' baseline not where ~mounting_yaw_deg says "
            "(or a receiver fault)"))

"""Roll and pitch of base_link (gravity), from the best source at hand (doc/design.md §9).

In: the odometry's attitude, IMU samples (``sensor_msgs/Imu``'s orientation, or gravity from its acceleration at
standstill when the orientation is unknown: :func:`tilt_from_imu`) and the attitudes of frames with ≥ 2
well-spread markers. Out: :meth:`TiltEstimator.tilt`, a frame's roll and pitch with its source: the IMU's,
interpolated, when a recent sample exists; else the odometry's corrected by the tilt of its odom frame against
gravity (``δ``, about odom's x and y, fixed in odom while the platform turns under it: the error seen from
heading ψ is ``Rz(−ψ)·δ``), kept as a random walk in a two-state Kalman filter updated by the absolute tilts
with χ² gating; else the odometry's. Seconds, radians, m/s²; numpy only, Python 3.8, no ROS.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import List, NamedTuple, Optional, Tuple

import numpy as np

from .paramspec import Params, param
from .transforms import matrix_to_rpy, quat_to_matrix, wrap_angle

__all__ = ["TiltParams", "Tilt", "TiltEstimator", "tilt_from_imu", "GRAVITY"]

GRAVITY = 9.80665  # m/s²
INITIAL_OFFSET_SIGMA = math.radians(5.0)  # rad, prior σ of the odometry's tilt error


#: the σ of an IMU's roll and pitch when it states none: a quarter of the odometry's default tilt σ (0.2°), what an
#: IMU's attitude filter reaches at least
IMU_DEFAULT_SIGMA = math.radians(0.2) / 4
#: the smallest σ of roll and pitch from gravity at standstill: the accelerometer's own axes are not better aligned
GRAVITY_SIGMA_FLOOR = math.radians(0.02)
#: at standstill (the acceleration is gravity) when the angular rate is below this (rad/s) ...
STANDSTILL_GYRO = 0.02
#: ... and | |a| − g | below this (m/s²): the thresholds of an IMU at rest, not of the platform's motion
STANDSTILL_ACCEL = 0.1


@dataclass
class TiltParams(Params):
    """Tuning of :class:`TiltEstimator` (cfg/params.yaml's ``tilt`` section; the odometry's own tilt σ is the
    pipeline's ``tilt_sigma_deg``)."""

    offset_walk: float = param(math.radians(0.05), "random walk of the odometry's tilt error: how fast a VO's tilt "
                               "drifts", "rad/√s", 0.0)
    gate_chi2: float = param(13.82, "gate of an absolute tilt against the prediction", "χ², 2 dof", above=0.0)
    imu_max_age: float = param(0.2, "an IMU sample further than this from the frame is not used for it", "s", 0.0)


class Tilt(NamedTuple):
    """Roll, pitch (rad) of base_link with their 1-σ (rad) and where they came from."""

    roll: float
    pitch: float
    sigma: float
    source: str   # 'imu', 'markers' or 'odometry'


def tilt_from_imu(orientation, orientation_cov, linear_acceleration, acceleration_cov, angular_velocity,
                  base_R_imu=None) -> Tuple[Optional[Tuple[float, float, float]], str]:
    """(roll, pitch, σ) of base_link in rad from one ``sensor_msgs/Imu`` sample, or (None, why not).

    ``orientation`` quaternion (x, y, z, w) of the IMU in a gravity-aligned frame; ``orientation_cov`` its
    row-major 3×3 covariance (rad²; covariance[0] = −1: orientation unknown, REP-145);
    ``linear_acceleration`` (m/s², specific force: +g up at rest) with ``acceleration_cov`` (m⁴/s⁴);
    ``angular_velocity`` (rad/s); ``base_R_imu`` the IMU's mounting rotation in base_link (None: aligned).
    The orientation is used when known and finite; else the acceleration when the IMU stands still
    (|ω| < :data:`STANDSTILL_GYRO`, | |a| − g | < :data:`STANDSTILL_ACCEL`).
    """
    R_bi = np.eye(3) if base_R_imu is None else np.asarray(base_R_imu, dtype=float)
    q = np.asarray(orientation, dtype=float)
    oc = np.asarray(orientation_cov, dtype=float).reshape(-1)
    why = ""
    if oc.size and oc[0] == -1:
        why = "orientation unknown (covariance[0] = -1)"
    elif not (np.all(np.isfinite(q)) and np.all(np.isfinite(oc))) or float(q @ q) < 0.5:
        why = "orientation not finite"
    else:
        R = quat_to_matrix(q / np.linalg.norm(q)) @ R_bi.T
        roll, pitch, _ = matrix_to_rpy(R)
        var = max(float(oc[0]), float(oc[4])) if oc.size == 9 else 0.0
        return (float(roll), float(pitch), math.sqrt(var) if var > 0 else IMU_DEFAULT_SIGMA), ""
    a = np.asarray(linear_acceleration, dtype=float)
    w = np.asarray(angular_velocity, dtype=float)
    ac = np.asarray(acceleration_cov, dtype=float).reshape(-1)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(w))) or (ac.size and ac[0] == -1):
        return None, why + "; acceleration not usable"
    if float(np.linalg.norm(w)) > STANDSTILL_GYRO or abs(float(np.linalg.norm(a)) - GRAVITY) > STANDSTILL_ACCEL:
        return None, why + "; not at standstill (no gravity from the acceleration)"
    g = R_bi @ a                                  # specific force in base_link: R_tᵀ (0, 0, g)
    roll = math.atan2(g[1], g[2])
    pitch = math.atan2(-g[0], math.hypot(g[1], g[2]))
    sa = math.sqrt(max(float(ac[0]), 0.0)) if ac.size and np.all(np.isfinite(ac)) else 0.0
    return (roll, pitch, max(sa / GRAVITY, GRAVITY_SIGMA_FLOOR)), ""


class TiltEstimator:
    """The tilt of base_link per frame (see the module docstring)."""

    def __init__(self, params: Optional[TiltParams], odometry_sigma: float):
        """``odometry_sigma``: 1-σ of the odometry's roll and pitch before any correction (rad: the pipeline's
        ``tilt_sigma_deg``)."""
        self.params = params or TiltParams()
        self.odometry_sigma = odometry_sigma
        self.offset = np.zeros(2)
        self.P = np.eye(2) * INITIAL_OFFSET_SIGMA ** 2   # a VO may start tilted by degrees
        self.t = -math.inf
        self.marker_updates = 0
        self.imu_updates = 0
        self.rejected = 0
        self.last_source = "odometry"            # the absolute source that last corrected the offset
        self._imu_t: List[float] = []
        self._imu: List[Tuple[float, float, float]] = []

    @staticmethod
    def _seen_from(odom_yaw: float) -> np.ndarray:
        """H: base_link's (roll, pitch) error = H · δ at the heading ``odom_yaw`` (rad)."""
        c, s = math.cos(odom_yaw), math.sin(odom_yaw)
        return np.array([[c, s], [-s, c]])

    def _predict(self, t: float) -> np.ndarray:
        dt = max(0.0, t - self.t) if math.isfinite(self.t) else 0.0
        return self.P + np.eye(2) * self.params.offset_walk ** 2 * dt

    def update(self, t: float, roll: float, pitch: float, cov, odom_roll: float, odom_pitch: float,
               source: str = "markers", odom_yaw: float = 0.0) -> bool:
        """An absolute tilt (rad, covariance 2×2 rad² or a σ) at ``t`` (s) with the odometry's roll, pitch
        and yaw then; False when gated or not finite."""
        C = np.asarray(cov, dtype=float)
        C = C * C * np.eye(2) if C.ndim == 0 else C
        z = wrap_angle(np.array([roll - odom_roll, pitch - odom_pitch]))
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(C)) and math.isfinite(t)):
            self.rejected += 1
            return False
        P = self._predict(t)
        H = self._seen_from(odom_yaw)
        S = H @ P @ H.T + C
        nu = z - H @ self.offset
        if float(nu @ np.linalg.solve(S, nu)) > self.params.gate_chi2:
            self.rejected += 1
            return False
        K = P @ H.T @ np.linalg.inv(S)
        self.offset = self.offset + K @ nu
        self.P = (np.eye(2) - K @ H) @ P
        self.t = max(t, self.t)
        if source == "imu":
            self.imu_updates += 1
        else:
            self.marker_updates += 1
        self.last_source = source
        return True

    def add_imu(self, t: float, roll: float, pitch: float, sigma: float) -> None:
        """An IMU tilt (rad, 1-σ rad) at time ``t`` (s); kept for interpolation at frame times."""
        if not all(math.isfinite(x) for x in (t, roll, pitch, sigma)):
            return
        i = bisect.bisect_right(self._imu_t, t)
        self._imu_t.insert(i, t)
        self._imu.insert(i, (roll, pitch, sigma))
        cut = bisect.bisect_left(self._imu_t, self._imu_t[-1] - 5.0)
        del self._imu_t[:cut], self._imu[:cut]

    def imu_at(self, t: float) -> Optional[Tuple[float, float, float]]:
        """The IMU's (roll, pitch, σ) interpolated at ``t`` (s), None without a sample within imu_max_age."""
        if not self._imu_t:
            return None
        i = bisect.bisect_right(self._imu_t, t)
        age = self.params.imu_max_age
        if 0 < i < len(self._imu_t) and self._imu_t[i] - self._imu_t[i - 1] <= 2 * age:
            t0, t1 = self._imu_t[i - 1], self._imu_t[i]
            a = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
            x0, x1 = np.array(self._imu[i - 1]), np.array(self._imu[i])
            r = x0 + a * (x1 - x0)
            return float(r[0]), float(r[1]), float(max(x0[2], x1[2]))
        for j in (i - 1, i):
            if 0 <= j < len(self._imu_t) and abs(self._imu_t[j] - t) <= age:
                return self._imu[j]
        return None

    def corrected(self, odom_roll: float, odom_pitch: float, odom_yaw: float) -> Tuple[float, float]:
        """The odometry's roll and pitch (rad) corrected by the estimated tilt error, without taking any sample
        (a prediction: where the markers will be)."""
        if not (self.marker_updates or self.imu_updates):
            return odom_roll, odom_pitch
        d = self._seen_from(odom_yaw) @ self.offset
        return odom_roll + float(d[0]), odom_pitch + float(d[1])

    def tilt(self, t: float, odom_roll: float, odom_pitch: float, odom_yaw: float = 0.0) -> Tilt:
        """The tilt of base_link at ``t`` (s) given the odometry's roll, pitch and yaw then (rad)."""
        imu = self.imu_at(t)
        if imu is not None:
            self.update(t, imu[0], imu[1], imu[2], odom_roll, odom_pitch, source="imu", odom_yaw=odom_yaw)
            return Tilt(imu[0], imu[1], imu[2], "imu")
        if self.marker_updates or self.imu_updates:
            P = self._predict(t)   # H is a rotation: the largest σ is the same in odom and in base_link
            d = self._seen_from(odom_yaw) @ self.offset
            return Tilt(odom_roll + float(d[0]), odom_pitch + float(d[1]),
                        math.sqrt(float(np.linalg.eigvalsh(P)[-1])), self.last_source)
        return Tilt(odom_roll, odom_pitch, self.odometry_sigma, "odometry")

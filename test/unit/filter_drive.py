"""A simulated drive with a known drifting odometry, shared by the MapOdomFilter tests.

The truth is built here from transforms.py: a base_link trajectory in map (standstill, then a
curve with some tilt), a map→odom yaw offset δψ(t) (constant drift and/or random walk) and odom
position drift; the odometry is the truth seen through the drifting map→odom, so
``map_T_odom_true(t) · odom_T_base(t) = map_T_base_true(t)`` exactly. The prism and the marker
yaws are the truth plus known noise. :meth:`Drive.run` feeds a filter and returns its errors.
"""

import math

import numpy as np

from aruco_abs_orient.transforms import make_T, rot_z, rpy_to_matrix, wrap_angle

PRISM_IN_BASE = np.array([-0.2, 0.05, 1.3])
SIGMA_PRISM = 0.005          # m
SIGMA_YAW = math.radians(0.2)


class Drive:
    """Truth and odometry sampled every ``dt`` s: still for ``still`` s, then a curve at ``speed`` m/s."""

    def __init__(self, seed, duration, dt=0.05, still=3.0, speed=1.0, dpsi0=2.0, drift_rate=0.0,
                 yaw_walk=0.0, trans_walk=0.0, rate_walk=0.0):
        rng = np.random.default_rng(seed)
        self.rng = rng
        n = int(round(duration / dt)) + 1
        self.t = np.arange(n) * dt
        moving = np.clip(self.t - still, 0.0, None)
        self.heading = 0.7 + 0.4 * np.sin(0.3 * moving)
        self.roll = 0.01 + 0.02 * np.sin(moving)
        self.pitch = 0.015 * np.cos(0.7 * moving)
        vel = speed * (self.t > still)[:, None] * np.stack([np.cos(self.heading), np.sin(self.heading),
                                                             np.zeros(n)], axis=1)
        self.p = np.array([5.0, -3.0, 0.2]) + np.concatenate([[np.zeros(3)], np.cumsum(vel[1:] * dt, axis=0)])
        steps = rng.normal(size=n) * yaw_walk * math.sqrt(dt)
        steps[0] = 0.0
        self.rate = drift_rate + np.cumsum(rng.normal(size=n) * rate_walk * math.sqrt(dt))   # rad/s
        self.dpsi = dpsi0 + np.concatenate([[0.0], np.cumsum(self.rate[:-1] * dt)]) + np.cumsum(steps)
        self.p_odom = np.zeros((n, 3))
        for k in range(1, n):
            walk = rng.normal(size=3) * trans_walk * math.sqrt(dt) * (self.t[k] > still)   # VO drifts when moving
            self.p_odom[k] = self.p_odom[k - 1] + rot_z(-self.dpsi[k]) @ (self.p[k] - self.p[k - 1]) + walk
        self.R = rpy_to_matrix(self.roll, self.pitch, self.heading)
        self.odom_T_base = make_T(rpy_to_matrix(self.roll, self.pitch, self.heading - self.dpsi), self.p_odom)
        self.map_t_odom = self.p - np.einsum("nij,nj->ni", rot_z(self.dpsi), self.p_odom)

    def prism(self, k):
        return self.p[k] + self.R[k] @ PRISM_IN_BASE + SIGMA_PRISM * self.rng.normal(size=3)

    def yaw(self, k):
        return self.heading[k] + SIGMA_YAW * self.rng.normal()

    def run(self, f, yaw_every=2, yaw_gap=(), marker_ids=(3, 5, 8), errors_from=0.0):
        """Feed prism (every step) and yaws (every ``yaw_every`` steps, none inside ``yaw_gap`` (t0, t1));
        return per-step (time, yaw error rad, base position error m) once initialised after ``errors_from``."""
        out = []
        for k, tk in enumerate(self.t):
            f.add_prism(tk, self.prism(k), SIGMA_PRISM, self.odom_T_base[k])
            if k % yaw_every == 0 and not (yaw_gap and yaw_gap[0] <= tk < yaw_gap[1]):
                mid = marker_ids[(k // yaw_every) % len(marker_ids)] if marker_ids else None
                f.add_yaw(tk, self.yaw(k), SIGMA_YAW, self.odom_T_base[k], marker_id=mid)
            if f.initialised and tk >= errors_from:
                T, _ = f.map_T_odom(tk)
                base = T @ self.odom_T_base[k]
                out.append((tk, float(wrap_angle(f.x[0] - self.dpsi[k])), np.linalg.norm(base[:3, 3] - self.p[k])))
        return out

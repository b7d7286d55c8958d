"""Synthetic signals with a known time offset for the timesync tests (built here, not by the package).

The platform drives an ellipse (4 m × 1.5 m half-axes, varying curvature so the turn rate varies)
at 0.2–0.6 m/s; its true heading is the analytic tangent direction. The VO yaw is that heading
+ a constant offset + a drift of 3°/min + 0.2° noise, at 30 fps, stamped on the camera clock =
true time + τ. The prism (no lever arm: it sits on the path) is tracked at ~19 Hz with jittered
stamps, 10 % dropouts and a 1 s gap, with 5 mm noise, stamped in true time.
"""

from __future__ import annotations

import math

import numpy as np

FPS = 30.0
YAW_OFFSET = 1.234  # rad, VO yaw − true heading
A, B = 4.0, 1.5  # m, half-axes of the ellipse
NOISE_YAW = math.radians(0.2)  # rad, VO yaw noise per frame
DRIFT = math.radians(3.0) / 60.0  # rad/s, VO yaw drift


def ellipse_theta(t):
    return 0.15 * t + 0.3 * np.sin(0.2 * t)


def true_position(t):
    th = ellipse_theta(t)
    return np.stack([A * np.cos(th), B * np.sin(th)], axis=-1)


def true_heading(t):
    th = ellipse_theta(t)
    return np.arctan2(B * np.cos(th), -A * np.sin(th))  # d(th)/dt > 0 cancels


def true_speed(t):
    th = ellipse_theta(t)
    dth = 0.15 + 0.06 * np.cos(0.2 * t)
    return dth * np.hypot(A * np.sin(th), B * np.cos(th))


def scenario(tau, seed=0, duration=60.0, noise_xy=0.005, noise_yaw=NOISE_YAW, drift=DRIFT, prism_rate=19.0):
    """(t_vo on the camera clock, yaw_vo, t_prism on the true clock, xy_prism)."""
    rng = np.random.default_rng(seed)
    t_true = np.arange(0.0, duration, 1.0 / FPS)
    yaw = true_heading(t_true) + YAW_OFFSET + drift * t_true + rng.normal(0.0, noise_yaw, len(t_true))
    tp = np.cumsum(rng.uniform(0.8, 1.2, int(duration * prism_rate * 1.3)) / prism_rate) - 2.0
    tp = tp[(tp > -2.0) & (tp < duration + 2.0)]
    keep = (rng.random(len(tp)) > 0.1) & ~((tp > 20.0) & (tp < 21.0))
    tp = tp[keep]
    xy = true_position(tp) + rng.normal(0.0, noise_xy, (len(tp), 2))
    return t_true + tau, np.angle(np.exp(1j * yaw)), tp, xy

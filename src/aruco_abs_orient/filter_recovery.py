"""Recovery and markers-only anchoring of the map→odom filter (doc/design.md §8).

In: the measurements the tracking filter could not use — gated yaws, gated resection poses, yaws and prisms
after ``reinit_after`` s without an accepted one — and, without a prism, the resection poses of the start-up
window. Out: the :class:`.filter_core.KalmanCore` reset when they agree with each other: δψ and ω to the
consensus of gated yaws from ``init_min_markers`` markers over ``lockout_window`` s (lock-out recovery) or of
the re-collected yaws (re-initialisation), the translation to two consecutive prisms that agree or to gated
resection poses that agree (re-anchoring), or the filter started from ``init_min_yaws`` resection poses whose
yaws and translations agree (markers only). The part of the state not reset is kept; a single disagreeing
marker cannot trigger any of them. numpy only, no ROS.
"""

from __future__ import annotations

from typing import List, Tuple

import numpy as np

from .filter_core import KalmanCore, Pose, Prism, UpdateResult, Yaw, result
from .filter_startup import Startup, reset_yaw
from .transforms import rot_z

__all__ = ["Recovery"]


class Recovery:
    """The evidence buffers (gated yaws and poses, start-up poses) and the resets they justify; the yaws and
    prisms re-collected after a gap are the start-up's buffers (``startup.yaws``, ``startup.prisms``)."""

    def __init__(self, core: KalmanCore, startup: Startup):
        self.core = core
        self.startup = startup
        self.gated: List[Yaw] = []                    # recent gated yaws (lock-out detection)
        self.poses: List[Tuple[Yaw, Pose]] = []       # resection poses buffered for a start without prism
        self.gated_poses: List[Pose] = []             # recent poses gated for their position (re-anchoring)

    def reinitialise(self, t: float) -> UpdateResult:
        """After ``reinit_after`` s without an accepted yaw: reset δψ (and ω) to the consensus of recent
        yaws, keeping the robot's map position and its covariance."""
        core, startup = self.core, self.startup
        cons, why = startup.consensus(startup.yaws, core.params.init_min_yaws)
        if cons is None:
            core.stats.waiting_reason = why
            return result("buffered")
        reset_yaw(core, t, cons)
        self.gated = []
        core.stats.reinitialisations += 1
        for y in cons[2]:
            core.count_yaw(True, y.marker_id, y.t)
        startup.yaws, startup.prisms = [], []
        return result("initialised")

    def from_lockout(self, sample: Yaw) -> bool:
        """Note a gated yaw; when the gated yaws of the last ``lockout_window`` s agree with each other
        (from ≥ ``init_min_markers`` markers, over half the window at least), reset δψ and ω to them."""
        p = self.core.params
        self.gated = [y for y in self.gated if y.t >= sample.t - p.lockout_window] + [sample]
        if len(self.gated) < p.lockout_min_yaws or sample.t - self.gated[0].t < 0.5 * p.lockout_window:
            return False
        cons, _ = self.startup.consensus(self.gated, p.lockout_min_yaws, p.init_min_markers)
        if cons is None or cons[2][-1].t - cons[2][0].t < 0.5 * p.lockout_window:
            return False
        reset_yaw(self.core, sample.t, cons)
        self.gated = []
        self.core.stats.lockout_recoveries += 1
        return True

    def reanchor_prism(self, t: float, p: np.ndarray, C: np.ndarray, q: np.ndarray) -> UpdateResult:
        """After ``reinit_after`` s without an accepted prism: two consecutive prisms that agree (χ² gate on
        the implied translations) re-anchor the translation, keeping δψ and its variance."""
        core, startup = self.core, self.startup
        prev = startup.prisms[-1] if startup.prisms else None
        startup.prisms = [Prism(t, p, C, q)]
        if prev is None or abs(t - prev.t) > max(core.params.max_delay, 1.0):
            return result("buffered")
        Rz = rot_z(core.x[0])
        d = (prev.p - Rz @ prev.q) - (p - Rz @ q)
        chi2 = float(d @ np.linalg.solve(prev.cov + C, d))
        if chi2 > core.params.gate_chi2_prism:
            return result("buffered", chi2, d)
        core.reanchor_translation(t, p, C, q)
        startup.prisms = []
        core.stats.prism_reanchors += 1
        core.stats.prism_accepted += 1
        core.stats.last_prism = max(t, core.stats.last_prism)
        core.stats.last_update = max(t, core.stats.last_update)
        return result("initialised", chi2, d)

    def reanchor_from_poses(self, pose: Pose) -> bool:
        """Resection poses whose yaw agrees but whose position is gated: when those of the last
        ``lockout_window`` s (≥ ``lockout_min_yaws``, over half the window) agree with each other, the
        filter's position is what is wrong (a prism-less run that drifted or was moved): re-anchor the
        translation to the newest, keeping δψ and ω."""
        core, p = self.core, self.core.params
        self.gated_poses = [x for x in self.gated_poses if x.t >= pose.t - p.lockout_window] + [pose]
        first = self.gated_poses[0]
        if len(self.gated_poses) < p.lockout_min_yaws or pose.t - first.t < 0.5 * p.lockout_window:
            return False
        Rz = rot_z(core.x[0])
        trans = np.array([x.p - Rz @ x.q for x in self.gated_poses])
        d = trans - trans[-1]
        if any(float(di @ np.linalg.solve(x.cov + pose.cov, di)) > p.gate_chi2_prism
               for di, x in zip(d, self.gated_poses)):
            return False
        core.reanchor_translation(pose.t, pose.p, pose.cov, pose.q)
        self.gated_poses = []
        core.stats.pose_reanchors += 1
        return True

    def initialise_from_poses(self, t: float, sample: Yaw, pose: Pose) -> UpdateResult:
        """Start (or re-start) without a prism: ``init_min_yaws`` buffered resection poses whose yaws agree and
        whose translations map→odom agree (χ² ``gate_chi2_pose`` on the position part)."""
        core, p = self.core, self.core.params
        self.poses = [x for x in self.poses if x[0].t >= t - max(p.standstill_duration, p.max_delay)]
        self.poses.append((sample, pose))
        cons, why = self.startup.consensus([y for y, _ in self.poses], p.init_min_yaws, p.init_min_markers)
        if cons is None:
            core.stats.waiting_reason = "resection poses: " + why
            return result("buffered")
        dpsi, var, used = cons
        members = [ps for y, ps in self.poses if any(y is u for u in used)]
        trans = np.array([m.p - rot_z(dpsi) @ m.q for m in members])
        mid = np.median(trans, axis=0)
        agree = [m for m, tr in zip(members, trans)
                 if float((tr - mid) @ np.linalg.solve(m.cov + 1e-6 * np.eye(3), tr - mid)) <= p.gate_chi2_pose]
        if len(agree) < p.init_min_yaws:
            core.stats.waiting_reason = (f"resection poses: {len(agree)} of {len(members)} agree in position, "
                                         f"{p.init_min_yaws} needed")
            return result("buffered")
        last = max(agree, key=lambda m: m.t)
        keep_position = core.stats.state == "reinitialising"
        core.t = max(core.t, last.t)
        core.anchor(dpsi, var, last.p, last.cov, last.q)
        core.stats.state, core.stats.waiting_reason = "tracking", ""
        core.stats.last_update = core.t
        core.stats.pose_accepted += len(agree)
        for y in used:
            core.count_yaw(True, y.marker_id, y.t)
        if keep_position:
            core.stats.reinitialisations += 1
        self.poses, self.startup.yaws, self.gated = [], [], []
        return result("initialised")

"""A scenario fed to the pipeline without rendering: exact marker bearings (plus noise) in place of
detection, the prism samples as the total station gives them, the VO as odometry.

For tests and benchmarks of what comes after detection (start-up, filter, recovery) over many seeds
and start times, where rendering and detecting every frame would only cost time. Times are the
scenario's true times (the camera clock's offset already removed, as :mod:`offline.process` does).
"""

from __future__ import annotations

import math
from typing import Iterator, Optional, Tuple

import numpy as np

from ..detection import MarkerObservation
from ..pipeline import AbsOrientPipeline, FrameResult
from .scenario import Scenario

__all__ = ["feed"]


def feed(scenario: Scenario, pipeline: AbsOrientPipeline, times: Optional[np.ndarray] = None,
         noise: float = 0.0, rng: Optional[np.random.Generator] = None,
         prism_lead: float = 0.06) -> Iterator[Tuple[float, FrameResult]]:
    """Yield (true time s, FrameResult) for each frame time in ``times`` (default: all the scenario's
    frames): the markers the camera sees then (:meth:`Scenario.marker_bearings`, each bearing perturbed
    by ``noise`` rad per axis, reported with that σ), after the prism samples up to ``prism_lead`` s past
    the frame (the total station's latency) and the IMU samples up to the frame (when the scenario has an
    IMU) were added."""
    times = scenario.frame_times if times is None else np.asarray(times, dtype=float)
    rng = rng if rng is not None else np.random.default_rng(0)
    frame, ids, bearings = scenario.marker_bearings(times, noise=noise, rng=rng)
    sigma = max(float(noise), 1e-5)
    stamps, positions = scenario.prism.stamps, scenario.prism.positions
    j = int(np.searchsorted(stamps, times[0] - 1.0)) if len(times) else 0
    imu_t, imu_rp = scenario.imu_samples()
    imu_sigma = math.radians(scenario.config.imu_tilt_noise_deg)
    k = int(np.searchsorted(imu_t, times[0] - 1.0)) if len(times) else 0
    for i, t in enumerate(times):
        while k < len(imu_t) and imu_t[k] <= t:
            pipeline.add_imu(float(imu_t[k]), float(imu_rp[k, 0]), float(imu_rp[k, 1]), imu_sigma)
            k += 1
        while j < len(stamps) and stamps[j] <= t + prism_lead:
            pipeline.add_prism(float(stamps[j]), positions[j])
            j += 1
        obs = [MarkerObservation(int(ids[k]), np.zeros((4, 3)), bearings[k], (0.0, 0.0), np.zeros((4, 2)),
                                 0.0, sigma, "full") for k in np.nonzero(frame == i)[0]]
        yield float(t), pipeline.process_observations(float(t), obs, scenario.odom_T_base(float(t)))

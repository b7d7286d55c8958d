"""A scenario fed to the pipeline without rendering: exact marker bearings (plus noise) in place of
detection, the prism samples as the total station gives them, the VO as odometry.

For tests and benchmarks of what comes after detection (start-up, filter, recovery, calibration) over
many seeds and start times, where rendering and detecting every frame would only cost time. Times are
the scenario's true times (the camera clock's offset already removed, as :mod:`offline.process` does).

A rolling shutter (``readout`` s): a frame's time is the capture time of its middle row, and a marker on
row v of the H-row image is seen as it was at that time + (v/H − ½)·readout (``pipeline.row_fraction``:
the row from the bearing through ``camera``'s model). Its bearing is solved for that time by fixed-point
iteration (the row depends on the bearing, which depends on the time).
"""

from __future__ import annotations

import math
from typing import Iterator, NamedTuple, Optional, Tuple

import numpy as np

from ..camera import Equirect
from ..detection import MarkerObservation
from ..pipeline import AbsOrientPipeline, FrameResult, row_fraction
from .scenario import Scenario

__all__ = ["FeedObservations", "marker_observations", "feed"]

_ROW_ITERATIONS = 3  # fixed-point steps row ↔ bearing: the row moves by < 0.01 px after the second


class FeedObservations(NamedTuple):
    """Marker observations of frames: ``frame`` (K,) index into the frame times, ``ids`` (K,),
    ``bearings`` (K, 3) unit, camera frame, ``rows`` (K,) their (v/H − ½) (``pipeline.row_fraction``)."""

    frame: np.ndarray
    ids: np.ndarray
    bearings: np.ndarray
    rows: np.ndarray


def marker_observations(scenario: Scenario, times, noise: float = 0.0, rng: Optional[np.random.Generator] = None,
                        readout: float = 0.0) -> FeedObservations:
    """The markers the true camera sees in the frames at true times ``times`` (s; each the capture time of
    the frame's middle row), each bearing taken at its row's capture time (``readout`` s of a rolling
    shutter; 0 = global shutter, :meth:`Scenario.marker_bearings` exactly) and perturbed by ``noise`` rad
    per axis (``rng``)."""
    times = np.atleast_1d(np.asarray(times, dtype=float))
    rng = rng if rng is not None else np.random.default_rng(0)
    height = scenario.config.width // 2
    if readout == 0.0:
        frame, ids, u = scenario.marker_bearings(times, noise=noise, rng=rng)
        return FeedObservations(frame, ids, u, row_fraction(u, height))
    frame, ids, u = scenario.marker_bearings(times)
    for _ in range(_ROW_ITERATIONS):
        t_row = times[frame] + row_fraction(u, height) * readout
        k, ids_row, u_row = scenario.marker_bearings(t_row)
        same = ids_row == ids[k]          # each row time's own marker (others in view are ignored)
        u = u.copy()
        u[k[same]] = u_row[same]          # a marker gone from view at its row time keeps its last bearing
    if noise > 0:
        u = u + rng.normal(0.0, noise, u.shape)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
    return FeedObservations(frame, ids, u, row_fraction(u, height))


def feed(scenario: Scenario, pipeline: AbsOrientPipeline, times: Optional[np.ndarray] = None,
         noise: float = 0.0, rng: Optional[np.random.Generator] = None,
         prism_lead: float = 0.06, readout: float = 0.0) -> Iterator[Tuple[float, FrameResult]]:
    """Yield (true time s, FrameResult) for each frame time in ``times`` (default: all the scenario's
    frames): the markers the camera sees then (:func:`marker_observations`, each bearing perturbed by
    ``noise`` rad per axis, reported with that σ; a rolling shutter of ``readout`` s), after the prism
    samples up to ``prism_lead`` s past the frame (the total station's latency) and the IMU samples up to
    the frame (when the scenario has an IMU) were added."""
    times = scenario.frame_times if times is None else np.asarray(times, dtype=float)
    rng = rng if rng is not None else np.random.default_rng(0)
    obs = marker_observations(scenario, times, noise=noise, rng=rng, readout=readout)
    height = scenario.config.width // 2
    u_px, v_px = Equirect(scenario.config.width, height).bearing_to_pixel(obs.bearings)
    sigma = max(float(noise), 1e-5)
    stamps, positions = scenario.prism.stamps, scenario.prism.positions
    j = int(np.searchsorted(stamps, times[0] - 1.0)) if len(times) else 0
    imu_t, imu_rp = scenario.imu_samples()
    imu_sigma = math.radians(scenario.config.imu_tilt_noise_deg)
    n = int(np.searchsorted(imu_t, times[0] - 1.0)) if len(times) else 0
    for i, t in enumerate(times):
        while n < len(imu_t) and imu_t[n] <= t:
            pipeline.add_imu(float(imu_t[n]), float(imu_rp[n, 0]), float(imu_rp[n, 1]), imu_sigma)
            n += 1
        while j < len(stamps) and stamps[j] <= t + prism_lead:
            pipeline.add_prism(float(stamps[j]), positions[j])
            j += 1
        found = [MarkerObservation(int(obs.ids[k]), np.zeros((4, 3)), obs.bearings[k],
                                   (float(u_px[k]), float(v_px[k])), np.zeros((4, 2)), 0.0, sigma, "full")
                 for k in np.nonzero(obs.frame == i)[0]]
        yield float(t), pipeline.process_observations(float(t), found, scenario.odom_T_base(float(t)),
                                                      image_height=height)

"""Shared by the calibration tests: exactly simulated recordings (the truth they are checked against).

The recordings are built here from known geometry (doc/design.md §1 frames): a non-holonomic platform drives
a loop (base_link x along its velocity), VO gives the tilt exactly and the yaw with an unknown,
drifting map→odom offset, the prism has total-station noise, and every marker within range gives a
bearing through the TRUE mounting (boresight B_true · R_nominal, true lever arm) with detection noise.
The estimator sees only the nominal mounting.
"""

from __future__ import annotations

import math

import numpy as np

from aruco_abs_orient.calibration import Recording, calibrate
from aruco_abs_orient.camera import DualFisheye
from aruco_abs_orient.markers import Marker, MarkerMap
from aruco_abs_orient.synthetic.feed import marker_observations
from aruco_abs_orient.transforms import make_T, rot_z, rpy_to_matrix
from aruco_abs_orient.tum import Trajectory

NOMINAL_CAMERA = make_T(rpy_to_matrix(0.0, 0.0, math.radians(90.0)), [0.10, 0.0, 0.45])
PRISM = make_T(None, [-0.05, 0.0, 0.62])
SIGMA_BEARING = math.radians(0.03)
PRISM_SIGMA = 0.003


def _marker_map() -> MarkerMap:
    rng = np.random.default_rng(7)
    markers = []
    for i, ang in enumerate(np.linspace(0, 2 * math.pi, 10, endpoint=False)):
        r = 7.0 + 2.0 * (i % 3)
        markers.append(Marker(i, np.array([r * math.cos(ang), r * math.sin(ang), 0.8 + rng.uniform(0, 1.5)]),
                              0.19, 0.001))
    return MarkerMap(markers)


def simulate(boresight_rpy=(0.0, 0.0, 0.0), lever_delta=(0.0, 0.0, 0.0), duration=60.0, fps=5.0,
             speed=0.8, drive=True, seed=0, outliers=0, crab_deg=0.0):
    """A recording: (obs_times, ids, bearings, sigmas, odom, prism_t, prism_p, marker map); ``crab_deg``: the
    platform's x axis turned that far from its direction of travel (a crabbing platform)."""
    rng = np.random.default_rng(seed)
    mmap = _marker_map()
    B = rpy_to_matrix(*boresight_rpy)
    R_bc = B @ NOMINAL_CAMERA[:3, :3]
    t_cam = NOMINAL_CAMERA[:3, 3] + np.asarray(lever_delta, dtype=float)
    t_prism = PRISM[:3, 3]

    def pose(t):
        """Ground-truth base_link pose: a rounded-square loop (straights and turns) of radius ~4 m."""
        s = speed * t if drive else 0.0
        # path parametrised by arc length on an ellipse-like curve
        phi = s / 4.0
        x, y = 4.0 * math.cos(phi) + 0.8 * math.cos(3 * phi), 3.0 * math.sin(phi)
        dx = -4.0 * math.sin(phi) - 2.4 * math.sin(3 * phi)
        dy = 3.0 * math.cos(phi)
        yaw = math.atan2(dy, dx) + math.radians(crab_deg) if drive else 0.7   # crab: body x off the travel
        roll = math.radians(1.5) * math.sin(0.7 * t)
        pitch = math.radians(1.0) * math.cos(0.5 * t)
        return np.array([x, y, 0.0]), rpy_to_matrix(roll, pitch, yaw)

    # VO: tilt exact, yaw offset δ(t) = drifting
    def delta(t):
        return 0.4 + math.radians(0.05) * t + math.radians(0.5) * math.sin(t / 17.0)

    tp = np.arange(0.0, duration, 0.05)
    pp = []
    for t in tp:
        p, R = pose(t)
        pp.append(p + R @ t_prism + rng.normal(0, PRISM_SIGMA, 3))
    odom_t = np.arange(0.0, duration, 0.02)
    odom_T = []
    for t in odom_t:
        p, R = pose(t)
        odom_T.append(make_T(rot_z(-delta(t)) @ R, rot_z(-delta(t)) @ p))
    odom = Trajectory.from_transforms(odom_t, np.array(odom_T))
    times, ids, bearings, sigmas = [], [], [], []
    for t in np.arange(1.0, duration - 1.0, 1.0 / fps):
        p, R = pose(t)
        C = p + R @ t_cam
        for m in mmap:
            v = (R @ R_bc).T @ (m.position - C)
            rng_m = np.linalg.norm(v)
            if rng_m > 10.0:
                continue
            u = v / rng_m + rng.normal(0, SIGMA_BEARING, 3)
            times.append(t)
            ids.append(m.id)
            bearings.append(u / np.linalg.norm(u))
            sigmas.append(SIGMA_BEARING)
    bearings = np.array(bearings)
    for k in rng.choice(len(bearings), outliers, replace=False):  # false ids / reflections
        b = rng.normal(size=3)
        bearings[k] = b / np.linalg.norm(b)
    return (np.array(times), np.array(ids), bearings, np.array(sigmas), odom, tp, np.array(pp), mmap)


def run(rec, unknowns=None, params=None):
    """calibrate() of a simulated recording (NOMINAL_CAMERA, PRISM)."""
    return calibrate(Recording(*rec, NOMINAL_CAMERA, PRISM), unknowns, params)


def feed_recording(sc, every: int, noise: float, readout=None, prism_shift: float = 0.0, survey_sigma=None,
                   stitch_distance: float = math.inf):
    """A Recording of ``sc``'s exact bearings (``synthetic.feed``, at their rows' capture times with the
    ``readout`` given, default the scenario's, + ``noise`` rad) in every ``every``-th frame, the VO as the
    generator makes it, the prism track with its stamps moved by ``prism_shift`` s, and the scenario's survey
    of the markers (with its σ, or ``survey_sigma`` m: an exact map surveyed that well); the lenses unknown but
    for the ``stitch_distance`` (m), as the camera's maker states it."""
    readout = sc.config.rolling_shutter_readout if readout is None else readout
    off = sc.config.camera_time_offset
    frames = sc.frame_times[::every]
    ob = marker_observations(sc, frames, noise=noise, rng=np.random.default_rng(sc.config.seed), readout=readout)
    grid = np.arange(sc.frame_times[0], sc.frame_times[-1], 1 / 30)
    survey = sc.surveyed_markers
    if survey_sigma is not None:
        survey = MarkerMap([Marker(m.id, m.position, m.size, survey_sigma) for m in survey], survey.dictionary)
    return Recording(frames[ob.frame] + off, ob.ids, ob.bearings, np.full(len(ob.ids), noise),
                     Trajectory.from_transforms(grid + off, sc.odom_T_base(grid)), sc.prism.stamps + off + prism_shift,
                     sc.prism.positions, survey, sc.base_T_camera_nominal, sc.base_T_prism, ob.rows,
                     DualFisheye(stitch_distance=stitch_distance))

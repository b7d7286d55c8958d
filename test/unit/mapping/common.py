"""Shared by the mapping tests: recordings of synthetic scenarios with exact marker bearings (``synthetic.feed``,
through the calibration tests' :func:`feed_recording`) and their corners, the truth they are checked against."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from aruco_abs_orient.markers import MarkerMap
from aruco_abs_orient.synthetic.scenario import PRESETS, Scenario

from ..calibration.common import feed_recording

#: the detection's centre σ on the realistic world's 3840 px frames (rad)
NOISE = math.radians(0.02)
#: the corner of a marker per unit side in its frame (x right, y up the face), ArUco order
_CORNERS = 0.5 * np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])


def scenario(preset: str = "demo", **changes) -> Scenario:
    return Scenario(dataclasses.replace(PRESETS[preset], **changes))


def recording(sc: Scenario, every: int = 6, noise: float = NOISE, true_mount: bool = True, control=None):
    """(Recording, corners (N, 4, 3)) of ``sc``'s exact bearings in every ``every``-th frame + ``noise`` rad: the
    camera's true lenses and readout, its true mounting (or the nominal one: the boresight unknown), the control
    markers ``control`` (a MarkerMap, default none); the corners at their rows' capture times, + 2·``noise``."""
    rec = feed_recording(sc, every, noise)
    rec = dataclasses.replace(rec, lenses=sc.lenses, marker_map=control if control is not None else MarkerMap([]),
                              base_T_camera=sc.base_T_camera_true if true_mount else sc.base_T_camera_nominal)
    return rec, corner_bearings(sc, rec, noise)


def corner_bearings(sc: Scenario, rec, noise: float) -> np.ndarray:
    """The stitched bearings (N, 4, 3) of the corners of each observation's marker, seen by the true camera at the
    observation's row time, + 2·``noise`` rad per axis."""
    t = np.asarray(rec.obs_times) - sc.config.camera_time_offset + rec.obs_rows * sc.config.rolling_shutter_readout
    T = sc.map_T_camera(t)
    rng = np.random.default_rng(sc.config.seed + 1)
    out = np.empty((len(t), 4, 3))
    for n, mid in enumerate(np.asarray(rec.obs_ids, dtype=int)):
        m = sc.markers[int(mid)]
        R = sc.map_R_marker(int(mid))
        points = m.position + m.size * (_CORNERS[:, :1] * R[:, 0] + _CORNERS[:, 1:] * R[:, 1])
        out[n] = sc.lenses.project((points - T[n, :3, 3]) @ T[n, :3, :3])
    out += rng.normal(0.0, 2.0 * noise, out.shape)
    return out / np.linalg.norm(out, axis=2, keepdims=True)


def errors(result, sc: Scenario):
    """Per mapped marker id: (|error| m, normalised error √(eᵀC⁻¹e), baseline m)."""
    out = {}
    for m in result.with_status("mapped"):
        e = m.position - sc.markers[m.id].position
        out[m.id] = (float(np.linalg.norm(e)), float(math.sqrt(e @ np.linalg.solve(m.cov, e))), m.baseline)
    return out

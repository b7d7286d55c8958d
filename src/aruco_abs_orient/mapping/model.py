"""What the marker mapping takes and gives: its error, its knobs, which camera parameters it frees, its result.

In: nothing (types only). Out: :class:`MappingError`, :class:`MappingParams` (the knobs of
:func:`~aruco_abs_orient.mapping.map_markers`: when a marker is seen enough, the tests of a marker and of a
control marker against the others; cfg/params.yaml's ``mapping`` section), :class:`MapUnknowns` (which camera
parameters the network estimates beside the markers and the heading), :class:`MappedMarker` (one marker: its
centre with its covariance, face normal with its σ, how it was seen, its test, and why it is left out when it
is) and :class:`MappingResult`.

Units: metres, radians, seconds inside; the report functions give millimetres and degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from ..errors import GeometryError
from ..paramspec import Params, param

__all__ = ["MappingError", "MappingParams", "MapUnknowns", "MappedMarker", "MappingResult", "chi2_quantile",
           "format_xyz"]


class MappingError(GeometryError):
    """The recording cannot place the markers, or the inputs are malformed; the message says why and what to do."""


@dataclass(frozen=True)
class MappingParams(Params):
    """Knobs of :func:`~aruco_abs_orient.mapping.map_markers` (cfg/params.yaml's ``mapping`` section; the
    network's own model, its knots and gates, is the ``calibration`` section's). A marker beyond ``loose_sigma``
    is placed with a warning (``process`` and the node weigh it by its σ: a far marker placed to a few cm still
    holds the heading where it is the only one in view); ``bias_deg`` is the error all sightings of a marker have
    in common (the camera's distortion and stitching, the print, its lighting, the corner fit), added to its
    covariance: no number of sightings averages it away."""

    error = MappingError

    min_views: int = param(10, "a marker seen in fewer images is refused (not placed), with what to drive", "", 1)
    moved_share: float = param(0.02, "a marker is taken to have moved (or to share its id) only when this share of "
                               "its sightings (and min_views) meet at a second place: a long recording's tail beyond "
                               "the gate is not a second marker", "", 0.0, 1.0)
    min_baseline: float = param(1.0, "a marker seen only from camera positions closer together than this is "
                                "refused", "m", 0.0)
    max_sigma: float = param(0.05, "a marker whose position 1-σ along its worst axis exceeds this is refused", "m",
                             above=0.0)
    loose_sigma: float = param(0.005, "a marker placed looser than this (1-σ, worst axis) is kept with a warning",
                               "m", above=0.0)
    max_normal_sigma_deg: float = param(5.0, "a face normal whose 1-σ exceeds this is not written (the marker is)",
                                        "deg", above=0.0)
    pattern_fit: bool = param(True, "the map's detections fit each small marker's whole pattern (detection."
                              "pattern_fit, off in the live pipeline): the edge fit's bias, the same on every frame, "
                              "would move a marker 8-13 m away by several mm")
    drift_walk_estimated: bool = param(True, "the network's map→odom yaw δ(t) a random walk about a free rate, the "
                                       "walk's size estimated from the recording (calibration.drift_walk_estimated,"
                                       " off in calibrate): a far marker seen alone no longer turns δ freely")
    bias_deg: float = param(0.01, "the error all sightings of a marker have in common, 1-σ per image axis", "deg",
                            0.0)
    test_alpha: float = param(0.001, "false-alarm rate of the test of each marker (and control marker) against "
                              "the others", "", above=0.0, below=1.0)
    noise_spread: float = param(2.0, "factor by which one marker's bearing variance may differ from the network's "
                                "before its test counts it as disagreeing (× the χ² quantile)", "", above=0.0)
    compare_alpha: float = param(0.001, "--compare's false-alarm rate per marker (χ² of its move, 3 degrees of "
                                 "freedom)", "", above=0.0, below=1.0)


class MapUnknowns(NamedTuple):
    """Which camera parameters the network estimates beside the markers, the map→odom yaw and the odometry's
    tilt: the boresight (roll, pitch, yaw), the rolling-shutter readout, the residual time offset, the two lenses'
    offset and relative rotation. Those left fixed are the calibration's (or the nominal ones)."""

    boresight: bool = False
    readout: bool = False
    time_offset: bool = False
    lenses: bool = False

    def free(self) -> Tuple[int, ...]:
        """Indices of the free globals in the calibration's vector x (``calibration.model.N_GLOBALS``)."""
        return (((0, 1, 2) if self.boresight else ()) + ((6,) if self.time_offset else ())
                + ((7,) if self.readout else ()) + ((8, 9, 10, 11) if self.lenses else ()))


@dataclass
class MappedMarker:
    """One marker of the recording.

    - ``id``; ``position`` (3,) m in map and its covariance ``cov`` (3, 3) m² (the residuals' correlation in
      time included); ``normal`` (3,) unit out of the face, or None (no corners, or too loose), and its 1-σ
      ``normal_sigma`` (rad, the larger of its two tilts);
    - ``views``: images it was used in; ``baseline`` (m): the largest distance between two camera positions it was
      seen from; ``ranges`` (min, max) m; ``redundancy``: the redundancy numbers of its observations summed (how
      many of them are spare); ``test``: its residuals' square sum over their redundancy (about 1 when it agrees
      with the others), ``test_limit`` the value it was held to; ``outliers``: its observations beyond the gate;
      ``rms`` (rad): the RMS angle of its residuals; ``cov`` is scaled by ``test`` where it exceeds 1 and holds
      its sightings' common error (``MappingParams.bias_deg``);
    - ``control``: None, or (its surveyed position (3,), the normalised difference of the network's estimate from
      it, √χ² of 3 degrees of freedom, and whether it tied the network);
    - ``status``: "mapped", "refused" (seen too little) or "left out" (disagrees); ``reason``: why, and what to do.
    """

    id: int
    position: np.ndarray
    cov: np.ndarray
    normal: Optional[np.ndarray] = None
    normal_sigma: float = float("nan")
    views: int = 0
    baseline: float = 0.0
    ranges: Tuple[float, float] = (float("nan"), float("nan"))
    redundancy: float = 0.0
    test: float = float("nan")
    test_limit: float = float("nan")
    outliers: int = 0
    rms: float = float("nan")
    control: Optional[Tuple[np.ndarray, float, bool]] = None
    status: str = "mapped"
    reason: str = ""

    @property
    def sigma(self) -> np.ndarray:
        """1-σ (3,) m along map x, y, z."""
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def ellipsoid(self, k: float = 3.0) -> Tuple[np.ndarray, np.ndarray]:
        """The k-σ ellipsoid: semi-axes (3,) m, largest first, and their unit directions (3, 3) as rows."""
        w, v = np.linalg.eigh(0.5 * (self.cov + self.cov.T))
        order = np.argsort(w)[::-1]
        return k * np.sqrt(np.maximum(w[order], 0.0)), v[:, order].T


@dataclass
class MappingResult:
    """What :func:`~aruco_abs_orient.mapping.map_markers` found.

    - ``markers``: every marker id seen (:class:`MappedMarker`), by id; those with status "mapped" are the map.
    - ``boresight`` (3,) rad (roll, pitch, yaw on top of the mounting given) and ``boresight_sigma`` (3,) rad (NaN
      when fixed); ``readout`` (s, the one used: estimated or given) and ``readout_sigma``; ``time_offset_delta``
      (s, added to the offset given) and ``time_offset_sigma``; ``lenses`` (the camera's lenses used).
    - ``variance_factors`` (the network's groups, as the calibration's), ``heading_model`` used.
    - ``yaw_drift`` (rad/s) the map→odom yaw's mean rate over the recording (the VO's yaw drift, sign flipped) and
      ``yaw_walk`` (rad/√s) its walk about that rate as estimated (NaN when not estimated:
      ``drift_walk_estimated`` off, or too short a recording).
    - counts: ``n_observations`` given, ``n_used`` in the network, ``skipped`` reason → count.
    - ``drive`` (T, 3) m: the camera's positions in map along the recording (for the report's plan).
    - ``warnings``: one line each.
    """

    markers: Dict[int, MappedMarker]
    boresight: np.ndarray
    boresight_sigma: np.ndarray
    readout: float
    readout_sigma: float
    time_offset_delta: float
    time_offset_sigma: float
    lenses: object
    variance_factors: Dict[str, float]
    heading_model: str
    n_observations: int
    n_used: int
    yaw_drift: float = float("nan")
    yaw_walk: float = float("nan")
    skipped: Dict[str, int] = field(default_factory=dict)
    drive: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    warnings: List[str] = field(default_factory=list)

    def with_status(self, status: str) -> List[MappedMarker]:
        """The markers of one status, by id."""
        return [m for _, m in sorted(self.markers.items()) if m.status == status]


def chi2_quantile(dof: float, alpha: float) -> float:
    """The (1 − ``alpha``) quantile of χ² with ``dof`` (> 0, real) degrees of freedom (Wilson–Hilferty: 3 % high at
    1 degree of freedom and α = 0.001, within 2 % from 3, within 0.2 % from 10)."""
    z = _normal_quantile(1.0 - alpha)
    h = 2.0 / (9.0 * dof)
    return dof * max(1.0 - h + z * math.sqrt(h), 0.0) ** 3


def _normal_quantile(p: float) -> float:
    """Φ⁻¹(p) by bisection on math.erf (no scipy on the robots' Python)."""
    lo, hi = -10.0, 10.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if 0.5 * (1.0 + math.erf(mid / math.sqrt(2.0))) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def format_xyz(p, digits: int = 3) -> str:
    """A point (3,) m as ``[x, y, z]`` with ``digits`` decimals."""
    return "[" + ", ".join(f"{float(v):.{digits}f}" for v in p) + "]"

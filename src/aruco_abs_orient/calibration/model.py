"""What the calibration takes and gives: its error, its knobs, the recording it reads and its result.

In: nothing (types only). Out: :class:`CalibrationError`, :class:`CalibrationParams` (the knobs of
:func:`~aruco_abs_orient.calibration.calibrate`), :class:`Recording` (the observations, odometry,
prism track, marker map, nominal lever arms and nominal camera lenses of one recording, on one clock),
:class:`Unknowns` (which parameters beside the boresight are estimated) and :class:`Calibration` (the
estimate with its σ, residuals, the platform model it chose and counts; degrees and millimetres in
:meth:`Calibration.report_dict`).

Units: metres, radians, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from ..camera import SINGLE_CENTRE, DualFisheye
from ..errors import GeometryError
from ..markers import MarkerMap
from ..paramspec import Params, param
from ..pipeline import PipelineParams
from ..transforms import make_T, rpy_to_matrix
from ..tum import Trajectory

__all__ = ["CalibrationError", "CalibrationParams", "Calibration", "Recording", "Unknowns", "N_GLOBALS",
           "HEADING_MODELS"]

#: length of the vector of named global unknowns x = (roll, pitch, yaw, Δl_x, Δl_y, Δl_z, Δτ, Δρ, Δo, ε_x, ε_y,
#: ε_z): boresight (rad), lever arm (m), time offset (s), readout (s), lens offset (m), the back lens's rotation
#: relative to the front one (rad, a rotation vector)
N_GLOBALS = 12

#: how the track heading measures the map→odom yaw: "auto" (chosen by the data, see ``solve``), "vo_yaw" (against
#: the VO's yaw: base_link x is the direction of travel) or "vo_track" (against the VO's own direction of travel)
HEADING_MODELS = ("auto", "vo_yaw", "vo_track")


class CalibrationError(GeometryError):
    """The recording cannot determine the calibration, or the inputs are malformed; the message says why."""


@dataclass
class CalibrationParams(Params):
    """Knobs of :func:`calibrate` (cfg/params.yaml's ``calibration`` section). Every number is positive. The
    lens priors keep a recording that says little about the lenses near the nominal ones with that σ in the
    boresight's. ``heading_model`` auto fits both models and keeps the VO's yaw unless the two boresight yaws
    differ by more than their difference's σ allows (a Hausman test at ``crab_test_chi2``) or the direction of
    travel is the more precise. With ``vo_tilt`` the odometry's tilt error (its odom frame tilted against
    gravity: a VO without gravity starts at the platform's tilt, and drifts) is a piecewise-linear rotation about
    map's x and y with knots every ``tilt_knot_spacing``, each tied to 0 by ``tilt_sigma_deg`` and to its
    neighbour by ``tilt_drift_sigma_deg``; without it, one constant tilt error."""

    error = CalibrationError

    knot_spacing: float = param(1.0, "spacing of the knots of the piecewise-linear map→odom yaw δ(t)", "s",
                                above=0.0)
    drift_sigma_deg: float = param(1.0, "1-σ of the change of δ between adjacent knots (a weak prior)", "deg",
                                   above=0.0)
    drift_walk_estimated: bool = param(False, "δ(t) a random walk about a free constant rate, the walk's size "
                                       "estimated from the recording (a variance component, drift_sigma_deg its "
                                       "start); off: drift_sigma_deg a fixed prior on δ's change")
    heading_smooth: float = param(0.25, "σ of the local quadratic fit of the prism track (heading_from_track)", "s",
                                  above=0.0)
    heading_step: float = param(0.25, "spacing of the heading constraints", "s", above=0.0)
    min_speed: float = param(0.2, "slowest speed whose track heading is used", "m/s", above=0.0)
    max_turn_rate_deg: float = param(30.0, "fastest yaw rate whose track heading is used", "deg/s", above=0.0)
    velocity_sigma: float = param(0.01, "a-priori velocity noise of the track: heading σ = it / speed, rescaled by "
                                  "the estimated variance factor", "m/s", above=0.0)
    min_moving_time: float = param(5.0, "least usable driving time to separate the boresight yaw", "s", above=0.0)
    prism_max_gap: float = param(PipelineParams.prism_max_gap, "largest gap between the prism fixes around an "
                                 "observation", "s", above=0.0)
    prism_sigma: float = param(PipelineParams.prism_sigma, "1-σ per axis of a prism position; enters each bearing "
                               "as σ / range", "m", above=0.0)
    pattern_bias_px: float = param(0.1, "1-σ per axis of a marker centre's bias that its pattern sets (the same on "
                                   "every frame) where its cells are pattern_bias_cell_px wide; ∝ 1/cell³, and "
                                   "along a marker's long edges × (their length over its short ones)^1.5 "
                                   "(seen obliquely); in the σ only", "px", 0.0)
    pattern_bias_cell_px: float = param(1.8, "the cell width of pattern_bias_px", "px", above=0.0)
    min_observations: int = param(20, "least usable observations", "", above=0)
    min_markers: int = param(2, "least distinct marker ids", "", above=0)
    loss_scale: float = param(2.0, "Cauchy scale of the robust stage", "σ", above=0.0)
    outlier_gate: float = param(4.0, "normalised residual beyond which an observation is dropped before the "
                                "least-squares stage", "σ", above=0.0)
    max_boresight_sigma_deg: float = param(0.1, "a boresight angle with a larger 1-σ is not determined "
                                           "(CalibrationError)", "deg", above=0.0)
    max_lever_sigma: float = param(0.02, "a lever-arm axis with a larger 1-σ is not determined", "m", above=0.0)
    max_time_offset_sigma: float = param(0.005, "a time offset with a larger 1-σ is not determined", "s",
                                         above=0.0)
    max_readout_sigma: float = param(0.005, "a rolling-shutter readout time with a larger 1-σ is not determined",
                                     "s", above=0.0)
    lens_offset_prior: float = param(0.01, "1-σ of the lens offset around the nominal one (what a camera of the "
                                     "kind may differ from its table value)", "m", above=0.0)
    lens_rotation_prior_deg: float = param(0.2, "1-σ of each component of the lenses' relative rotation around "
                                           "the nominal", "deg", above=0.0)
    max_lens_offset_sigma: float = param(0.002, "above this the lens offset is reported as loosely determined (a "
                                         "warning saying what to drive), not refused", "m", above=0.0)
    max_lens_rotation_sigma_deg: float = param(0.05, "the same for the lenses' relative rotation", "deg", above=0.0)
    max_iterations: int = param(30, "Gauss-Newton iterations per stage", "", above=0)
    clock_tolerance: float = param(2e-4, "Δτ and Δρ are linearised: calibrate (and map's network) solves again "
                                   "with the clocks moved by them until both are below this", "s", above=0.0)
    heading_model: str = param("auto", "how the prism track's heading measures the map→odom yaw: against the VO's "
                               "yaw (precise; a platform that crabs biases it), its direction of travel (any "
                               "platform; noisy when its translation is), or auto", choices=HEADING_MODELS)
    crab_test_chi2: float = param(6.63, "the Hausman test's threshold of auto", "χ², 1 dof", above=0.0)
    odom_levelled: bool = param(False, "the odometry's tilt is gravity's at the start (wheel odometry with an "
                                "IMU): its tilt error starts at 0; otherwise it is estimated, told apart from the "
                                "camera's roll and pitch by the platform's turns")
    vo_tilt: bool = param(True, "the odometry's tilt error drifts (see the class doc)")
    tilt_knot_spacing: float = param(10.0, "spacing of the knots of the odometry's tilt error", "s", above=0.0)
    tilt_sigma_deg: float = param(2.0, "1-σ tying each knot of the tilt error to 0", "deg", above=0.0)
    tilt_drift_sigma_deg: float = param(0.3, "1-σ tying each knot of the tilt error to its neighbour", "deg",
                                        above=0.0)


@dataclass
class Calibration:
    """A boresight / lever-arm calibration and how well the recording determined it.

    - ``boresight_rpy`` (3,) rad: roll, pitch, yaw of B (``R_bc = B · R_bc_nominal``, in base_link);
      ``boresight_sigma`` (3,) rad, 1-σ.
    - ``lever_arm_delta`` (3,) m: correction of the camera origin in base_link (zero when not estimated);
      ``lever_arm_sigma`` (3,) m (NaN when not estimated); ``lever_arm_estimated``.
    - ``cov``: covariance of (roll, pitch, yaw[, Δx, Δy, Δz][, Δτ]) in rad², m², s² (the ones estimated).
    - ``residual_rms_before`` / ``residual_rms_after`` (rad): RMS angle between observed and predicted
      bearings with the nominal and with the calibrated transform (δ(t) fitted in both), over the
      observations kept; ``residual_median_before`` / ``_after`` likewise (rad).
    - ``heading_rms`` (rad): RMS of the track-heading residuals kept.
    - ``variance_factors``: a-posteriori variance factors of the groups ('markers', 'heading'), and the
      inflation of their variances for the residuals' correlation in time ('markers_correlation',
      'heading_correlation', ≥ 1: ``variance.correlation_factor``), included in ``cov`` and the σ.
    - counts: ``n_observations`` given, ``n_used`` kept, ``n_markers`` distinct ids kept, ``n_heading``
      heading constraints kept, ``moving_time`` (s) they cover, ``skipped`` reason → count.
    - ``used`` (N,) bool over the input observations; ``residuals_before`` / ``residuals_after`` (N,)
      rad (NaN where unusable).
    - ``time_offset_delta`` (s): the residual time offset found (0 when not estimated): the camera
      stamps are total-station time + (the offset given + it); ``time_offset_sigma`` (s, NaN when not
      estimated); ``time_offset_estimated``.
    - ``readout`` (s): the rolling-shutter readout time used (estimated, or the one given; 0 = global
      shutter): row v of an H-row image is captured at the frame stamp + (v/H − ½)·readout;
      ``readout_sigma`` (s, NaN when not estimated); ``readout_estimated``.
    - ``lenses``: the camera's two lenses (``camera.DualFisheye``), the nominal ones with the estimated lens
      offset and relative rotation when ``lenses_estimated``; ``lens_offset_sigma`` (m) and
      ``lens_rotation_sigma`` (3,) rad (NaN when not estimated).
    - ``lens_yaw_sigma`` (2,) rad: the 1-σ of each lens's own yaw (front, back: the boresight yaw ∓ half the
      relative rotation about z), what a marker's heading through that lens rests on; ``lens_observations``
      (2,): the observations kept that each lens saw. A lens that saw few markers is known only as well as
      the lenses' prior allows.
    - ``odom_tilt`` (2,) rad and ``odom_tilt_sigma`` (2,): the odometry's tilt error at the first observation
      (about map x, y: the odom frame's tilt against gravity; 0 with ``odom_levelled``).
    - ``heading_model`` ("vo_yaw" or "vo_track") and ``heading_model_reason``: the platform model the track
      headings were taken with and why (``CalibrationParams.heading_model``).
    - ``marker_offsets``: id → (offset (3,) m, its 1-σ (3,) m): where the observations put each marker
      against its surveyed position (the survey's error, fitted as a random effect of σ ``marker.sigma``
      scaled by the variance factor 'marker_positions').
    - ``warnings``: what the recording determined only loosely (one line each, with what to record).
    """

    boresight_rpy: np.ndarray
    boresight_sigma: np.ndarray
    lever_arm_delta: np.ndarray
    lever_arm_sigma: np.ndarray
    lever_arm_estimated: bool
    cov: np.ndarray
    residual_rms_before: float
    residual_rms_after: float
    residual_median_before: float
    residual_median_after: float
    heading_rms: float
    variance_factors: Dict[str, float]
    n_observations: int
    n_used: int
    n_markers: int
    n_heading: int
    moving_time: float
    iterations: int
    used: np.ndarray
    residuals_before: np.ndarray
    residuals_after: np.ndarray
    skipped: Dict[str, int] = field(default_factory=dict)
    time_offset_delta: float = 0.0
    time_offset_sigma: float = float("nan")
    time_offset_estimated: bool = False
    readout: float = 0.0
    readout_sigma: float = float("nan")
    readout_estimated: bool = False
    lenses: DualFisheye = SINGLE_CENTRE
    lens_offset_sigma: float = float("nan")
    lens_rotation_sigma: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    lenses_estimated: bool = False
    lens_yaw_sigma: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    lens_observations: np.ndarray = field(default_factory=lambda: np.zeros(2, dtype=int))
    odom_tilt: np.ndarray = field(default_factory=lambda: np.zeros(2))
    odom_tilt_sigma: np.ndarray = field(default_factory=lambda: np.zeros(2))
    heading_model: str = "vo_yaw"
    heading_model_reason: str = ""
    marker_offsets: Dict[int, Tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)

    @property
    def boresight_matrix(self) -> np.ndarray:
        """B (3×3), the rotation in base_link applied on top of the nominal camera mounting."""
        return rpy_to_matrix(*self.boresight_rpy)

    def apply(self, base_T_camera_nominal) -> np.ndarray:
        """The calibrated base_T_camera (4×4) from the nominal one."""
        T = np.asarray(base_T_camera_nominal, dtype=float)
        return make_T(self.boresight_matrix @ T[:3, :3], T[:3, 3] + self.lever_arm_delta)

    def report_dict(self) -> dict:
        """The calibration for a report: degrees, millimetres, counts."""
        deg = [round(math.degrees(float(x)), 5) for x in self.boresight_rpy]
        out = {
            "boresight_rpy_deg": deg,
            "boresight_sigma_deg": [round(math.degrees(float(x)), 5) for x in self.boresight_sigma],
            "lever_arm_estimated": self.lever_arm_estimated,
            "residual_rms_before_deg": math.degrees(self.residual_rms_before),
            "residual_rms_after_deg": math.degrees(self.residual_rms_after),
            "residual_median_before_deg": math.degrees(self.residual_median_before),
            "residual_median_after_deg": math.degrees(self.residual_median_after),
            "heading_rms_deg": math.degrees(self.heading_rms),
            "variance_factors": dict(self.variance_factors),
            "observations": self.n_observations,
            "observations_used": self.n_used,
            "markers": self.n_markers,
            "heading_constraints": self.n_heading,
            "moving_time_s": self.moving_time,
            "iterations": self.iterations,
            "skipped": dict(self.skipped),
            "heading_model": self.heading_model,
            "heading_model_reason": self.heading_model_reason,
            "odom_tilt_deg": [round(math.degrees(float(x)), 5) for x in self.odom_tilt],
            "odom_tilt_sigma_deg": [round(math.degrees(float(x)), 5) for x in self.odom_tilt_sigma],
            "marker_offsets_mm": {int(k): [round(1e3 * float(x), 2) for x in v[0]]
                                  for k, v in sorted(self.marker_offsets.items())},
        }
        if self.lenses_estimated:
            out["lens_offset_mm"] = round(1e3 * self.lenses.lens_offset, 3)
            out["lens_offset_sigma_mm"] = round(1e3 * self.lens_offset_sigma, 3)
            out["lens_rotation_deg"] = [round(math.degrees(float(x)), 5) for x in self.lenses.lens_rotation]
            out["lens_rotation_sigma_deg"] = [round(math.degrees(float(x)), 5) for x in self.lens_rotation_sigma]
        out["lens_yaw_sigma_deg"] = [round(math.degrees(float(x)), 5) for x in self.lens_yaw_sigma]
        out["lens_observations"] = [int(x) for x in self.lens_observations]
        if self.time_offset_estimated:
            out["time_offset_delta_ms"] = round(1e3 * self.time_offset_delta, 3)
            out["time_offset_sigma_ms"] = round(1e3 * self.time_offset_sigma, 3)
        if self.readout_estimated:
            out["readout_ms"] = round(1e3 * self.readout, 3)
            out["readout_sigma_ms"] = round(1e3 * self.readout_sigma, 3)
        if self.lever_arm_estimated:
            out["lever_arm_delta_mm"] = [round(1e3 * float(x), 3) for x in self.lever_arm_delta]
            out["lever_arm_sigma_mm"] = [round(1e3 * float(x), 3) for x in self.lever_arm_sigma]
        return out


@dataclass
class Recording:
    """One recording's inputs to the calibration, everything on ONE clock (the camera/VO clock).

    - ``obs_times`` (N,) s: the frame stamp of each marker observation; ``obs_ids`` (N,) marker ids;
      ``bearings`` (N, 3) marker-centre bearings in the camera frame; ``sigmas`` (N,) rad, their 1-σ
      per perpendicular axis.
    - ``odom``: odom_T_base_link over time (tilt and relative yaw).
    - ``prism_times`` (K,) s, ``prism_positions`` (K, 3) m in map: the prism track (total-station
      stamps + the time offset).
    - ``marker_map``: the surveyed markers; ``base_T_camera`` (nominal) and ``base_T_prism``: 4×4.
    - ``obs_rows`` (N,): (v/H − ½) of each observation's image row (``pipeline.row_fraction``; None:
      all 0, the middle row); with a rolling-shutter readout ρ an observation is captured at
      ``obs_times + obs_rows · ρ``.
    - ``lenses``: the camera's lenses as known before (``camera.DualFisheye``; the single centre by default):
      the start of their estimate, or fixed.
    - ``cell_px`` (N, 2): the width of each observed marker's cells in image pixels along the azimuth and the
      elevation ((N,): the same along both), and ``pixel_pitch`` (rad per pixel) of the image: the markers'
      pattern bias in the σ (``bias``); None: not taken into account.
    """

    obs_times: np.ndarray
    obs_ids: np.ndarray
    bearings: np.ndarray
    sigmas: np.ndarray
    odom: Trajectory
    prism_times: np.ndarray
    prism_positions: np.ndarray
    marker_map: MarkerMap
    base_T_camera: np.ndarray
    base_T_prism: np.ndarray
    obs_rows: Optional[np.ndarray] = None
    lenses: DualFisheye = SINGLE_CENTRE
    cell_px: Optional[np.ndarray] = None
    pixel_pitch: float = float("nan")


class Unknowns(NamedTuple):
    """Which parameters beside the boresight (roll, pitch, yaw) are estimated: the camera's lever arm, the
    residual time offset, the rolling-shutter readout, the two lenses' offset and relative rotation."""

    lever_arm: bool = False
    time_offset: bool = False
    readout: bool = False
    lenses: bool = False

    def free(self) -> Tuple[int, ...]:
        """Indices of the free globals in x (``N_GLOBALS``)."""
        return ((0, 1, 2) + ((3, 4, 5) if self.lever_arm else ()) + ((6,) if self.time_offset else ())
                + ((7,) if self.readout else ()) + ((8, 9, 10, 11) if self.lenses else ()))

"""The per-frame core shared by the offline bag tool and the ROS node (doc/design.md §4).

``AbsOrientPipeline.process_image`` takes one 360° image with its time (total-station/ROS time:
the camera clock's offset already removed) and the odometry pose ``odom_T_base`` at that time, and
returns a :class:`FrameResult`: the marker observations with the absolute yaw each gives, the
filtered absolute attitude and pose of base_link, and ``map_T_odom`` with covariances. Prism
positions are fed as they arrive (``add_prism``). Here: the parameters, the inputs, detection and the
filter's output; the per-frame solve and its gates are ``framesolve.py``'s (:class:`FrameSolver`, mixed in),
the prism history ``prismbuffer.py``'s. Nothing here imports rospy; Python 3.8.

Rolling shutter (the camera driver's stamp convention): an image's stamp is the capture time of its
MIDDLE row, and row v of an H-row image is captured at stamp + (v/H − ½)·readout. With a ``readout``
(s, from the calibration file; 0 = a global shutter) each marker observation gets its row's capture
time: the prism is interpolated and the tilt taken at that time, and its yaw is referred back to the
frame stamp with the odometry's yaw rate before fusion and the filter (:func:`row_fraction`).

Units: seconds, metres, radians. Covariances: rad² and m².
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from .camera import DualFisheye, Equirect
from .correction import FilterParams, MapOdomFilter
from .detection import DetectionError, DetectorParams, MarkerObservation, frame_to_grey
from .errors import ConfigurationError
from .framesolve import FrameResult, FrameSolver, ObservationResult
from .markers import MarkerMap
from .paramspec import Params, param
from .prismbuffer import PrismBuffer
from .solver import FitSettings
from .tilt import TiltEstimator, TiltParams
from .tracking import MarkerTracker, TrackingParams
from .transforms import matrix_to_rpy, rpy_to_matrix, wrap_angle, yaw_of

__all__ = ["PipelineParams", "AbsOrientPipeline", "FrameResult", "ObservationResult", "PipelineError",
           "PrismBuffer", "all_param_fields", "row_fraction", "PARAM_GROUPS"]

#: longest gap (s) between two frames' odometry poses whose difference gives the rates that move the tilt
#: and yaw to an observation's row time; beyond it the rates are taken as zero
ODOM_RATE_MAX_GAP = 0.5


def row_fraction(bearings, height: int) -> np.ndarray:
    """(v/H − ½) of the image row v each camera-frame bearing (…, 3) falls on in an equirect image of
    ``height`` rows (``camera.Equirect``'s convention): row v is captured at the frame stamp + this ·
    the readout time (−½ top row, 0 the middle, +½ the bottom)."""
    h = int(height)
    if h < 1:
        raise PipelineError(f"image height: expected a positive number of rows, got {height!r}")
    _, v = Equirect(2 * h, h).bearing_to_pixel(np.asarray(bearings, dtype=float))
    return v / h - 0.5


class PipelineError(ConfigurationError):
    """Bad pipeline configuration (lever arms, parameters): names the field."""


@dataclass
class PipelineParams(Params):
    """Knobs of the pipeline itself (cfg/params.yaml's ``pipeline`` section; detection, tracking, the filter, the
    tilt and the multi-marker fits have their own). ``tilt_from_markers`` is off by default because the markers
    measure the CAMERA's attitude: an uncalibrated camera roll or pitch would be taken for a platform tilt (and
    the self-check could no longer see it); with a calibration file the markers correct the tilt whatever it
    says, and an IMU wins over both. The lens fields describe the camera without a calibration file
    (``camera.DualFisheye``); a calibration file's ``camera_lenses`` replace them."""

    error = PipelineError

    prism_sigma: float = param(0.005, "1-σ per axis of a total-station prism position that comes without its own "
                               "covariance", "m", 0.0, 0.2)
    prism_max_gap: float = param(0.5, "largest gap between the two prism samples around an image for "
                                 "interpolation; beyond it the frame gives no absolute yaw (counted)", "s", 0.0, 5.0)
    prism_max_extrapolation: float = param(0.15, "how far past the newest prism sample an image may lie (live, "
                                           "the prism arrives a little after the image)", "s", 0.0, 2.0)
    tilt_sigma_deg: float = param(0.2, "1-σ of roll and of pitch from the odometry", "deg", 0.0, 10.0)
    lever_sigma: float = param(0.002, "1-σ per axis of the camera–prism lever arm", "m", 0.0, 0.1)
    min_range: float = param(0.5, "nearest usable marker", "m", 0.0, 20.0)
    elevation_gate: float = param(5.0, "a marker whose observed elevation disagrees with the map, prism and tilt "
                                  "by more than this is rejected before the filter (a wrong id, a moved marker)",
                                  "σ", 0.0, 100.0)
    fusion_gate: float = param(4.0, "a marker whose yaw disagrees with the frame's other markers by more than this "
                               "is left out of the frame's fused yaw", "σ", 0.0, 100.0)
    init_search_interval: int = param(1, "before the filter is initialised (every search a full-frame one), "
                                      "search only every n-th image (1: every image, so that a node started while "
                                      "driving keeps the frames that start it)", "frames", 1, 100)
    jpeg_reduce: int = param(1, "decode JPEGs at 1/n resolution (accuracy falls with it: bench/detection.py)", "",
                             choices=(1, 2, 4, 8))
    markers_only: bool = param(False, "ignore the prism: every frame's pose from a resection on its markers (≥ 3, or "
                               "≥ 2 with the tilt); without it only frames without a prism position are resected")
    resection_min_cone_deg: float = param(10.0, "a resection whose markers all lie within this angle of each other, "
                                          "seen from the camera, is refused", "deg", 0.0, 90.0)
    attitude_min_spread_deg: float = param(20.0, "with the prism, a frame whose markers span at least this angle "
                                           "also measures roll and pitch (a gated update of the tilt; 90: off)",
                                           "deg", 0.0, 90.0)
    tilt_fit_interval: float = param(0.1, "at most one of those measurements in each slot of this much time (a "
                                     "frame's fit shares its markers, geometry and errors with the next frame's: at "
                                     "30 fps the fits of 0.1 s say little more than one, and each costs about 2 ms of "
                                     "CPU; 0: every frame)", "s", 0.0, 10.0)
    tilt_from_markers: bool = param(False, "let that measurement (and a resection's roll and pitch) correct the "
                                    "odometry's tilt without a calibration file (see the class doc)")
    lens_offset: float = param(0.0, "each fisheye lens's centre from the camera origin along its axis (0: one "
                               "centre); calibrate starts its estimate from it", "m", 0.0, 0.1)
    stitch_distance: float = param(0.0, "the distance the camera stitches its two images at (0: infinity)", "m",
                                   0.0)
    blend_band_deg: float = param(2.0, "width of the blend band at the stitching seams", "deg", 0.0, 90.0)

    def lenses(self) -> DualFisheye:
        """The camera's lenses these parameters describe (``camera.DualFisheye``)."""
        return DualFisheye(self.lens_offset, stitch_distance=self.stitch_distance or math.inf,
                           blend_band=math.radians(self.blend_band_deg))

    def check_together(self) -> None:
        try:
            self.lenses()
        except ConfigurationError as e:
            raise PipelineError(f"PipelineParams: {e}") from None


#: the pipeline's knobs of the camera itself: read when the pipeline is made, never changed live
CAMERA_FIELDS = ("lens_offset", "stitch_distance", "blend_band_deg")

#: (group, params class) of every tunable the pipeline takes: cfg/params.yaml's sections, in its order
PARAM_GROUPS = (("pipeline", PipelineParams), ("detection", DetectorParams), ("tracking", TrackingParams),
                ("filter", FilterParams))


def all_param_fields() -> List[Tuple[str, str, object]]:
    """(group, name, default) of every tunable: pipeline, detection, tracking, filter (flat, unique names)."""
    return [(group, f.name, f.default) for group, cls in PARAM_GROUPS for f in fields(cls)]


class AbsOrientPipeline(FrameSolver):
    """Detection → per-marker yaw → map→odom filter, one image at a time.

    ``base_T_camera`` and ``base_T_prism`` are the static lever arms (4×4, from tf_static or a
    calibration); ``marker_map`` gives ids, positions, sizes and the dictionary; ``readout`` (s) the
    camera's rolling-shutter readout time (the calibration file's; 0 = global shutter, see the module
    docstring); ``calibrated``: ``base_T_camera`` comes from ``calibrate`` (its roll and pitch were
    measured), so the markers' roll and pitch correct the odometry's tilt as with ``tilt_from_markers``;
    ``lenses``: the camera's two lenses (the calibration file's; default the params' ``lenses()``): each
    marker's yaw is solved along the ray of the lens that saw it; ``lens_yaw_sigma`` (front, back) rad: how well
    the calibration knew each lens's yaw: the markers of the lens known worse count for that much less. The
    params objects (cfg/params.yaml's sections; their defaults when None): ``params`` the pipeline's,
    ``detector_params``, ``tracking_params``, ``filter_params``, ``tilt_params`` and ``fit_settings`` (the
    multi-marker fits).
    """

    def __init__(self, marker_map: MarkerMap, base_T_camera, base_T_prism,
                 params: Optional[PipelineParams] = None, detector_params: Optional[DetectorParams] = None,
                 filter_params: Optional[FilterParams] = None, readout: float = 0.0,
                 tracking_params: Optional[TrackingParams] = None, calibrated: bool = False,
                 lenses: Optional[DualFisheye] = None, lens_yaw_sigma=None,
                 tilt_params: Optional[TiltParams] = None, fit_settings: Optional[FitSettings] = None):
        for name, T in (("base_T_camera", base_T_camera), ("base_T_prism", base_T_prism)):
            T = np.asarray(T, dtype=float)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise PipelineError(f"{name}: expected a finite 4×4 transform")
        if not (isinstance(readout, (int, float)) and math.isfinite(readout) and 0.0 <= readout < 1.0):
            raise PipelineError(f"readout: expected a rolling-shutter readout time in [0, 1) s, got {readout!r}")
        self.readout = float(readout)
        self.calibrated = bool(calibrated)
        self.marker_map = marker_map
        self.base_T_camera = np.asarray(base_T_camera, dtype=float)
        self.base_T_prism = np.asarray(base_T_prism, dtype=float)
        self.params = params or PipelineParams()
        self.params.validate()
        self.detector_params = detector_params or DetectorParams()
        self.tracking_params = tracking_params or TrackingParams()
        self.filter_params = filter_params or FilterParams()
        self.tilt_params = tilt_params or TiltParams()
        self.fit_settings = fit_settings or FitSettings()
        self.lenses = lenses if lenses is not None else self.params.lenses()
        known = np.zeros(2) if lens_yaw_sigma is None else np.asarray(lens_yaw_sigma, dtype=float).reshape(2)
        self._lens_excess = np.sqrt(np.maximum(known ** 2 - np.min(known) ** 2, 0.0))   # rad, front and back
        self.prism = PrismBuffer()
        self.stats: Dict[str, int] = {}
        self._build()

    def _build(self) -> None:
        self.tracker = MarkerTracker(self.marker_map, self.detector_params, params=self.tracking_params,
                                     lenses=self.lenses)
        self.filter = MapOdomFilter(self.base_T_prism, self.filter_params)
        self.tilt = TiltEstimator(self.tilt_params, math.radians(self.params.tilt_sigma_deg))
        self.last_stamp: Optional[float] = None
        self._last_odom: Optional[Tuple[float, np.ndarray]] = None   # (t, roll/pitch/yaw) of the last frame
        self._tilt_fit_slot: Optional[int] = None   # the tilt_fit_interval slot of the last tilt taken from the markers
        self._uninitialised_frames = 0

    @property
    def tilt_from_markers(self) -> bool:
        """Whether the markers' roll and pitch correct the odometry's tilt: ``tilt_from_markers``, or a
        calibrated camera (after ``calibrate`` the camera's own roll and pitch are known, so the markers'
        attitude is the platform's: on the realistic demo, whose VO drifts 0.5°/min in tilt, heading RMSE
        0.0253° → 0.0249°, p95 0.044° → 0.040°, and the self-check no longer takes the tilt drift for a
        0.32° camera tilt)."""
        return self.params.tilt_from_markers or self.calibrated

    def _tilt_slot(self, t: float) -> Optional[int]:
        """The ``tilt_fit_interval`` slot of time ``t`` (s); None with an interval of 0 (no slots)."""
        interval = self.params.tilt_fit_interval
        return None if interval <= 0.0 else math.floor(t / interval)

    def _tilt_fit_due(self, t: float) -> bool:
        """Whether a frame at ``t`` (s) measures roll and pitch: the first of each ``tilt_fit_interval`` slot of
        time to take one (slots, not the time since the last one: a 10 fps camera's jittered stamps keep all their
        fits at 0.1 s), every frame with an interval of 0."""
        slot = self._tilt_slot(t)
        return slot is None or slot != self._tilt_fit_slot

    def _count(self, key: str, n: int = 1) -> None:
        self.stats[key] = self.stats.get(key, 0) + n

    # ------------------------------------------------------------------ configuration
    def update_params(self, **changes) -> None:
        """Change tunables by name (any of :func:`all_param_fields`), e.g. from dynamic_reconfigure."""
        per_group: Dict[str, dict] = {group: {} for group, _ in PARAM_GROUPS}
        names = {name: group for group, name, _ in all_param_fields()}
        for k, v in changes.items():
            if k not in names:
                raise PipelineError(f"unknown parameter {k!r}")
            per_group[names[k]][k] = v
        if per_group["pipeline"]:
            p = replace(self.params, **per_group["pipeline"])   # checked when made
            self.params = p
            self.tilt.odometry_sigma = math.radians(p.tilt_sigma_deg)
        if per_group["detection"] or per_group["tracking"]:
            detector = replace(self.detector_params, **per_group["detection"])  # both validated before either
            tracking = replace(self.tracking_params, **per_group["tracking"])   # is taken
            self.detector_params, self.tracking_params = detector, tracking
            self.tracker = MarkerTracker(self.marker_map, self.detector_params, params=self.tracking_params,
                                     lenses=self.lenses)
        if per_group["filter"]:
            self.filter_params = replace(self.filter_params, **per_group["filter"])
            self.filter.update_params(self.filter_params)

    def reset(self) -> None:
        """Start over (time jumped back, a bag looped): filter, tracking and prism history."""
        self.prism.clear()
        self._build()
        self._count("resets")

    # ------------------------------------------------------------------ inputs
    def add_prism(self, t: float, p_map, cov=None) -> None:
        """A total-station prism position ``p_map`` (3,) m in map at total-station time ``t`` (s), with its
        covariance ``cov`` (3×3 m², the instrument's: :mod:`geocom.accuracy`; None: ``prism_sigma`` per axis)."""
        p = np.asarray(p_map, dtype=float)
        if cov is not None:
            cov = np.asarray(cov, dtype=float)
            if cov.shape != (3, 3) or not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0):
                self._count("bad_prism")
                return
        if p.shape != (3,) or not np.all(np.isfinite(p)) or not math.isfinite(t):
            self._count("bad_prism")
            return
        self.prism.add(float(t), p, cov)

    def add_imu(self, t: float, roll: float, pitch: float, sigma: float) -> None:
        """Roll and pitch of base_link (rad, 1-σ rad) from an IMU at total-station time ``t`` (s)
        (:func:`tilt.tilt_from_imu` turns a ``sensor_msgs/Imu`` into them)."""
        self.tilt.add_imu(float(t), float(roll), float(pitch), float(sigma))

    @property
    def waiting_reason(self) -> str:
        """Why there is no pose yet ('' once the filter is initialised): the filter's reason, with what
        the frames so far showed (markers seen, and why the pipeline kept them from the filter)."""
        if self.filter.initialised:
            return ""
        s = self.stats
        why = self.filter.stats.waiting_reason
        if not s.get("frames") and not s.get("observations"):
            return "no images yet"
        seen = s.get("observations", 0)
        if not seen:
            return f"no marker of the map seen in {s.get('frames', 0)} frame(s)"
        kept = [f"{s[k]} {what}" for k, what in (("no_prism", "frame(s) without a prism position"),
                                               ("too_few_for_resection", "frame(s) with too few markers for a "
                                                "resection"),
                                               ("resection_degenerate", "resection(s) refused for their geometry"),
                                               ("rejected_elevation", "marker(s) whose elevation disagrees with "
                                                "the map (wrong id or moved marker)"),
                                               ("degenerate", "marker(s) in degenerate geometry")) if s.get(k)]
        return f"{why}; {seen} marker observation(s)" + (f", {', '.join(kept)}" if kept else "")

    def map_T_odom(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """map_T_odom (4×4) and its covariance (4×4 over yaw, x, y, z) at time ``t``."""
        return self.filter.map_T_odom(t)

    def process_image(self, t: float, image: Union[np.ndarray, bytes], odom_T_base) -> FrameResult:
        """One image at total-station time ``t`` with the odometry pose ``odom_T_base`` (4×4) then.

        ``image``: JPEG bytes (decoded here, reduced by ``jpeg_reduce``) or a numpy frame (grey or BGR) —
        also a JPEG decoded beforehand, in another thread, by ``detection.frame_to_grey`` with the same
        ``jpeg_reduce`` (the node does: decoding the next image overlaps processing this one).
        Never raises for bad data: a corrupt image, NaN odometry or a missing prism give a
        FrameResult with ``error`` set (and a counter in ``stats``).
        """
        res = FrameResult(stamp=float(t))
        self._count("frames")
        if not self.filter.initialised:
            self._uninitialised_frames += 1
            if (self._uninitialised_frames - 1) % int(self.params.init_search_interval):
                self._count("skipped_before_init")
                return res
        clock = time.perf_counter()
        odom_T_base = np.asarray(odom_T_base, dtype=float)
        if odom_T_base.shape != (4, 4) or not np.all(np.isfinite(odom_T_base)):
            res.error = "odometry pose is not a finite 4×4 transform"
            self._count("bad_odometry")
            return res
        try:
            grey = frame_to_grey(image, int(self.params.jpeg_reduce))
        except DetectionError as e:
            res.error = f"bad image: {e}"
            self._count("bad_images")
            return res
        res.timings["decode"] = 1e3 * (time.perf_counter() - clock)

        prism = self._prism_at(t)
        map_T_camera = None
        if self.filter.initialised:
            map_T_odom, _ = self.filter.map_T_odom(t)
            map_T_base = map_T_odom @ odom_T_base     # map→odom is a yaw: its roll and pitch are the odometry's,
            roll, pitch, yaw = matrix_to_rpy(odom_T_base[:3, :3])        # corrected by the estimated tilt error
            map_T_base[:3, :3] = rpy_to_matrix(*self.tilt.corrected(float(roll), float(pitch), float(yaw)),
                                               float(yaw_of(map_T_base[:3, :3])))
            if prism is not None:  # the prism knows the position better than odometry
                map_T_base[:3, 3] = prism[0] - map_T_base[:3, :3] @ self.base_T_prism[:3, 3]
            map_T_camera = map_T_base @ self.base_T_camera

        clock = time.perf_counter()
        try:
            tracked = self.tracker.process(grey, map_T_camera)
        except DetectionError as e:
            res.error = f"bad image: {e}"
            self._count("bad_images")
            return res
        res.timings["track"] = 1e3 * (time.perf_counter() - clock)
        res.tracking = tracked.stats
        self._count("rejected_unknown", tracked.stats.rejected_unknown)
        self._count("rejected_tracking_gate", tracked.stats.rejected_gate)
        return self.process_observations(t, tracked.observations, odom_T_base, res, prism, tracked.gated,
                                         image_height=grey.shape[0] * int(self.params.jpeg_reduce))

    def process_observations(self, t: float, observations: List[MarkerObservation], odom_T_base,
                             res: Optional[FrameResult] = None, prism=None,
                             gated: Sequence[MarkerObservation] = (),
                             image_height: Optional[int] = None) -> FrameResult:
        """The frame's marker ``observations`` (already detected, ids of the map) at total-station time
        ``t`` (s) with the odometry pose ``odom_T_base`` (4×4): yaws, fusion, filter. :meth:`process_image`
        calls it after detection; tests and other detectors may call it directly (``res`` and the
        interpolated ``prism`` are then made here). ``gated``: markers the tracker found far from their
        prediction: their yaws are reported (a moved marker shows there) but not used. ``image_height``
        (rows of the full-resolution image): needed with a rolling-shutter ``readout``, for each
        observation's row time."""
        if self.readout > 0.0 and image_height is None:
            raise PipelineError("process_observations: image_height is needed with a rolling-shutter readout")
        if res is None:
            res = FrameResult(stamp=float(t))
            odom_T_base = np.asarray(odom_T_base, dtype=float)
            prism = self._prism_at(t)
        odom_rpy = np.array(matrix_to_rpy(odom_T_base[:3, :3]), dtype=float)
        odom_roll, odom_pitch, odom_yaw = (float(a) for a in odom_rpy)
        clock = time.perf_counter()
        self._count("observations", len(observations))
        if prism is None:
            self._count("markers_only_frames" if self.params.markers_only else "no_prism")
            tilt = self.tilt.tilt(t, odom_roll, odom_pitch, odom_yaw)
            self._resect_frame(t, res, observations, tilt, odom_T_base, gated)
        else:
            p, extra_sigma = prism
            res.prism_position = p
            measured = self.prism.cov_at(t)
            res.prism_cov = np.eye(3) * self.params.prism_sigma ** 2 if measured is None else measured
            prism_cov = res.prism_cov + np.eye(3) * extra_sigma ** 2
            self.filter.add_prism(t, p, prism_cov, odom_T_base)
            tilt = self.tilt.tilt(t, odom_roll, odom_pitch, odom_yaw)
            if (self.tilt_from_markers and tilt.source != "imu" and self._tilt_fit_due(t)
                    and self._tilt_from_markers(t, observations, p, prism_cov, tilt, odom_roll, odom_pitch, odom_yaw)):
                self._tilt_fit_slot = self._tilt_slot(t)
                tilt = self.tilt.tilt(t, odom_roll, odom_pitch, odom_yaw)
            rows = self._row_times(t, list(observations) + list(gated), image_height, odom_rpy)
            self._solve_frame(t, res, observations, (p, prism_cov), tilt, odom_T_base, gated, rows)
        res.tilt_source = tilt.source
        self._last_odom = (float(t), odom_rpy)
        res.timings["solve"] = 1e3 * (time.perf_counter() - clock)

        res.initialised = self.filter.initialised
        if res.initialised:
            res.map_T_odom, res.map_T_odom_cov = self.filter.map_T_odom(t)
            map_T_base = res.map_T_odom @ odom_T_base
            R = map_T_base[:3, :3]
            if res.prism_position is not None:  # the lever arm turned by the tilt in use (a tilted odometry corrected)
                R_tilt = rpy_to_matrix(tilt.roll, tilt.pitch, float(yaw_of(R)))
                map_T_base[:3, 3] = res.prism_position - R_tilt @ self.base_T_prism[:3, 3]
                res.base_position_cov = res.prism_cov
            res.map_T_base = map_T_base
            res.yaw = float(yaw_of(R))
            res.yaw_sigma = float(math.sqrt(max(res.map_T_odom_cov[0, 0], 0.0)))
            for r in res.observations:
                if math.isfinite(r.yaw):
                    r.residual = float((r.yaw - res.yaw + math.pi) % (2 * math.pi) - math.pi)
        self.last_stamp = float(t)
        return res

    def _row_times(self, t: float, observations, image_height, odom_rpy: np.ndarray):
        """Per observation: None at a global shutter (readout 0: the frame's prism and tilt serve), else
        (row time − t in s, prism position at the row time or None, the odometry's roll, pitch and yaw
        changes from t to the row time) — at the rates between the previous frame's odometry and this
        one's (zero when there is none within ``ODOM_RATE_MAX_GAP``)."""
        if self.readout == 0.0 or not observations:
            return [None] * len(observations)
        rate = np.zeros(3)
        if self._last_odom is not None and 0.0 < t - self._last_odom[0] <= ODOM_RATE_MAX_GAP:
            rate = wrap_angle(odom_rpy - self._last_odom[1]) / (t - self._last_odom[0])
        dts = row_fraction(np.array([o.centre for o in observations]), image_height) * self.readout
        q = self.params
        out = []
        for dt in dts:
            prism = self.prism.at(t + float(dt), q.prism_max_gap, q.prism_max_extrapolation)
            droll, dpitch, dyaw = (float(r) * dt for r in rate)
            out.append((float(dt), None if prism is None else prism[0], droll, dpitch, dyaw))
        return out

    def _prism_at(self, t: float):
        if self.params.markers_only:
            return None
        return self.prism.at(t, self.params.prism_max_gap, self.params.prism_max_extrapolation)

"""The per-frame core shared by the offline bag tool and the ROS node (DESIGN §4 steps 1–6).

``AbsOrientPipeline.process_image`` takes one 360° image with its time (total-station/ROS time:
the camera clock's offset already removed) and the odometry pose ``odom_T_base`` at that time, and
returns a :class:`FrameResult`: the marker observations with the absolute yaw each gives, the
filtered absolute attitude and pose of base_link, and ``map_T_odom`` with covariances. Prism
positions are fed as they arrive (``add_prism``). Nothing here imports rospy; Python 3.8.

Units: seconds, metres, radians. Covariances: rad² and m².
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, field, fields, replace
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from .correction import FilterParams, MapOdomFilter
from .detection import DetectionError, DetectorParams, MarkerObservation, decode_jpeg, to_grey
from .errors import ConfigurationError
from .markers import MarkerMap
from .solver import SolverError, fuse_yaws, yaw_from_marker
from .tracking import MarkerTracker, TrackingStats
from .transforms import matrix_to_rpy, yaw_of

__all__ = ["PipelineParams", "AbsOrientPipeline", "FrameResult", "ObservationResult", "PipelineError",
           "PrismBuffer", "all_param_fields"]


class PipelineError(ConfigurationError, ValueError):
    """Bad pipeline configuration (lever arms, parameters): names the field."""


@dataclass
class PipelineParams:
    """Knobs of the pipeline itself (detection and filter knobs live in their own objects).

    - ``prism_sigma``: 1-σ per axis of a total-station prism position (m).
    - ``prism_max_gap``: largest gap between the two prism samples around an image for
      interpolation (s); beyond it the frame gives no absolute yaw (counted).
    - ``prism_max_extrapolation``: how far past the newest prism sample an image may lie (s);
      used live, where the prism arrives a little after the image.
    - ``tilt_sigma_deg``: 1-σ of roll and of pitch from the odometry (degrees).
    - ``lever_sigma``: 1-σ per axis of the camera–prism lever arm (m).
    - ``min_range``: nearest usable marker (m).
    - ``elevation_gate``: a marker whose observed elevation disagrees with the map, prism and
      tilt by more than this many σ is rejected before the filter (a wrong id, a moved marker).
    - ``fusion_gate``: a marker whose yaw disagrees with the frame's other markers by more than
      this many σ is left out of the frame's fused yaw (σ).
    - ``init_search_interval``: before the filter is initialised (no prediction: every search
      is a full-frame one), search only every n-th image (frames). 1 (every image) by default:
      the filter starts from three consistent yaws, and a node (re)started while driving should
      not throw away the frames that give them (live, the newest image wins anyway).
    - ``jpeg_reduce``: decode JPEGs at 1/1, 1/2, 1/4 or 1/8 resolution (1 = full; accuracy
      falls with resolution, see bench/detection.py).
    """

    prism_sigma: float = 0.005
    prism_max_gap: float = 0.5
    prism_max_extrapolation: float = 0.15
    tilt_sigma_deg: float = 0.2
    lever_sigma: float = 0.002
    min_range: float = 0.5
    elevation_gate: float = 5.0
    fusion_gate: float = 4.0
    init_search_interval: int = 1
    jpeg_reduce: int = 1

    def validate(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise PipelineError(f"PipelineParams.{f.name}: expected a finite non-negative number, got {v!r}")
        if self.init_search_interval < 1:
            raise PipelineError(f"PipelineParams.init_search_interval: expected ≥ 1, got {self.init_search_interval!r}")
        if self.jpeg_reduce not in (1, 2, 4, 8):
            raise PipelineError(f"PipelineParams.jpeg_reduce: expected 1, 2, 4 or 8, got {self.jpeg_reduce!r}")


def all_param_fields() -> List[Tuple[str, str, object]]:
    """(group, name, default) of every tunable: pipeline, detection, filter (flat, unique names)."""
    out = []
    for group, cls in (("pipeline", PipelineParams), ("detection", DetectorParams), ("filter", FilterParams)):
        for f in fields(cls):
            out.append((group, f.name, f.default))
    return out


@dataclass
class ObservationResult:
    """One marker in one frame, and what it said about the absolute yaw."""

    observation: MarkerObservation
    yaw: float = float("nan")            # rad, absolute yaw of base_link from this marker alone
    yaw_sigma: float = float("nan")      # rad
    range: float = float("nan")          # m, camera → marker
    residual: float = float("nan")       # rad, yaw − filtered yaw (wrapped)
    accepted: bool = False
    reason: str = ""                     # why rejected (empty when accepted)

    @property
    def id(self) -> int:
        return self.observation.id


@dataclass
class FrameResult:
    """Everything one image gave. Times in s (total-station time); angles in rad."""

    stamp: float
    observations: List[ObservationResult] = field(default_factory=list)
    fused_yaw: Optional[float] = None               # this frame's markers fused (before the filter)
    fused_yaw_sigma: Optional[float] = None
    yaw: Optional[float] = None                     # filtered absolute yaw of base_link
    yaw_sigma: Optional[float] = None
    map_T_base: Optional[np.ndarray] = None         # 4×4 corrected pose
    base_position_cov: Optional[np.ndarray] = None  # 3×3 m² (prism, lever arm removed)
    prism_position: Optional[np.ndarray] = None     # (3,) m, prism interpolated at the image time
    map_T_odom: Optional[np.ndarray] = None
    map_T_odom_cov: Optional[np.ndarray] = None     # 4×4 over (yaw, x, y, z)
    initialised: bool = False
    error: Optional[str] = None
    timings: Dict[str, float] = field(default_factory=dict)   # ms per stage
    tracking: Optional[TrackingStats] = None        # how the markers were searched


class PrismBuffer:
    """Recent prism positions (total-station time), interpolated at image times."""

    def __init__(self, horizon: float = 30.0):
        self.horizon = horizon
        self.t: List[float] = []
        self.p: List[np.ndarray] = []

    def add(self, t: float, p) -> None:
        if self.t and t <= self.t[-1]:
            if t == self.t[-1]:
                return
            i = bisect.bisect_left(self.t, t)  # late sample: insert in order
            self.t.insert(i, t)
            self.p.insert(i, np.asarray(p, dtype=float))
        else:
            self.t.append(t)
            self.p.append(np.asarray(p, dtype=float))
        cut = bisect.bisect_left(self.t, self.t[-1] - self.horizon)
        if cut:
            del self.t[:cut], self.p[:cut]

    def clear(self) -> None:
        self.t.clear()
        self.p.clear()

    def at(self, t: float, max_gap: float, max_extrapolation: float) -> Optional[Tuple[np.ndarray, float]]:
        """(position, extra 1-σ in m from interpolation/extrapolation) at ``t``, or None."""
        n = len(self.t)
        if n == 0:
            return None
        i = bisect.bisect_right(self.t, t)
        if 0 < i < n:
            t0, t1 = self.t[i - 1], self.t[i]
            if t1 - t0 > max_gap:
                return None
            a = (t - t0) / (t1 - t0)
            return self.p[i - 1] + a * (self.p[i] - self.p[i - 1]), 0.0
        if i == n and n >= 2 and t - self.t[-1] <= max_extrapolation:
            v = (self.p[-1] - self.p[-2]) / max(self.t[-1] - self.t[-2], 1e-3)
            dt = t - self.t[-1]
            return self.p[-1] + v * dt, 0.5 * float(np.linalg.norm(v)) * dt
        if i == n and t == self.t[-1]:
            return self.p[-1], 0.0
        return None


class AbsOrientPipeline:
    """Detection → per-marker yaw → map→odom filter, one image at a time.

    ``base_T_camera`` and ``base_T_prism`` are the static lever arms (4×4, from tf_static or a
    calibration); ``marker_map`` gives ids, positions, sizes and the dictionary.
    """

    def __init__(self, marker_map: MarkerMap, base_T_camera, base_T_prism,
                 params: Optional[PipelineParams] = None, detector_params: Optional[DetectorParams] = None,
                 filter_params: Optional[FilterParams] = None):
        for name, T in (("base_T_camera", base_T_camera), ("base_T_prism", base_T_prism)):
            T = np.asarray(T, dtype=float)
            if T.shape != (4, 4) or not np.all(np.isfinite(T)):
                raise PipelineError(f"{name}: expected a finite 4×4 transform")
        self.marker_map = marker_map
        self.base_T_camera = np.asarray(base_T_camera, dtype=float)
        self.base_T_prism = np.asarray(base_T_prism, dtype=float)
        self.params = params or PipelineParams()
        self.params.validate()
        self.detector_params = detector_params or DetectorParams()
        self.filter_params = filter_params or FilterParams()
        self.prism = PrismBuffer()
        self.stats: Dict[str, int] = {}
        self._build()

    def _build(self) -> None:
        self.tracker = MarkerTracker(self.marker_map, self.detector_params)
        self.filter = MapOdomFilter(self.base_T_prism, self.filter_params)
        self.last_stamp: Optional[float] = None
        self._uninitialised_frames = 0

    def _count(self, key: str, n: int = 1) -> None:
        self.stats[key] = self.stats.get(key, 0) + n

    # ------------------------------------------------------------------ configuration
    def update_params(self, **changes) -> None:
        """Change tunables by name (any of :func:`all_param_fields`), e.g. from dynamic_reconfigure."""
        groups = {"pipeline": self.params, "detection": self.detector_params, "filter": self.filter_params}
        per_group: Dict[str, dict] = {g: {} for g in groups}
        names = {name: group for group, name, _ in all_param_fields()}
        for k, v in changes.items():
            if k not in names:
                raise PipelineError(f"unknown parameter {k!r}")
            per_group[names[k]][k] = v
        if per_group["pipeline"]:
            p = replace(self.params, **per_group["pipeline"])
            p.validate()
            self.params = p
        if per_group["detection"]:
            self.detector_params = replace(self.detector_params, **per_group["detection"])
            self.tracker = MarkerTracker(self.marker_map, self.detector_params)
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
        """A total-station prism position ``p_map`` (3,) m in map at total-station time ``t`` (s)."""
        p = np.asarray(p_map, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)) or not math.isfinite(t):
            self._count("bad_prism")
            return
        self.prism.add(float(t), p)

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
                                               ("rejected_elevation", "marker(s) whose elevation disagrees with "
                                                "the map (wrong id or moved marker)"),
                                               ("degenerate", "marker(s) in degenerate geometry")) if s.get(k)]
        return f"{why}; {seen} marker observation(s)" + (f", {', '.join(kept)}" if kept else "")

    def map_T_odom(self, t: float) -> Tuple[np.ndarray, np.ndarray]:
        """map_T_odom (4×4) and its covariance (4×4 over yaw, x, y, z) at time ``t``."""
        return self.filter.map_T_odom(t)

    def process_image(self, t: float, image: Union[np.ndarray, bytes], odom_T_base) -> FrameResult:
        """One image at total-station time ``t`` with the odometry pose ``odom_T_base`` (4×4) then.

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
            if isinstance(image, (bytes, bytearray, memoryview)):
                grey = decode_jpeg(bytes(image), reduce=int(self.params.jpeg_reduce))
            else:
                grey = to_grey(image)
        except DetectionError as e:
            res.error = f"bad image: {e}"
            self._count("bad_images")
            return res
        res.timings["decode"] = 1e3 * (time.perf_counter() - clock)

        prism = self.prism.at(t, self.params.prism_max_gap, self.params.prism_max_extrapolation)
        map_T_camera = None
        if self.filter.initialised:
            map_T_odom, _ = self.filter.map_T_odom(t)
            map_T_base = map_T_odom @ odom_T_base
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
        res.timings["detect"] = 1e3 * (time.perf_counter() - clock)
        res.tracking = tracked.stats
        self._count("rejected_unknown", tracked.stats.rejected_unknown)
        self._count("rejected_tracking_gate", tracked.stats.rejected_gate)
        return self.process_observations(t, tracked.observations, odom_T_base, res, prism, tracked.gated)

    def process_observations(self, t: float, observations: List[MarkerObservation], odom_T_base,
                             res: Optional[FrameResult] = None, prism=None,
                             gated: Sequence[MarkerObservation] = ()) -> FrameResult:
        """The frame's marker ``observations`` (already detected, ids of the map) at total-station time
        ``t`` (s) with the odometry pose ``odom_T_base`` (4×4): yaws, fusion, filter. :meth:`process_image`
        calls it after detection; tests and other detectors may call it directly (``res`` and the
        interpolated ``prism`` are then made here). ``gated``: markers the tracker found far from their
        prediction: their yaws are reported (a moved marker shows there) but not used."""
        if res is None:
            res = FrameResult(stamp=float(t))
            odom_T_base = np.asarray(odom_T_base, dtype=float)
            prism = self.prism.at(t, self.params.prism_max_gap, self.params.prism_max_extrapolation)
        roll, pitch, _ = matrix_to_rpy(odom_T_base[:3, :3])
        clock = time.perf_counter()
        self._count("observations", len(observations))
        if prism is None:
            self._count("no_prism")
            res.observations = [ObservationResult(o, reason="no prism position")
                                for o in list(observations) + list(gated)]
        else:
            p, extra_sigma = prism
            res.prism_position = p
            s2 = self.params.prism_sigma ** 2 + extra_sigma ** 2
            prism_cov = np.eye(3) * s2
            self.filter.add_prism(t, p, prism_cov, odom_T_base)
            self._solve_frame(t, res, observations, p, prism_cov, roll, pitch, odom_T_base, gated)
        res.timings["solve"] = 1e3 * (time.perf_counter() - clock)

        res.initialised = self.filter.initialised
        if res.initialised:
            res.map_T_odom, res.map_T_odom_cov = self.filter.map_T_odom(t)
            map_T_base = res.map_T_odom @ odom_T_base
            R = map_T_base[:3, :3]
            if res.prism_position is not None:
                map_T_base[:3, 3] = res.prism_position - R @ self.base_T_prism[:3, 3]
                res.base_position_cov = np.eye(3) * (self.params.prism_sigma ** 2)
            res.map_T_base = map_T_base
            res.yaw = float(yaw_of(R))
            res.yaw_sigma = float(math.sqrt(max(res.map_T_odom_cov[0, 0], 0.0)))
            for r in res.observations:
                if math.isfinite(r.yaw):
                    r.residual = float((r.yaw - res.yaw + math.pi) % (2 * math.pi) - math.pi)
        self.last_stamp = float(t)
        return res

    def _solve_frame(self, t, res: FrameResult, observations, prism_p, prism_cov, roll, pitch,
                     odom_T_base, gated=()) -> None:
        """Yaw from each marker (closed form), their fusion (shared prism/tilt errors, false ids
        dropped), and one filter update with the fused yaw."""
        q = self.params
        estimates = []
        tracker_gated = {id(o) for o in gated}
        for o in list(observations) + list(gated):
            m = self.marker_map[o.id]  # the tracker only returns ids of the map
            if not m.visible_from(prism_p, margin=float(np.linalg.norm(self.base_T_camera[:3, 3]
                                                                       - self.base_T_prism[:3, 3]))):
                self._count("rejected_behind")
                res.observations.append(ObservationResult(o, reason="seen from behind its surveyed face (wrong id)"))
                continue
            try:
                est = yaw_from_marker(
                    o.centre, m.position, prism_p, float(roll), float(pitch), self.base_T_camera,
                    self.base_T_prism[:3, 3], sigma_bearing=o.sigma, prism_cov=prism_cov, marker_sigma=m.sigma,
                    tilt_sigma=math.radians(q.tilt_sigma_deg), lever_sigma=q.lever_sigma, min_range=q.min_range)
            except SolverError as e:
                self._count("degenerate")
                res.observations.append(ObservationResult(o, reason=f"geometry: {e}"))
                continue
            r = ObservationResult(o, yaw=est.yaw, yaw_sigma=est.sigma, range=est.range)
            res.observations.append(r)
            if id(o) in tracker_gated:
                r.reason = "tracking gate: far from its predicted bearing (moved marker, or the filter is off)"
                continue
            if abs(est.elevation_residual) > q.elevation_gate * est.elevation_sigma:
                r.reason = "elevation disagrees with the map (wrong id or moved marker)"
                self._count("rejected_elevation")
                continue
            estimates.append((r, est))
        if not estimates:
            return
        fused = fuse_yaws([e for _, e in estimates], gate=q.fusion_gate)
        for (r, _), used in zip(estimates, fused.used):
            if not used:
                r.reason = "disagrees with the other markers of the frame"
                self._count("rejected_fusion")
        update = self.filter.add_yaw(t, fused.yaw, fused.sigma, odom_T_base,
                                     sources=[r.id for (r, _), used in zip(estimates, fused.used) if used])
        res.fused_yaw, res.fused_yaw_sigma = fused.yaw, fused.sigma
        for (r, _), used in zip(estimates, fused.used):
            if used:
                r.accepted = bool(update.accepted)
                r.reason = "" if r.accepted else f"filter: {update.status}"
        self._count("filter_" + update.status)

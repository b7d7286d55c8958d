"""Map-guided marker tracking in 360° frames (doc/design.md §6): detect, don't search.

In: a frame, the predicted ``map_T_camera`` (or none) and the marker map. Out: the map's markers found in small
gnomonic views around their predicted bearings (all views of a frame in one mosaic, one OpenCV call), gated by
``gate_deg`` against the prediction, plus a vertical strip sweeping the panorama for markers the prediction
misses. The whole frame is searched (:meth:`MarkerDetector.detect`) at start-up, without a pose, every
``max_full_interval`` frames if set, and after a loss, when every map id is accepted (the prediction is what is
suspect) and the next recovery waits longer, up to ``lost_backoff_max_frames``, while it finds only what was
predicted. Metres, radians (``*_deg`` parameters in degrees), milliseconds for the reported times; Python 3.8,
numpy and OpenCV only.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from .camera import SINGLE_CENTRE, DualFisheye, Equirect, GnomonicView, angle_between, bearing_to_azel
from .detection import (
    DetectionError,
    DetectorParams,
    MarkerDetector,
    MarkerObservation,
    Wanted,
    dedupe_observations,
    to_grey,
)
from .detection.detector import band_rows
from .detection.jpegrows import RowsMissing, bilinear_rows
from .markers import MarkerMap
from .paramspec import Params, param
from .transforms import invert_T, rot_z, transform_points, wrap_angle

__all__ = ["TrackingError", "TrackingParams", "MarkerPrediction", "TrackingStats", "TrackingResult", "RowPlan",
           "MarkerTracker"]


class TrackingError(DetectionError):
    """A pose or map the tracker cannot use."""


@dataclass
class TrackingParams(Params):
    """The knobs of map-guided tracking (cfg/params.yaml's ``tracking`` section; those worth changing live are
    also in cfg/AbsOrient.cfg). How each ROI view and the sweep are searched is
    :class:`~aruco_abs_orient.detection.DetectorParams`' (``view_*``). An ROI view's field of view is the
    marker's angular size × (1 + 2·``roi_margin``) + 2·``gate_deg``."""

    error = TrackingError

    roi_margin: float = param(0.5, "margin of an ROI view around the predicted marker, a fraction of its size", "",
                              0.0)
    roi_min_px: int = param(32, "smallest ROI view side", "px", 0)
    roi_target_side_px: float = param(16.0, "ROI views of small markers are upsampled until the marker's side "
                                      "spans this", "px", 0.0)
    roi_max_upsample: float = param(3.0, "... by at most this factor", "", 0.0)
    gate_deg: float = param(1.0, "largest angle between an observed and a predicted centre (a rejected quad in an "
                            "ROI view is read only within it of the view's centre)", "deg", 0.0, 30.0)
    min_predicted_side_px: float = param(6.0, "markers predicted smaller than this are not tracked", "px", 0.0)
    sweep_tile_deg: float = param(8.0, "width of the vertical strip searched each frame while tracking, so that "
                                  "markers the prediction misses are found", "deg", 0.0)
    sweep_period_frames: int = param(72, "frames for the sweeping tile to go once around 360°", "frames", 1, 10000)
    sweep_every_frames: int = param(2, "the tile is searched on every n-th frame only (and moves by n steps then)",
                                    "frames", 0)
    sweep_max_el_deg: float = param(60.0, "the tile spans elevations within this of the horizon", "deg", 0.0)
    max_full_interval: int = param(0, "frames between forced full-frame searches while tracking (0: only at "
                                   "start-up and after a loss)", "frames", 0)
    lost_after_frames: int = param(3, "consecutive frames with predictions but no accepted marker after which "
                                   "tracking falls back to full-frame search", "frames", 1, 1000)
    decode_rows: bool = param(True, "process: decode only the image rows tracking reads (libjpeg-turbo, built on "
                              "first use with the system's C compiler and libjpeg's headers; without them whole "
                              "frames, as the node does)")
    decode_row_margin_deg: float = param(3.0, "process: rows decoded beyond those the last frame's views and sweep "
                                         "read, for the markers' motion until a frame is searched (a read beyond "
                                         "them decodes the frame whole)", "deg", 0.0, 90.0)
    lost_backoff_max_frames: int = param(24, "after a full-frame search that found no marker off its prediction, "
                                         "the next waits for twice the misses, up to this (lost_after_frames or "
                                         "less: no back-off)", "frames", 0)


@dataclass
class MarkerPrediction:
    """Where a map marker should appear: ``bearing`` (3,) unit, camera frame; ``angular_size``
    (radians, side of a marker facing the camera); ``range`` (metres)."""

    id: int
    bearing: np.ndarray
    angular_size: float
    range: float


@dataclass
class TrackingStats:
    """What one frame cost and found: ``mode`` 'full' or 'tracked'; ``recovery`` True for a
    full-frame search after a loss (map ids accepted without the prediction gate);
    ``predicted`` markers looked for in ROI views; ``found`` accepted observations by
    method; ``rejected_unknown`` detections of ids not in the map; ``rejected_gate``
    detections too far from their prediction; ``sweep_u0`` first column of the sweeping tile
    (−1 when none); ``time_ms`` wall time of :meth:`MarkerTracker.process` (milliseconds)."""

    mode: str
    predicted: int = 0
    found: Dict[str, int] = field(default_factory=dict)
    rejected_unknown: int = 0
    rejected_gate: int = 0
    sweep_u0: int = -1
    time_ms: float = 0.0
    recovery: bool = False


@dataclass
class TrackingResult:
    """``observations``: accepted map markers; ``gated``: map markers found farther than ``gate_deg``
    from their prediction (kept out of the filter, but reported: a moved marker shows up there)."""

    observations: List[MarkerObservation]
    stats: TrackingStats
    gated: List[MarkerObservation] = field(default_factory=list)


class RowPlan(NamedTuple):
    """The image rows tracking will read in the frames after the last one, each span [r0, r1) widened already:
    the last frame's ROI views' ``rois`` (None: it had none) and, in the frames that sweep (tracker frame numbers
    ``frame + n`` divisible by ``every``), the sweep's band ``sweep``; ``whole``: the whole frame (a search of the
    whole frame may come next)."""

    frame: int
    every: int
    rois: Optional[Tuple[int, int]]
    sweep: Tuple[int, int]
    whole: bool

    def rows(self, ahead: int) -> Optional[Tuple[int, int]]:
        """The rows of the frame ``ahead`` frames after the next one (0: the next), None for the whole frame."""
        spans = [span for span, used in ((self.rois, True), (self.sweep, (self.frame + ahead) % self.every == 0))
                 if used and span is not None]
        if self.whole or not spans:
            return None
        return min(s[0] for s in spans), max(s[1] for s in spans)


class MarkerTracker:
    """Markers of a map, tracked frame to frame from a predicted camera pose.

    >>> tracker = MarkerTracker(MarkerMap.load("markers.yaml"))    # doctest: +SKIP
    >>> result = tracker.process(grey, map_T_camera)              # doctest: +SKIP
    """

    def __init__(self, marker_map: MarkerMap, detector_params: Optional[DetectorParams] = None,
                 api: Optional[str] = None, params: Optional[TrackingParams] = None,
                 lenses: DualFisheye = SINGLE_CENTRE):
        self.map = marker_map
        self.lenses = lenses
        self.detector = MarkerDetector(marker_map.dictionary, detector_params, api)
        self.params = params if params is not None else TrackingParams()
        self.reset()

    def reset(self) -> None:
        """Forget the tracking state: the next frame is searched whole."""
        self.frame = 0
        self._since_full: Optional[int] = None
        self._misses = 0
        self._lost_after = self.params.lost_after_frames  # misses before the next recovery search
        self._views = {}
        self._last_maps: list = []  # the last frame's ROI views' remap maps (what row_plan reads)

    def _roi(self, equirect: Equirect, m: MarkerPrediction, fov: float, upsample: float):
        """The ROI view of marker ``m`` and its remap maps. Last frame's are reused, turned
        about the vertical, while the prediction's elevation stays within a tenth of the
        view's field of view of its centre and the wanted field of view within 10 %: turning
        a view about the camera's z axis only shifts its equirect columns (exactly)."""
        key = (m.id, equirect.width)
        az, el = (float(a) for a in bearing_to_azel(m.bearing))
        cached = self._views.get(key)
        if cached is not None:
            view, maps, cfov, caz, cel = cached
            if abs(el - cel) < 0.1 * cfov and abs(fov - cfov) < 0.1 * cfov:
                turn = float(wrap_angle(az - caz))
                turned = GnomonicView(rot_z(turn) @ view.center_bearing, (view.width, view.height), view.focal)
                return turned, (maps[0] - np.float32(turn / equirect.rad_per_px), maps[1])
        view = self.detector.view_around(equirect, m.bearing, fov, upsample, min_px=self.params.roi_min_px)
        maps = self.detector.view_maps(view, equirect, step=4)
        self._views[key] = (view, maps, fov, az, el)
        return view, maps

    def row_plan(self, height: int) -> RowPlan:
        """What the next frames of ``height`` rows will read (:class:`RowPlan`): the rows of the last frame's ROI
        views and of the sweep's band, each widened by ``decode_row_margin_deg`` for the markers' motion
        meanwhile."""
        eq = Equirect(2 * height, height)
        q = self.params
        pad = int(math.ceil(math.radians(q.decode_row_margin_deg) / eq.rad_per_px))
        rois = None
        if self._last_maps:
            spans = [bilinear_rows(my) for _, my in self._last_maps]
            rois = (min(s[0] for s in spans) - pad, max(s[1] for s in spans) + pad)
        v0, v1 = band_rows(eq, math.radians(q.sweep_max_el_deg))
        sweep = (v0 - pad, v1 + pad)
        # whole: the last frame searched the whole image (no pose to predict from yet, or a recovery: the next
        # one may too), a recovery may come next, or a forced search is due
        whole = (not self._since_full or self._misses + 1 >= self._lost_after
                 or (q.max_full_interval > 0 and self._since_full + 1 >= q.max_full_interval))
        return RowPlan(self.frame, self._sweep_every(), rois, sweep, whole)

    def _sweep_every(self) -> int:
        """The sweeping tile is searched on every n-th tracked frame (``sweep_every_frames``; 0 as 1)."""
        return max(1, int(self.params.sweep_every_frames))

    def predict(self, map_T_camera, equirect: Equirect) -> List[MarkerPrediction]:
        """Predicted bearings of all the map's markers (where the camera's stitched image shows them), nearest
        first.

        ``map_T_camera``: 4×4 pose of the camera frame in the map.
        """
        T = np.asarray(map_T_camera, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise TrackingError(f"map_T_camera: expected a finite 4×4 matrix, got shape {T.shape}")
        ids = self.map.ids
        p = transform_points(invert_T(T), self.map.positions(ids))
        rng = np.linalg.norm(p, axis=1)
        near = rng <= 1e-6
        bearings = self.lenses.project(np.where(near[:, None], 1.0, p))
        out = []
        for mid, b, r in zip(ids, bearings, rng):
            if r <= 1e-6:
                continue
            size = 2.0 * math.atan(self.map[mid].size / (2.0 * r))
            out.append(MarkerPrediction(mid, b, size, float(r)))
        return sorted(out, key=lambda m: m.range)

    def process(self, image: np.ndarray, map_T_camera=None, what: str = "image") -> TrackingResult:
        """Observations of map markers in one equirect frame (grey or BGR uint8, 2:1).

        ``map_T_camera``: predicted 4×4 camera pose in the map, or None (unknown: the whole
        frame is searched and every id in the map accepted). After ``lost_after_frames``
        frames in a row with predictions but no accepted marker, the whole frame is searched
        and every map id accepted without the prediction gate (``stats.recovery``). Raises
        DetectionError (or TrackingError) for an unusable image or pose; the state is
        unchanged then. A frame decoded in part (``detection.jpegrows.RowFrame``) that lacks rows a search
        reads is decoded whole then (its ``completed`` says so) and searched again: the same observations.
        """
        try:
            return self._process(image, map_T_camera, what)
        except RowsMissing:
            return self._process(image.complete(), map_T_camera, what)

    def _process(self, image: np.ndarray, map_T_camera, what: str) -> TrackingResult:
        t0 = time.perf_counter()
        grey = to_grey(image, what)
        eq = Equirect(grey.shape[1], grey.shape[0])
        q = self.params
        preds = self.predict(map_T_camera, eq) if map_T_camera is not None else []
        by_id = {m.id: m for m in preds}
        recovery = map_T_camera is not None and self._misses >= self._lost_after
        full = (map_T_camera is None or self._since_full is None or recovery
                or (q.max_full_interval > 0 and self._since_full >= q.max_full_interval))
        stats = TrackingStats(mode="full" if full else "tracked", recovery=recovery)
        if full:
            candidates = self.detector.detect(grey, what)
            self._since_full = 0
            self._last_maps = []
        else:
            gate = math.radians(q.gate_deg)
            views, maps, expect, sizes = [], [], [], []
            for m in preds:
                side = m.angular_size / eq.rad_per_px
                if side < q.min_predicted_side_px:
                    continue
                up = min(max(q.roi_target_side_px / side, 1.0), q.roi_max_upsample)
                fov = m.angular_size * (1.0 + 2.0 * q.roi_margin) + 2.0 * gate
                view, view_maps = self._roi(eq, m, fov, up)
                views.append(view)
                maps.append(view_maps)
                expect.append(m.id)
                sizes.append(m.angular_size)
            stats.predicted = len(views)
            self._last_maps = maps
            candidates = self.detector.detect_in_views(grey, eq, views, maps, expect, "tracked", sizes, gate=gate)
            every = self._sweep_every()
            if self.frame % every == 0:
                step = eq.width / q.sweep_period_frames * every
                width = int(math.ceil(max(math.radians(q.sweep_tile_deg) / eq.rad_per_px, step)))
                stats.sweep_u0 = int(self.frame // every * step) % eq.width
                # the sweep looks for what the prediction misses: OpenCV's own finds suffice
                candidates += self.detector.detect_columns(
                    grey, eq, stats.sweep_u0, width, "full", max_el=math.radians(q.sweep_max_el_deg),
                    wanted=Wanted(rescue=False, skip_ids={o.id for o in candidates}))
            self._since_full += 1
        accepted, gated = [], []
        off_prediction = False  # a recovery's find beyond the gate of its prediction (or unpredicted)
        for o in candidates:
            if o.id not in self.map:
                stats.rejected_unknown += 1
            elif map_T_camera is not None and not recovery and (
                    o.id not in by_id
                    or float(angle_between(o.centre, by_id[o.id].bearing)) > math.radians(q.gate_deg)):
                stats.rejected_gate += 1
                gated.append(o)
            else:
                accepted.append(o)
                off_prediction |= recovery and (o.id not in by_id or float(
                    angle_between(o.centre, by_id[o.id].bearing)) > math.radians(q.gate_deg))
        accepted = sorted(dedupe_observations(accepted), key=lambda o: o.id)
        for o in accepted:
            stats.found[o.method] = stats.found.get(o.method, 0) + 1
        # a miss: markers were predicted (in ROI views) or detected but none accepted; a
        # frame that neither predicted nor saw anything says nothing about the prediction
        missed = not accepted and (stats.predicted > 0 or stats.rejected_gate > 0)
        self._misses = self._misses + 1 if missed else 0
        if recovery and not off_prediction:  # the prediction held: the next search waits longer
            self._lost_after = min(2 * self._lost_after, max(q.lost_backoff_max_frames, q.lost_after_frames))
        elif off_prediction or (not full and accepted):
            self._lost_after = q.lost_after_frames
        self.frame += 1
        stats.time_ms = (time.perf_counter() - t0) * 1000.0
        return TrackingResult(accepted, stats, sorted(dedupe_observations(gated), key=lambda o: o.id))
